"""Noise characterisation of a unit: six Allan curves -> IEEE 952 terms, warnings, files.

The owner of what ``imu-calib noise`` writes (issue 13; CONTRACT 5):

- the IMU grade file (:mod:`.imu_grade`, ``replay --imu NOISE.yaml`` accepts it): white
  noise N, bias random walk K, quantum ``q = sqrt(12) Q``, and the flicker floor B as the
  grade's Gauss-Markov bias (sigma ``0.664 B / 0.62``, correlation time ``tau_B / 1.9``: the
  Gauss-Markov Allan deviation peaks at 0.62 sigma near 1.9 T_c, see :mod:`.imu_grade`),
  each the rms over the three axes of the values the record shows (0 where it shows none);
  the per-axis values with their 95 % intervals under ``noise_characterisation``;
- Kalibr's ``imu.yaml`` (ethz-asl/kalibr wiki, "IMU Noise Model"): ``*_noise_density`` is N
  [rad/s/sqrt(Hz), m/s^2/sqrt(Hz)], ``*_random_walk`` is K [rad/s^2/sqrt(Hz),
  m/s^3/sqrt(Hz)] (Kalibr's bias Wiener process), ``update_rate`` [Hz], ``rostopic``. Kalibr
  needs a positive random walk: where the record does not show K its 95 % upper bound is
  written, and the file says so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .allan import AllanCurve
from .noise_fit import TERMS, AxisFit, fit_axis

#: (sensor, first column, unit of the rate, unit per term)
SENSORS = (
    ('gyro', 0, 'rad/s', {'Q': 'rad', 'N': 'rad/s/sqrt(Hz)', 'B': 'rad/s',
                          'K': 'rad/s/sqrt(s)', 'R': 'rad/s^2'}),
    ('accel', 3, 'm/s^2', {'Q': 'm/s', 'N': 'm/s^2/sqrt(Hz)', 'B': 'm/s^2',
                           'K': 'm/s^2/sqrt(s)', 'R': 'm/s^3'}),
)
_AXES = 'xyz'
_TERM_NAME = {'Q': 'quantisation Q', 'N': 'white noise N', 'B': 'bias instability B',
              'K': 'rate random walk K', 'R': 'rate ramp R'}
#: Gauss-Markov peak of the Allan deviation: 0.62 sigma near tau = 1.9 T_c (imu_grade.py)
_GM_PEAK, _GM_TAU = 0.62, 1.9
_FLICKER_FLOOR = 0.664


@dataclass(frozen=True)
class NoiseResult:
    """The Allan curves and fits of the six channels (gyro x, y, z, accel x, y, z)."""

    curve: AllanCurve
    fits: tuple[AxisFit, ...]
    source: str  # 'static record' or 'N stationary windows'

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.curve.tau0_s

    def value(self, sensor: str, term: str) -> float:
        """rms over the three axes of the values shown (0 when no axis shows the term)."""
        col = _column(sensor)
        vals = [f.terms[term].value for f in self.fits[col:col + 3]]
        shown = [v for v in vals if v is not None]
        return float(np.sqrt(np.mean(np.square(shown)))) if shown else 0.0

    def bound(self, sensor: str, term: str) -> float:
        """The value, or where no axis shows it the largest 95 % upper bound."""
        v = self.value(sensor, term)
        if v > 0:
            return v
        col = _column(sensor)
        return float(max(f.terms[term].high for f in self.fits[col:col + 3]))

    def warnings(self) -> list[str]:
        """One plain line per problem: terms the record does not show, bumps, drifts."""
        out: list[str] = []
        dur = self.curve.duration_s
        for sensor, col, _, units in SENSORS:
            fits = self.fits[col:col + 3]
            for term in ('N', 'B', 'K'):
                missing = [_AXES[a] for a, f in enumerate(fits) if not f.terms[term].shown]
                if missing:
                    bound = max(fits[_AXES.index(a)].terms[term].high for a in missing)
                    longest = float(self.curve.tau_s[-1]) if len(self.curve.tau_s) else 0.0
                    out.append(
                        f'{sensor} {",".join(missing)}: {_TERM_NAME[term]} not shown by the '
                        f'record ({self.source}, {dur:.0f} s, taus up to {longest:.3g} s): '
                        f'below {bound:.3g} {units[term]} (95 %)'
                        + ('; too short a record, or the unit has none' if term != 'N'
                           else ''))
            for a, f in enumerate(fits):
                for lo, hi, ratio in f.bumps:
                    out.append(f'{sensor} {_AXES[a]}: the Allan deviation stands {ratio:.2g}x '
                               f'above the noise model at tau {lo:.3g}-{hi:.3g} s (vibration, '
                               'a disturbance?): the static assumption fails there; those taus '
                               'are left out of the fit')
                r = f.terms['R']
                if r.shown:
                    out.append(f'{sensor} {_AXES[a]}: a rate ramp (+1 slope) R = {r.value:.3g} '
                               f'{units["R"]} dominates the long taus: the output drifts (tilt, '
                               'temperature), the static assumption fails there')
        return out

    # ------------------------------------------------------------------------- files
    def grade_dict(self, name: str = 'measured') -> dict[str, Any]:
        """The :class:`~.imu_grade.ImuGrade` mapping (``{'imu_grade': {...}}``) plus details."""
        g: dict[str, Any] = {'name': name, 'description': (
            f'measured by imu-calib noise from a {self.source} of {self.curve.duration_s:.0f} s '
            f'at {self.rate_hz:.6g} Hz (rms over axes of the terms the record shows)')}
        for sensor, prefix, n_key, k_key, b_key, c_key, q_key in (
                ('gyro', 'gyro', 'gyro_noise_rad_s_rt_hz', 'gyro_bias_random_walk_rad_s2_rt_hz',
                 'gyro_bias_instability_rad_s', 'gyro_bias_correlation_s',
                 'gyro_quantization_rad'),
                ('accel', 'accel', 'accel_noise_m_s2_rt_hz', 'accel_bias_random_walk_m_s3_rt_hz',
                 'accel_bias_instability_m_s2', 'accel_bias_correlation_s',
                 'accel_quantization_m_s')):
            g[n_key] = self.value(sensor, 'N')
            g[k_key] = self.value(sensor, 'K')
            b = self.value(sensor, 'B')
            g[b_key] = _FLICKER_FLOOR * b / _GM_PEAK
            col = _column(sensor)
            taus = [f.terms['B'].tau_s for f in self.fits[col:col + 3] if f.terms['B'].shown]
            g[c_key] = float(np.median(taus)) / _GM_TAU if taus else 3600.0  # type: ignore[arg-type]
            g[q_key] = math.sqrt(12.0) * self.value(sensor, 'Q')
        return {'imu_grade': g, 'noise_characterisation': self.details()}

    def details(self) -> dict[str, Any]:
        """Per-axis terms with 95 % intervals (or upper bounds), units, the record, warnings."""
        axes: dict[str, Any] = {}
        for sensor, col, _, units in SENSORS:
            for a in range(3):
                f = self.fits[col + a]
                axes[f'{sensor}_{_AXES[a]}'] = {
                    t: {**f.terms[t].as_dict(), 'unit': units[t]} for t in TERMS}
        return {'method': 'overlapping Allan deviation, IEEE Std 952-1997 annex C terms, '
                          '95 % intervals (chi-square, Greenhall edf)',
                'source': self.source, 'rate_hz': self.rate_hz,
                'duration_s': self.curve.duration_s, 'samples': self.curve.n_samples,
                'axes': axes, 'warnings': self.warnings()}

    def kalibr_dict(self, rostopic: str) -> tuple[dict[str, Any], list[str]]:
        """Kalibr's ``imu.yaml`` mapping and its comment lines."""
        d = {'accelerometer_noise_density': self.value('accel', 'N'),
             'accelerometer_random_walk': self.bound('accel', 'K'),
             'gyroscope_noise_density': self.value('gyro', 'N'),
             'gyroscope_random_walk': self.bound('gyro', 'K'),
             'rostopic': rostopic, 'update_rate': self.rate_hz}
        notes = ['Kalibr IMU noise model (ethz-asl/kalibr wiki "IMU Noise Model"), written by '
                 'imu-calib noise',
                 'noise_density: white noise N [m/s^2/sqrt(Hz), rad/s/sqrt(Hz)]; random_walk: '
                 'bias random walk K [m/s^3/sqrt(Hz), rad/s^2/sqrt(Hz)]; update_rate [Hz]',
                 'values as measured (rms over axes); Kalibr\'s authors advise inflating them '
                 'for real motion']
        for sensor, key in (('accel', 'accelerometer_random_walk'),
                            ('gyro', 'gyroscope_random_walk')):
            if self.value(sensor, 'K') == 0.0:
                notes.append(f'{key}: the record does not show a rate random walk; this is its '
                             '95 % upper bound')
        return d, notes


def _column(sensor: str) -> int:
    return {'gyro': 0, 'accel': 3}[sensor]


def characterise(curve: AllanCurve, source: str) -> NoiseResult:
    """Fit the six channels of ``curve`` (gyro x, y, z, accel x, y, z)."""
    if curve.adev.shape[1] != 6:
        raise ValueError('expected six channels: gyro x, y, z, accel x, y, z')
    return NoiseResult(curve, tuple(fit_axis(curve, a) for a in range(6)), source)
