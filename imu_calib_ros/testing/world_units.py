"""Unit classes of the world oracle: raw (uncalibrated) errors and noise of real IMUs.

The values below are this module's own, taken from typical data sheets of each class; they
are deliberately NOT read from ``config/imus`` (the grade files are the estimator's prior and
must not define the test's truth). Every constant error of CONTRACT section 3 is drawn
uniformly with a random sign up to ``size`` times the class's maximum, so ``size = 1`` reaches
the maximum and ``size = 0.2`` gives a fifth of it; the noise terms are drawn uniformly
within the class's range (they do not scale with ``size``).

Constant errors at ``size = 1`` (each element ``size * max * U(-1, 1)`` unless a range is
given; a range ``lo..hi`` means magnitude ``size * U(lo, hi)`` with a random sign):

==================  ==================  ==================  ==================  ==================
term                nav (RLG/FOG)       tactical            industrial_mems     consumer_mems
==================  ==================  ==================  ==================  ==================
gyro bias           1 deg/h             1 deg/h             1 deg/s             1 deg/s
gyro scale (Kg ii)  1 %                 1 %                 3 %                 3 %
gyro misalign (ij)  10 mrad             10 mrad             30 mrad             30 mrad
gyro asymmetry      0.1 %               0.1 %               0.3 %               0.3 %
gyro G (9 terms)    0                   0.2..2 deg/h/g      0.01..0.1 (deg/s)/g 0.01..0.1 (deg/s)/g
accel bias          10 mg               10 mg               100 mg              100 mg
accel scale         1 %                 1 %                 3 %                 3 %
accel misalign      10 mrad             10 mrad             30 mrad             30 mrad
accel asymmetry     0.1 %               0.1 %               0.3 %               0.3 %
accel quadratic     10..100 ug/g^2      10..100 ug/g^2      10..100 ug/g^2      10..100 ug/g^2
size effect r_ij    20 mm               20 mm               3 mm                3 mm
==================  ==================  ==================  ==================  ==================

Noise (IEEE Std 952 terms; uniform in the range; GM = first-order Gauss-Markov bias
instability with steady-state sigma and correlation time; RW = bias random walk density):

==================  ==================  ==================  ==================  ==================
term                nav                 tactical            industrial_mems     consumer_mems
==================  ==================  ==================  ==================  ==================
ARW                 0.002-0.005         0.05-0.15           0.002-0.005         0.01-0.02
                    deg/sqrt(h)         deg/sqrt(h)         deg/s/sqrt(Hz)      deg/s/sqrt(Hz)
VRW                 5-20 ug/sqrt(Hz)    30-60 ug/sqrt(Hz)   60-100 ug/sqrt(Hz)  150-300 ug/sqrt(Hz)
gyro GM sigma, tau  0.001-0.003 deg/h,  0.1-0.5 deg/h,      1-3 deg/h, 100 s    3-10 deg/h, 100 s
                    3600 s              600 s
gyro RW             0                   0                   0.5 deg/h/sqrt(h)   3 deg/h/sqrt(h)
accel GM sigma, tau 2-5 ug, 3600 s      10-50 ug, 600 s     5-15 ug, 100 s      30-100 ug, 100 s
accel RW            0                   0                   0.5 ug/sqrt(s)      2 ug/sqrt(s)
quantisation        increments 0.1 urad increments 1 urad   values 0.00625 deg/s values 0.061 deg/s
                    / 1e-6 m/s          / 1e-5 m/s          / 0.25 mg           / 0.488 mg
==================  ==================  ==================  ==================  ==================

Increment quantisation (optical units, interval-mean output) carries the residual like a
pulse counter; value quantisation (MEMS registers) rounds each output to its LSB.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: standard gravity, the "g" of mg, ug and (deg/s)/g [m/s^2]
G0_M_S2 = 9.80665
_DEG = math.pi / 180.0
_DEG_H = _DEG / 3600.0  # rad/s per deg/h
_UG = 1e-6 * G0_M_S2  # m/s^2 per ug

#: the unit classes :func:`draw_unit` knows
UNIT_KINDS: tuple[str, ...] = ('nav', 'tactical', 'industrial_mems', 'consumer_mems')


@dataclass(frozen=True)
class UnitErrors:
    """Constant errors of CONTRACT section 3 (all SI; arrays are copied and made read-only).

    ``gyro_scale_misalignment`` (Kg) must be symmetric: CONTRACT 3 defines the body frame
    as the one in which it is; ``size_effect_m`` row i is r_i with r_i[i] = 0.
    """

    gyro_bias_rad_s: FloatArray  # (3,) bg
    gyro_scale_misalignment: FloatArray  # (3, 3) Kg, symmetric
    gyro_scale_asymmetry: FloatArray  # (3,) ag
    gyro_g_sensitivity_rad_s_per_m_s2: FloatArray  # (3, 3) G
    accel_bias_m_s2: FloatArray  # (3,) ba
    accel_scale_misalignment: FloatArray  # (3, 3) Ka
    accel_scale_asymmetry: FloatArray  # (3,) aa
    accel_quadratic_per_m_s2: FloatArray  # (3,) qa
    size_effect_m: FloatArray  # (3, 3) row i = r_i

    def __post_init__(self) -> None:
        for f in fields(self):
            a = np.array(getattr(self, f.name), dtype=float)
            want = (3, 3) if f.name in _MATRICES else (3,)
            if a.shape != want or not np.all(np.isfinite(a)):
                raise ValueError(f'{f.name}: expected finite values of shape {want}')
            a.setflags(write=False)
            object.__setattr__(self, f.name, a)
        kg = self.gyro_scale_misalignment
        if np.max(np.abs(kg - kg.T)) > 0.0:
            raise ValueError('gyro_scale_misalignment must be symmetric (CONTRACT 3)')
        if np.any(np.diag(self.size_effect_m) != 0.0):
            raise ValueError('size_effect_m must have a zero diagonal (CONTRACT 3)')

    @classmethod
    def zeros(cls) -> 'UnitErrors':
        """An error-free unit."""
        return cls(**{f.name: np.zeros((3, 3) if f.name in _MATRICES else 3)
                      for f in fields(cls)})

    def replace(self, **changes: Any) -> 'UnitErrors':
        """A copy with some fields replaced."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d.update(changes)
        return UnitErrors(**d)

    def to_contract(self) -> dict[str, dict[str, Any]]:
        """``gyroscope`` and ``accelerometer`` blocks of CONTRACT section 4 (plain lists)."""
        def lst(a: FloatArray) -> Any:
            return [[float(x) for x in row] for row in a] if a.ndim == 2 else \
                [float(x) for x in a]
        return {
            'gyroscope': {
                'bias': lst(self.gyro_bias_rad_s),
                'scale_misalignment': lst(self.gyro_scale_misalignment),
                'scale_asymmetry': lst(self.gyro_scale_asymmetry),
                'g_sensitivity': lst(self.gyro_g_sensitivity_rad_s_per_m_s2)},
            'accelerometer': {
                'bias': lst(self.accel_bias_m_s2),
                'scale_misalignment': lst(self.accel_scale_misalignment),
                'scale_asymmetry': lst(self.accel_scale_asymmetry),
                'quadratic': lst(self.accel_quadratic_per_m_s2),
                'size_effect': lst(self.size_effect_m)},
        }


