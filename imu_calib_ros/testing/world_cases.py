"""Named small world cases for tests, and the truth-vs-calibration comparison.

API
---
``make_case(tmp_path, unit='nav', size=1.0, mount_deg=0.0, offset_mm=0.0, latency_ms=0.0,
sample_type='interval_mean', joint_rate_hz=100.0, imu_rate_hz=100.0, seed=0,
plan='demo_short', fixture='three_axis', noise=True, **config) -> (bag, truth)``

Generates, with :mod:`imu_calib_ros.testing.world_sim` (the independent CONTRACT 1-3 world),
``tmp_path/<case>/bag`` (ROS 2 Jazzy mcap bag written with rosbags) and
``tmp_path/<case>/truth.yaml``, and returns the bag path and a :class:`CaseTruth`:

- ``unit``: ``nav``, ``tactical``, ``industrial_mems``, ``consumer_mems`` (raw errors scaled by
  ``size`` in (0, 1], see :mod:`~imu_calib_ros.testing.world_units`);
- ``mount_deg``: the mounting error, exactly this angle about a random axis (CONTRACT 2:
  ``R_enu_imu = chain * R_rpy * R_mount``); ``offset_mm``: reference-point offset of this
  length in a random direction;
- ``latency_ms``: joint stamps = true time + latency (CONTRACT 1, up to +-50 ms);
- ``sample_type``: ``'interval_mean'`` (CONTRACT 1 default) or ``'point'``;
- ``plan``: a plan name or path (``demo_short``: 185 s), or ``'random'``
  (``core.plans.random_plan(seed, count=12)``, about 3 min);
- ``fixture``: shipped name or path (the plain command's ``--fixture`` is
  ``truth.fixture_path``);
- ``**config``: any other :class:`~imu_calib_ros.testing.world_sim.WorldConfig` field
  (``wrap_joints=True``, ``drop_fraction_imu=0.01``, ``receipt_delay_s=(1.5e-3, 2.5e-3)``,
  ``joint_velocities=False``, ...).

Example (a test of the plain command)::

    from imu_calib_ros.testing.world_cases import make_case, compare_calibration
    bag, truth = make_case(tmp_path, unit='consumer_mems', size=1.0, mount_deg=10,
                           latency_ms=20, sample_type='point', joint_rate_hz=20, seed=3)
    # imu-calib replay {bag} --fixture {truth.fixture_path} --output {tmp_path}/c.yaml
    rows = compare_calibration(yaml.safe_load(open(calib)), truth.data)
    assert max(abs(r.z) for r in rows if r.sigma > 0) < 5

``CaseTruth`` has ``path`` (truth.yaml), ``fixture_path``, ``data`` (the truth mapping),
``errors`` (:class:`~imu_calib_ros.testing.world_units.UnitErrors`, turn-on biases),
``gyro_bias_at_end_rad_s`` / ``accel_bias_at_end_m_s2`` (what a filter tracking the total
bias should end at), ``mounting_rotvec_rad``, ``reference_point_imu_m``, ``latency_s``,
``sample_type``, ``unit_kind``.

``compare_calibration(calib, truth) -> list[Comparison]``: one row per free CONTRACT 4
parameter (bias against ``bias_at_end``; Kg's upper triangle; the six size-effect
coordinates), with ``group`` (bench_accuracy's target group names), ``error``, ``sigma``,
``z = error / sigma`` (inf for a non-zero error held at sigma 0), ``fixed``, and the
engineering unit (``scale``, ``unit``).
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .world_sim import (Mounting, WorldConfig, joint_profile, simulate_to_files,
                        fixture_path as _fixture_path)
from .world_units import UnitErrors, draw_unit

G0_M_S2 = 9.80665
_DEG_H = math.pi / 180.0 / 3600.0
_UG = 1e-6 * G0_M_S2
#: group -> (SI value of one engineering unit, unit name)
ENGINEERING_UNITS: dict[str, tuple[float, str]] = {
    'gyro_bias': (_DEG_H, 'deg/h'), 'gyro_scale': (1e-6, 'ppm'),
    'gyro_misalignment': (1e-6, 'urad'), 'gyro_asymmetry': (1e-6, 'ppm'),
    'gyro_g_sensitivity': (_DEG_H / G0_M_S2, 'deg/h/g'), 'accel_bias': (_UG, 'ug'),
    'accel_scale': (1e-6, 'ppm'), 'accel_misalignment': (1e-6, 'urad'),
    'accel_asymmetry': (1e-6, 'ppm'), 'accel_quadratic': (_UG / G0_M_S2 ** 2, 'ug/g^2'),
    'size_effect': (1e-3, 'mm'),
}
_AX = 'xyz'


@dataclass(frozen=True)
class CaseTruth:
    """Truth of a generated case (see module docstring)."""

    path: Path
    fixture_path: Path
    data: dict[str, Any]

    @property
    def _cal(self) -> dict[str, Any]:
        return self.data['imu_calibration']

    @property
    def errors(self) -> UnitErrors:
        """True constant errors (turn-on biases)."""
        g, a = self._cal['gyroscope'], self._cal['accelerometer']
        return UnitErrors(
            gyro_bias_rad_s=g['bias'], gyro_scale_misalignment=g['scale_misalignment'],
            gyro_scale_asymmetry=g['scale_asymmetry'],
            gyro_g_sensitivity_rad_s_per_m_s2=g['g_sensitivity'], accel_bias_m_s2=a['bias'],
            accel_scale_misalignment=a['scale_misalignment'],
            accel_scale_asymmetry=a['scale_asymmetry'],
            accel_quadratic_per_m_s2=a['quadratic'], size_effect_m=a['size_effect'])

    @property
    def gyro_bias_at_end_rad_s(self) -> np.ndarray:
        """Turn-on gyro bias plus the drift at the last sample [rad/s]."""
        return np.asarray(self._cal['bias_at_end']['gyro_rad_s'], dtype=float)

    @property
    def accel_bias_at_end_m_s2(self) -> np.ndarray:
        """Turn-on accelerometer bias plus the drift at the last sample [m/s^2]."""
        return np.asarray(self._cal['bias_at_end']['accel_m_s2'], dtype=float)

    @property
    def mounting_rotvec_rad(self) -> np.ndarray:
        """True mounting error as a rotation vector (IMU frame) [rad]."""
        return np.asarray(self._cal['mounting']['rotvec_rad'], dtype=float)

    @property
    def reference_point_imu_m(self) -> np.ndarray:
        """True reference point from the axes' common point, IMU frame [m]."""
        return np.asarray(self._cal['reference_point']['xyz_imu_m'], dtype=float)

    @property
    def latency_s(self) -> float:
        """Joint stamp minus true time [s]."""
        return float(self._cal['time']['joint_latency_s'])

    @property
    def sample_type(self) -> str:
        """``interval_mean`` or ``point``."""
        return str(self._cal['time']['sample_type'])

    @property
    def unit_kind(self) -> str:
        """Unit class."""
        return str(self._cal['unit']['kind'])


