"""IMU grade presets: noise densities, bias stability and typical constant-error magnitudes.

A grade (``config/imus/NAME.yaml``, SI units, engineering values in comments) serves two
users: the simulator draws the true constant errors from its one-sigma magnitudes and adds
its noise; the estimator takes the same magnitudes as a hint for its initial covariance.
A file without the ``sigma:`` block (what ``imu-calib noise`` writes: a measured noise model)
states no constant errors: ``sigma`` is None, the estimator's priors come from the data alone
(``estimator/priors.py``), and the simulator refuses to draw errors from it. A ``sigma:``
value of 0 is a statement too: that error does not exist (an optical gyro's g-sensitivity).

Noise terms (IEEE Std 952-1997 / 1293-1998 names):

- ``*_noise_*_rt_hz``: white rate/specific-force noise density N (angle/velocity random walk);
  the mean over an interval ``dt`` then has the standard deviation ``N / sqrt(dt)``.
- ``*_bias_instability_*`` with ``*_bias_correlation_s``: a first-order Gauss-Markov bias
  of that steady-state standard deviation and correlation time (its Allan deviation peaks at
  about 0.62 sigma near tau = 1.9 T_c, close to the 0.664 B flicker floor of a datasheet's
  bias instability B).
- ``*_bias_random_walk_*``: rate random walk K (bias drifts as a Wiener process).
- ``*_quantization_*``: increment quantum (rad, m/s) of an integrating output; 0 = none.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from .config import from_mapping, load_yaml, resolve_config_file
from .errors import ConfigError
from .sensor_model import SensorErrors

_NONNEG = {'min': 0.0}


@dataclass(frozen=True)
class ErrorSigmas:
    """One-sigma magnitudes of the constant errors of CONTRACT 3 (SI, dimensionless = ratio)."""

    gyro_bias_rad_s: float = field(default=0.0, metadata=_NONNEG)
    gyro_scale: float = field(default=0.0, metadata=_NONNEG)
    gyro_misalignment_rad: float = field(default=0.0, metadata=_NONNEG)
    gyro_asymmetry: float = field(default=0.0, metadata=_NONNEG)
    gyro_g_sensitivity: float = field(default=0.0, metadata=_NONNEG)  # (rad/s)/(m/s^2)
    accel_bias_m_s2: float = field(default=0.0, metadata=_NONNEG)
    accel_scale: float = field(default=0.0, metadata=_NONNEG)
    accel_misalignment_rad: float = field(default=0.0, metadata=_NONNEG)
    accel_asymmetry: float = field(default=0.0, metadata=_NONNEG)
    accel_quadratic: float = field(default=0.0, metadata=_NONNEG)  # 1/(m/s^2)
    size_effect_m: float = field(default=0.0, metadata=_NONNEG)


@dataclass(frozen=True)
class ImuGrade:
    """Noise model and constant-error magnitudes of one class of IMU (see module docstring)."""

    name: str
    description: str = ''
    gyro_noise_rad_s_rt_hz: float = field(default=0.0, metadata=_NONNEG)
    gyro_bias_instability_rad_s: float = field(default=0.0, metadata=_NONNEG)
    gyro_bias_correlation_s: float = field(default=3600.0, metadata={'min': 1e-3})
    gyro_bias_random_walk_rad_s2_rt_hz: float = field(default=0.0, metadata=_NONNEG)
    accel_noise_m_s2_rt_hz: float = field(default=0.0, metadata=_NONNEG)
    accel_bias_instability_m_s2: float = field(default=0.0, metadata=_NONNEG)
    accel_bias_correlation_s: float = field(default=3600.0, metadata={'min': 1e-3})
    accel_bias_random_walk_m_s3_rt_hz: float = field(default=0.0, metadata=_NONNEG)
    gyro_quantization_rad: float = field(default=0.0, metadata=_NONNEG)
    accel_quantization_m_s: float = field(default=0.0, metadata=_NONNEG)
    sigma: ErrorSigmas | None = None  # None: a noise model only (see the module docstring)

    def noise_dict(self) -> dict[str, float]:
        """The noise terms as a plain dict (for truth/provenance files)."""
        keys = ('gyro_noise_rad_s_rt_hz', 'gyro_bias_instability_rad_s',
                'gyro_bias_correlation_s', 'gyro_bias_random_walk_rad_s2_rt_hz',
                'accel_noise_m_s2_rt_hz', 'accel_bias_instability_m_s2',
                'accel_bias_correlation_s', 'accel_bias_random_walk_m_s3_rt_hz',
                'gyro_quantization_rad', 'accel_quantization_m_s')
        return {k: float(getattr(self, k)) for k in keys}

    def without_noise(self) -> 'ImuGrade':
        """The same grade with every stochastic term zero (for exactness tests)."""
        return ImuGrade(self.name, self.description, gyro_bias_correlation_s=(
            self.gyro_bias_correlation_s), accel_bias_correlation_s=self.accel_bias_correlation_s,
            sigma=self.sigma)


def load_grade(name_or_path: str | os.PathLike[str]) -> ImuGrade:
    """Load a grade by shipped name (``'nav_grade'``, ``'mems_mti1'``) or by file path.

    Raises
    ------
    ConfigError
        Missing file, malformed YAML, unknown or missing key, negative value.
    """
    path = resolve_config_file(str(name_or_path), 'imus')
    data = load_yaml(path)
    if not isinstance(data, dict) or 'imu_grade' not in data:
        raise ConfigError('expected a top-level key imu_grade', str(path), 'imu_grade')
    grade = from_mapping(ImuGrade, data['imu_grade'], str(path), prefix='imu_grade')
    for name in ('gyro_bias_correlation_s', 'accel_bias_correlation_s'):
        if not math.isfinite(getattr(grade, name)):
            raise ConfigError('must be finite', str(path), f'imu_grade.{name}')
    return grade


def draw_errors(grade: ImuGrade, rng: np.random.Generator) -> SensorErrors:
    """Draw random true constant errors with the grade's one-sigma magnitudes.

    Every element is an independent zero-mean normal variable. ``Kg`` is symmetric
    (CONTRACT 3 defines the body frame by that): its diagonal has sigma ``gyro_scale`` and
    each of its three distinct off-diagonal pairs sigma ``gyro_misalignment_rad`` (Savage's
    MARS convention kappa_ij = kappa_ji). ``Ka`` has six free off-diagonal misalignments.
    The size-effect matrix has a zero diagonal (Kozlov & Kapralov: r_ii = 0).

    Parameters
    ----------
    grade:
        Source of the sigmas.
    rng:
        numpy Generator; the draw order is fixed, so a seed reproduces the errors.
    """
    s = grade.sigma
    if s is None:
        raise ConfigError('the grade states no constant errors (no sigma: block), so no '
                          'errors can be drawn from it; give one with a sigma: block',
                          grade.name, 'imu_grade.sigma')
    off = ~np.eye(3, dtype=bool)

    def full(scale_sigma: float, mis_sigma: float) -> np.ndarray:
        m = rng.normal(0.0, 1.0, (3, 3))
        return np.where(off, m * mis_sigma, m * scale_sigma)

    gyro_bias = rng.normal(0.0, s.gyro_bias_rad_s, 3)
    kg = full(s.gyro_scale, s.gyro_misalignment_rad)
    kg = np.triu(kg) + np.triu(kg, 1).T  # symmetric: upper triangle mirrored
    gyro_asym = rng.normal(0.0, s.gyro_asymmetry, 3)
    gyro_g = rng.normal(0.0, s.gyro_g_sensitivity, (3, 3))
    accel_bias = rng.normal(0.0, s.accel_bias_m_s2, 3)
    ka = full(s.accel_scale, s.accel_misalignment_rad)
    accel_asym = rng.normal(0.0, s.accel_asymmetry, 3)
    accel_quad = rng.normal(0.0, s.accel_quadratic, 3)
    size = np.where(off, rng.normal(0.0, s.size_effect_m, (3, 3)), 0.0)
    return SensorErrors(
        gyro_bias_rad_s=gyro_bias,
        gyro_scale_misalignment=kg,
        gyro_scale_asymmetry=gyro_asym,
        gyro_g_sensitivity_rad_s_per_m_s2=gyro_g,
        accel_bias_m_s2=accel_bias,
        accel_scale_misalignment=ka,
        accel_scale_asymmetry=accel_asym,
        accel_quadratic_per_m_s2=accel_quad,
        size_effect_m=size,
    )