_MATRICES = frozenset({'gyro_scale_misalignment', 'gyro_g_sensitivity_rad_s_per_m_s2',
                       'accel_scale_misalignment', 'size_effect_m'})


@dataclass(frozen=True)
class UnitNoise:
    """Stochastic errors of one unit (SI). Zero everywhere: a noise-free unit.

    ``quantization`` is ``'increment'`` (quanta of ``value * dt`` with the residual carried,
    an integrating unit's pulse counter; ``*_quantum`` in rad and m/s) or ``'value'`` (each
    output rounded to its LSB; ``*_quantum`` in rad/s and m/s^2).
    """

    gyro_noise_rad_s_rt_hz: float = 0.0
    accel_noise_m_s2_rt_hz: float = 0.0
    gyro_bias_instability_rad_s: float = 0.0
    gyro_bias_correlation_s: float = 3600.0
    gyro_bias_random_walk_rad_s2_rt_hz: float = 0.0
    accel_bias_instability_m_s2: float = 0.0
    accel_bias_correlation_s: float = 3600.0
    accel_bias_random_walk_m_s3_rt_hz: float = 0.0
    quantization: str = 'increment'
    gyro_quantum: float = 0.0
    accel_quantum: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (truth file ``noise:`` block)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class Unit:
    """A drawn unit: its class, the error size it was drawn with, its errors and noise."""

    kind: str
    size: float
    errors: UnitErrors
    noise: UnitNoise