def load_truth(path: str | os.PathLike[str], fixture: str | os.PathLike[str] = '') -> CaseTruth:
    """Read a truth file written by :func:`~imu_calib_ros.testing.world_sim.write_truth`."""
    with open(path, encoding='utf-8') as fh:
        data = yaml.safe_load(fh)
    fx = fixture or data['imu_calibration']['provenance'].get('fixture', '')
    return CaseTruth(Path(path), Path(fx), data)


def make_case(tmp_path: str | os.PathLike[str], unit: str = 'nav', size: float = 1.0,
              mount_deg: float = 0.0, offset_mm: float = 0.0, latency_ms: float = 0.0,
              sample_type: str = 'interval_mean', joint_rate_hz: float = 100.0,
              imu_rate_hz: float = 100.0, seed: int = 0, plan: str = 'demo_short',
              fixture: str = 'three_axis', noise: bool = True,
              unit_noise: dict[str, Any] | None = None,
              **config: Any) -> tuple[Path, CaseTruth]:
    """Generate a named small case in ``tmp_path`` (module docstring); returns (bag, truth).
    ``unit_noise``: fields of the drawn unit's :class:`~.world_units.UnitNoise` to replace (a
    unit outside its class's noise ranges)."""
    fx_path = _fixture_path(fixture).resolve()
    name = (f'{unit}-s{size:g}-m{mount_deg:g}-o{offset_mm:g}-l{latency_ms:g}-{sample_type}'
            f'-j{joint_rate_hz:g}-i{imu_rate_hz:g}-{Path(str(plan)).stem}-{fx_path.stem}-{seed}')
    if config:  # other world options (a low-pass filter's tau, drops...): in the name too
        name += '-' + hashlib.sha256(repr(sorted(config.items())).encode()).hexdigest()[:8]
    if unit_noise:
        name += '-' + hashlib.sha256(repr(sorted(unit_noise.items())).encode()).hexdigest()[:8]
    out = Path(tmp_path) / name
    rng_unit, rng_mount, rng_plan = (np.random.default_rng(s) for s in
                                     np.random.SeedSequence([seed, 1]).spawn(3))
    if plan == 'random':
        from ..core.plans import random_plan
        plan_obj: Any = random_plan(int(rng_plan.integers(0, 2 ** 31)), 12)
    else:
        plan_obj = plan
    profile = joint_profile(plan_obj, fx_path)
    u = draw_unit(unit, size, rng_unit)
    if unit_noise:
        u = dataclasses.replace(u, noise=dataclasses.replace(u.noise, **unit_noise))

    def direction() -> np.ndarray:
        v = rng_mount.normal(size=3)
        return v / np.linalg.norm(v)
    mounting = Mounting(direction() * math.radians(mount_deg), direction() * offset_mm * 1e-3)
    cfg = WorldConfig(imu_rate_hz=imu_rate_hz, sample_type=sample_type,
                      joint_rate_hz=joint_rate_hz, joint_latency_s=latency_ms * 1e-3,
                      noise=noise, **config)
    bag, truth_path, _ = simulate_to_files(out, fx_path, profile, u, mounting, cfg, seed,
                                           provenance={'case': name})
    return bag, load_truth(truth_path, fx_path)


