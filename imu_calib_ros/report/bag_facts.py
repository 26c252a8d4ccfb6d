"""What the report shows of the bag itself: content hash, joint timeline with the detected
plan segments, and the Allan deviation of the stationary windows (issue 12).

Pure numpy on the core's types; the CLI reads the bag and hands the arrays in.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def content_hash(path: str | Path) -> str:
    """SHA-256 of a bag's files (a directory: every file, sorted by name; or one file), the
    first 16 hex digits: which recording this report covers, whatever its path."""
    p = Path(path)
    files = sorted(f for f in p.rglob('*') if f.is_file()) if p.is_dir() else [p]
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        with open(f, 'rb') as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b''):
                h.update(chunk)
    return h.hexdigest()[:16]


def allan_deviation(x: FloatArray, dt_s: float, taus_n: list[int]) -> FloatArray:
    """Overlapping Allan deviation of a rate sequence ``x`` (N, k) at cluster sizes
    ``taus_n`` (IEEE Std 952, annex C): ``0.5 <(mean_{i+n} - mean_i)^2>``; NaN where the
    sequence is shorter than three clusters."""
    out = np.full((len(taus_n), x.shape[1]), np.nan)
    c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    for k, n in enumerate(taus_n):
        if 3 * n > len(x):
            continue
        means = (c[n:] - c[:-n]) / n
        d = means[n:] - means[:-n]
        out[k] = np.sqrt(0.5 * np.mean(d * d, axis=0))
    return out


@dataclass
class AllanResult:
    """Allan deviation of each axis pooled over the stationary windows."""

    tau_s: FloatArray
    gyro_rad_s: FloatArray  # (len(tau), 3)
    accel_m_s2: FloatArray  # (len(tau), 3)
    windows: int
    seconds: float


def pooled_allan(gyro: FloatArray, accel: FloatArray, dt_s: float,
                 windows: list[tuple[int, int]]) -> AllanResult | None:
    """Allan deviation per axis from the stationary windows ``[(i0, i1), ...]``: the Allan
    variance of each window (its own mean removed: the attitude differs between windows),
    pooled weighted by the number of cluster differences."""
    longest = max((b - a for a, b in windows), default=0)
    if longest < 12:
        return None
    taus_n = sorted({int(n) for n in np.unique(np.logspace(0, np.log10(longest / 3), 14)
                                               .astype(int)) if n >= 1})
    num = {'g': np.zeros((len(taus_n), 3)), 'a': np.zeros((len(taus_n), 3))}
    den = np.zeros(len(taus_n))
    for a, b in windows:
        for key, x in (('g', gyro[a:b]), ('a', accel[a:b])):
            ad = allan_deviation(x - x.mean(axis=0), dt_s, taus_n)
            w = np.array([max(len(x) - 2 * n + 1, 0) if 3 * n <= len(x) else 0
                          for n in taus_n], float)
            num[key] += np.nan_to_num(ad ** 2) * w[:, None]
            if key == 'g':
                den += w
    ok = den > 0
    tau = np.asarray(taus_n, float)[ok] * dt_s
    return AllanResult(tau, np.sqrt(num['g'][ok] / den[ok, None]),
                       np.sqrt(num['a'][ok] / den[ok, None]), len(windows),
                       float(sum(b - a for a, b in windows) * dt_s))


@dataclass
class BagFacts:
    """The bag as the report shows it (:func:`imu_calib_ros.cli.report` gathers it)."""

    path: str
    sha256: str
    duration_s: float
    imu_samples: int
    imu_rate_hz: float
    joint_names: tuple[str, ...]
    t_joint_s: FloatArray  # joint timeline, thinned
    q_deg: FloatArray  # (M, n)
    windows_s: list[tuple[float, float]]  # stationary windows (the plan's dwells)
    allan: AllanResult | None = None
    nav: dict[str, tuple[FloatArray, FloatArray]] = field(default_factory=dict)

    @property
    def segments(self) -> int:
        """Motion segments between the stationary windows."""
        return max(len(self.windows_s) - 1, 0)

    def summary(self) -> dict[str, Any]:
        """Header figures."""
        return {'bag': self.path, 'content hash (sha256)': self.sha256,
                'duration': f'{self.duration_s:.1f} s, {self.imu_samples} IMU samples at '
                            f'{self.imu_rate_hz:.4g} Hz',
                'plan segments detected': f'{len(self.windows_s)} stationary windows, '
                                          f'{self.segments} motion segments between them'}