@dataclass(frozen=True)
class _ClassSpec:
    arw_rad_s_rt_hz: tuple[float, float]
    vrw_m_s2_rt_hz: tuple[float, float]
    gyro_bias_rad_s: float
    scale: float
    misalignment_rad: float
    accel_bias_m_s2: float
    g_sensitivity: tuple[float, float]  # magnitude range, (rad/s)/(m/s^2)
    size_effect_m: float
    gyro_gm: tuple[float, float]
    gyro_tau_s: float
    gyro_rw: float
    accel_gm: tuple[float, float]
    accel_tau_s: float
    accel_rw: float
    quantization: str
    gyro_quantum: float
    accel_quantum: float


_SQRT_H = 60.0  # sqrt(3600 s)
_MEMS_G = (0.01 * _DEG / G0_M_S2, 0.1 * _DEG / G0_M_S2)
SPECS: dict[str, _ClassSpec] = {
    'nav': _ClassSpec(
        arw_rad_s_rt_hz=(0.002 * _DEG / _SQRT_H, 0.005 * _DEG / _SQRT_H),
        vrw_m_s2_rt_hz=(5 * _UG, 20 * _UG), gyro_bias_rad_s=1.0 * _DEG_H, scale=0.01,
        misalignment_rad=0.010, accel_bias_m_s2=10e-3 * G0_M_S2, g_sensitivity=(0.0, 0.0),
        size_effect_m=0.020, gyro_gm=(0.001 * _DEG_H, 0.003 * _DEG_H), gyro_tau_s=3600.0,
        gyro_rw=0.0, accel_gm=(2 * _UG, 5 * _UG), accel_tau_s=3600.0, accel_rw=0.0,
        quantization='increment', gyro_quantum=1e-7, accel_quantum=1e-6),
    'tactical': _ClassSpec(
        arw_rad_s_rt_hz=(0.05 * _DEG / _SQRT_H, 0.15 * _DEG / _SQRT_H),
        vrw_m_s2_rt_hz=(30 * _UG, 60 * _UG), gyro_bias_rad_s=1.0 * _DEG_H, scale=0.01,
        misalignment_rad=0.010, accel_bias_m_s2=10e-3 * G0_M_S2,
        g_sensitivity=(0.2 * _DEG_H / G0_M_S2, 2.0 * _DEG_H / G0_M_S2),
        size_effect_m=0.020, gyro_gm=(0.1 * _DEG_H, 0.5 * _DEG_H), gyro_tau_s=600.0,
        gyro_rw=0.0, accel_gm=(10 * _UG, 50 * _UG), accel_tau_s=600.0, accel_rw=0.0,
        quantization='increment', gyro_quantum=1e-6, accel_quantum=1e-5),
    'industrial_mems': _ClassSpec(
        arw_rad_s_rt_hz=(0.002 * _DEG, 0.005 * _DEG), vrw_m_s2_rt_hz=(60 * _UG, 100 * _UG),
        gyro_bias_rad_s=1.0 * _DEG, scale=0.03, misalignment_rad=0.030,
        accel_bias_m_s2=100e-3 * G0_M_S2, g_sensitivity=_MEMS_G, size_effect_m=0.003,
        gyro_gm=(1.0 * _DEG_H, 3.0 * _DEG_H), gyro_tau_s=100.0,
        gyro_rw=0.5 * _DEG_H / _SQRT_H, accel_gm=(5 * _UG, 15 * _UG), accel_tau_s=100.0,
        accel_rw=0.5 * _UG, quantization='value', gyro_quantum=0.00625 * _DEG,
        accel_quantum=0.25e-3 * G0_M_S2),
    'consumer_mems': _ClassSpec(
        arw_rad_s_rt_hz=(0.01 * _DEG, 0.02 * _DEG), vrw_m_s2_rt_hz=(150 * _UG, 300 * _UG),
        gyro_bias_rad_s=1.0 * _DEG, scale=0.03, misalignment_rad=0.030,
        accel_bias_m_s2=100e-3 * G0_M_S2, g_sensitivity=_MEMS_G, size_effect_m=0.003,
        gyro_gm=(3.0 * _DEG_H, 10.0 * _DEG_H), gyro_tau_s=100.0,
        gyro_rw=3.0 * _DEG_H / _SQRT_H, accel_gm=(30 * _UG, 100 * _UG), accel_tau_s=100.0,
        accel_rw=2.0 * _UG, quantization='value', gyro_quantum=0.061 * _DEG,
        accel_quantum=0.488e-3 * G0_M_S2),
}
#: asymmetry maximum as a fraction of the scale maximum
ASYMMETRY_FRACTION = 0.1
#: accelerometer quadratic error magnitude range [ug/g^2]
QUADRATIC_UG_G2 = (10.0, 100.0)