@dataclass(frozen=True)
class Comparison:
    """One free parameter: truth vs a calibration file (SI; ``scale`` = SI per eng. unit)."""

    name: str
    group: str
    key: str
    truth: float
    value: float
    sigma: float
    fixed: bool
    scale: float
    unit: str

    @property
    def error(self) -> float:
        """Estimate minus truth [SI]."""
        return self.value - self.truth

    @property
    def z(self) -> float:
        """error / sigma; inf for a non-zero error at sigma 0, 0 for an exact zero."""
        if self.sigma > 0.0:
            return self.error / self.sigma
        return 0.0 if self.error == 0.0 else math.copysign(math.inf, self.error)


def _entries(key: str) -> list[tuple[str, str, tuple[int, ...]]]:
    """(label, group, index) of the free values of one CONTRACT 4 key."""
    diag: list[tuple[int, ...]] = [(i,) * 2 for i in range(3)]
    upper: list[tuple[int, ...]] = [(0, 1), (0, 2), (1, 2)]
    off: list[tuple[int, ...]] = [(i, j) for i in range(3) for j in range(3) if i != j]
    full: list[tuple[int, ...]] = [(i, j) for i in range(3) for j in range(3)]
    vec: list[tuple[int, ...]] = [(i,) for i in range(3)]

    def lab(g: str, idx: tuple[int, ...]) -> str:
        # vectors and scale factors: one axis letter; other matrix entries: row, column
        axes = idx[:1] if len(idx) == 1 or g.endswith('_scale') else idx
        return f'{g}[{"".join(_AX[k] for k in axes)}]'
    table: dict[str, list[tuple[str, list[tuple[int, ...]]]]] = {
        'gyroscope.bias': [('gyro_bias', vec)],
        'gyroscope.scale_misalignment': [('gyro_scale', diag), ('gyro_misalignment', upper)],
        'gyroscope.scale_asymmetry': [('gyro_asymmetry', vec)],
        'gyroscope.g_sensitivity': [('gyro_g_sensitivity', full)],
        'accelerometer.bias': [('accel_bias', vec)],
        'accelerometer.scale_misalignment': [('accel_scale', diag), ('accel_misalignment', off)],
        'accelerometer.scale_asymmetry': [('accel_asymmetry', vec)],
        'accelerometer.quadratic': [('accel_quadratic', vec)],
        'accelerometer.size_effect': [('size_effect', off)],
    }
    return [(lab(g, idx), g, idx) for g, idxs in table[key] for idx in idxs]


