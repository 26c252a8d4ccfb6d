"""What the report shows of the bag itself: content hash, joint timeline with the detected
plan segments, and the noise of the stationary windows (issue 12).

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


def windows_noise(gyro: FloatArray, accel: FloatArray, dt_s: float,
                  windows: list[tuple[int, int]]) -> Any:
    """The noise of the stationary windows ``[(i0, i1), ...]``: the same overlapping Allan
    deviation (one segment per window) and IEEE 952 fit as ``imu-calib noise`` on a
    calibration bag (:func:`~imu_calib_ros.core.noise_characterisation.characterise`); None
    when no window holds 12 samples."""
    from ..core.allan import windows_accumulator
    from ..core.noise_characterisation import characterise
    wins = [(a, b) for a, b in windows if b - a >= 12]
    if not wins:
        return None
    curve = windows_accumulator(gyro, accel, dt_s, wins).curve()
    if len(curve.tau_s) < 2:
        return None
    return characterise(curve, f'{len(wins)} stationary windows')


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
    allan: Any = None  # core.noise_characterisation.NoiseResult of the windows
    nav: dict[str, tuple[FloatArray, FloatArray]] = field(default_factory=dict)
    # (t, rms velocity spread (T, 3), draws): navigations with calibrations drawn from the
    # file's sigmas about 'this calibration' (the expected error envelope), or None
    envelope: tuple[FloatArray, FloatArray, int] | None = None

    @property
    def segments(self) -> int:
        """Motion segments between the stationary windows."""
        return max(len(self.windows_s) - 1, 0)

    def segment_moves(self, min_deg: float = 0.5) -> list[str]:
        """Each motion segment as the joints it turned and by how much, between the means of
        the stationary windows around it: ``'inner +90'``, ``'middle -90 inner +180'``."""
        t, q = self.t_joint_s, self.q_deg
        means = []
        for a, b in self.windows_s:
            k = (t >= a) & (t <= b)
            means.append(q[k].mean(axis=0) if k.any() else
                         q[min(int(np.searchsorted(t, a)), len(t) - 1)])
        out = []
        for m0, m1 in zip(means[:-1], means[1:]):
            d = m1 - m0
            moved = [f'{n} {v:+.0f}' for n, v in zip(self.joint_names, d) if abs(v) >= min_deg]
            out.append(' '.join(moved) or 'no net turn')
        return out

    def summary(self) -> dict[str, Any]:
        """Header figures."""
        return {'bag': self.path, 'content hash (sha256)': self.sha256,
                'duration': f'{self.duration_s:.1f} s, {self.imu_samples} IMU samples at '
                            f'{self.imu_rate_hz:.4g} Hz',
                'plan segments detected': f'{len(self.windows_s)} stationary windows, '
                                          f'{self.segments} motion segments between them'
                                          + _moves_text(self.segment_moves())}


def _moves_text(moves: list[str]) -> str:
    """The segments' turns in order (deg), or, past 24 of them, how often each occurs."""
    if not moves:
        return ''
    if len(moves) <= 24:
        return ': ' + '; '.join(moves) + ' (deg)'
    from collections import Counter
    return ': ' + '; '.join(f'{m} x{n}' for m, n in Counter(moves).most_common()) + ' (deg)'