def draw_unit(kind: str, size: float, rng: np.random.Generator) -> Unit:
    """Draw a raw unit of class ``kind`` with constant errors scaled by ``size``.

    Parameters
    ----------
    kind : str
        One of :data:`UNIT_KINDS` (table in the module docstring).
    size : float
        In (0, 1]: the fraction of the class's maximum raw error (CONTRACT 5: raw units).
    rng : numpy.random.Generator

    Returns
    -------
    Unit
        Kg symmetric (CONTRACT 3 body frame), Ka full, size effect with zero diagonal.
    """
    if kind not in SPECS:
        raise ValueError(f'unknown unit kind {kind!r} (known: {", ".join(UNIT_KINDS)})')
    if not 0.0 < size <= 1.0:
        raise ValueError(f'size must be in (0, 1], got {size}')
    s = SPECS[kind]

    def sym(mx: float, n: int | tuple[int, ...]) -> FloatArray:
        return size * mx * rng.uniform(-1.0, 1.0, n)

    def mag(lo: float, hi: float, n: int | tuple[int, ...]) -> FloatArray:
        return size * rng.uniform(lo, hi, n) * rng.choice([-1.0, 1.0], n)

    kg = np.diag(sym(s.scale, 3))
    off = sym(s.misalignment_rad, 3)
    for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):
        kg[i, j] = kg[j, i] = off[k]
    ka = sym(s.misalignment_rad, (3, 3))
    np.fill_diagonal(ka, sym(s.scale, 3))
    r = sym(s.size_effect_m, (3, 3))
    np.fill_diagonal(r, 0.0)
    q_lo, q_hi = (x * _UG / G0_M_S2 ** 2 for x in QUADRATIC_UG_G2)
    errors = UnitErrors(
        gyro_bias_rad_s=sym(s.gyro_bias_rad_s, 3),
        gyro_scale_misalignment=kg,
        gyro_scale_asymmetry=sym(ASYMMETRY_FRACTION * s.scale, 3),
        gyro_g_sensitivity_rad_s_per_m_s2=mag(*s.g_sensitivity, (3, 3)),
        accel_bias_m_s2=sym(s.accel_bias_m_s2, 3),
        accel_scale_misalignment=ka,
        accel_scale_asymmetry=sym(ASYMMETRY_FRACTION * s.scale, 3),
        accel_quadratic_per_m_s2=mag(q_lo, q_hi, 3),
        size_effect_m=r)
    noise = UnitNoise(
        gyro_noise_rad_s_rt_hz=float(rng.uniform(*s.arw_rad_s_rt_hz)),
        accel_noise_m_s2_rt_hz=float(rng.uniform(*s.vrw_m_s2_rt_hz)),
        gyro_bias_instability_rad_s=float(rng.uniform(*s.gyro_gm)),
        gyro_bias_correlation_s=s.gyro_tau_s,
        gyro_bias_random_walk_rad_s2_rt_hz=s.gyro_rw,
        accel_bias_instability_m_s2=float(rng.uniform(*s.accel_gm)),
        accel_bias_correlation_s=s.accel_tau_s,
        accel_bias_random_walk_m_s3_rt_hz=s.accel_rw,
        quantization=s.quantization, gyro_quantum=s.gyro_quantum,
        accel_quantum=s.accel_quantum)
    return Unit(kind, float(size), errors, noise)