PARAMETER_KEYS: tuple[str, ...] = (
    'gyroscope.bias', 'gyroscope.scale_misalignment', 'gyroscope.scale_asymmetry',
    'gyroscope.g_sensitivity', 'accelerometer.bias', 'accelerometer.scale_misalignment',
    'accelerometer.scale_asymmetry', 'accelerometer.quadratic', 'accelerometer.size_effect')


def compare_calibration(calib: dict[str, Any], truth: dict[str, Any],
                        bias_at_end: bool = True) -> list[Comparison]:
    """Rows of truth vs a CONTRACT 4 calibration mapping (module docstring).

    Parameters
    ----------
    calib, truth : dict
        Parsed YAML of the calibration file and of the world's truth file.
    bias_at_end : bool
        Compare the biases with ``bias_at_end`` (turn-on + drift at the last sample).
    """
    c, t = calib['imu_calibration'], truth['imu_calibration']
    fixed = set(c.get('fixed') or [])
    rows: list[Comparison] = []
    for key in PARAMETER_KEYS:
        sect, name = key.split('.')
        tv = np.asarray(t[sect][name], dtype=float)
        if bias_at_end and name == 'bias':
            tv = np.asarray(t['bias_at_end']['gyro_rad_s' if sect == 'gyroscope'
                                              else 'accel_m_s2'], dtype=float)
        cv = np.asarray(c[sect][name], dtype=float)
        sv = np.asarray(c['sigma'][sect][name], dtype=float)
        for label, group, idx in _entries(key):
            scale, unit = ENGINEERING_UNITS[group]
            rows.append(Comparison(label, group, key, float(tv[idx]), float(cv[idx]),
                                   float(sv[idx]), key in fixed, scale, unit))
    return rows


def plain_command_worst(bag: str | os.PathLike[str], fixture: str | os.PathLike[str],
                        truth: dict[str, Any], out: str | os.PathLike[str]
                        ) -> tuple[int, str, Comparison | None]:
    """CONTRACT 5's plain ``imu-calib replay BAG --fixture F --output OUT`` (``--quiet``), in
    process: its exit status, its stderr, and the estimated parameter farthest from
    ``truth`` in its own sigmas (:func:`compare_calibration`; None without a file)."""
    import contextlib
    import io
    from ..cli import main
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(['replay', str(bag), '--fixture', str(fixture), '--output', str(out),
                   '--quiet'])
    if rc != 0 or not Path(out).exists():
        return rc, err.getvalue(), None
    rows = [r for r in compare_calibration(yaml.safe_load(Path(out).read_text()), truth)
            if not r.fixed]
    return rc, err.getvalue(), max(rows, key=lambda r: abs(r.z))
