"""Per-sample compensation of a raw IMU stream with a calibration, and its covariances.

:class:`StreamCompensation` wraps :func:`imu_calib_ros.core.sensor_model.compensate_one`
(the same bits as ``compensate``) for one sample at a time, so that the compensator node,
the calibration node and offline code use literally the same code (issue 14 item 2: it was
in ``nodes/common.py``). Plain Python floats, no rclpy.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .types import GAP_PERIODS


class StreamCompensation:
    """Compensate one raw IMU sample at a time with a calibration; covariances for the message.

    The values are :func:`imu_calib_ros.core.sensor_model.compensate_one` (the same bits as
    ``compensate`` on ``(1, 3)`` arrays) with ``omega_dot_imu`` the backward difference of
    consecutive raw mean rates (``sensor_model.mean_rate_derivative(causal=True)``: Kozlov &
    Kapralov eq. 1 needs the angular acceleration for the size effect; a causal difference
    keeps the output latency at zero samples), zero after a gap > 1.5 nominal periods.
    Everything runs in Python floats: ~20-40 us per sample, no numpy call.

    Covariances (diagonal, rad^2/s^2 and m^2/s^4): white noise of the mean over one interval,
    ``N^2 / dt`` (CONTRACT 1: values are interval means), plus the first-order propagation of
    the calibration's one-sigma values through the model of CONTRACT 3, treating the sigmas as
    independent.

    Parameters
    ----------
    result:
        The calibration (``errors`` and ``sigma``), a :class:`CalibrationResult`.
    gyro_noise_rad_s_rt_hz, accel_noise_m_s2_rt_hz:
        White-noise densities (ARW, VRW) of the sensor.
    nominal_period_s:
        Configured nominal period [s], used for the noise variance after a gap or at the
        first sample, and as the gap threshold (1.5 periods, CONTRACT 1) for the rate
        derivative; ``0`` = detect it from the data: the median of the first
        :attr:`RATE_INTERVALS` stamp intervals (:attr:`measured_period_s`, measured in
        either case). Until then the rate derivative is zero and the noise of the mean uses
        the median of the intervals seen so far (``FIRST_PERIOD_S`` before any interval).
    """

    RATE_INTERVALS = 20  # stamp intervals whose median is the measured period
    RATE_TOLERANCE = 0.2  # a configured rate further than this (relative) from the measured
    FIRST_PERIOD_S = 1e-3  # noise-of-the-mean period before any interval: errs large below 1 kHz

    def __init__(self, result: Any, gyro_noise_rad_s_rt_hz: float = 0.0,
                 accel_noise_m_s2_rt_hz: float = 0.0, nominal_period_s: float = 0.0):
        from .sensor_model import compensate_one
        self._compensate_one = compensate_one
        self._gyro_n2 = float(gyro_noise_rad_s_rt_hz) ** 2
        self._accel_n2 = float(accel_noise_m_s2_rt_hz) ** 2
        if not (math.isfinite(nominal_period_s) and nominal_period_s >= 0.0):
            raise ValueError(f'nominal_period_s must be >= 0 (0 = detect), got {nominal_period_s}')
        self.configured_period_s = float(nominal_period_s)
        #: the period in use: the configured one, else the measured one (None until then)
        self.nominal_period_s: float | None = self.configured_period_s or None
        self.measured_period_s: float | None = None
        #: one line when a configured rate is more than RATE_TOLERANCE off the measured one
        self.rate_mismatch = ''
        self._intervals_ns: list[int] = []
        self._provisional_s = self.FIRST_PERIOD_S
        self._prev: tuple[int, tuple[float, float, float]] | None = None
        self.update(result)

    @property
    def intervals_ns(self) -> tuple[int, ...]:
        """The stamp intervals the period was (or is being) measured from."""
        return tuple(self._intervals_ns)

    def _learn(self, interval_ns: int) -> None:
        """Collect one stamp interval; at RATE_INTERVALS, fix the measured period."""
        iv = self._intervals_ns
        iv.append(interval_ns)
        med = float(np.median(iv)) * 1e-9  # a few calls per start-up only
        self._provisional_s = med
        if len(iv) < self.RATE_INTERVALS:
            return
        if self.configured_period_s > 0.0:
            f_cfg, f_meas = 1.0 / self.configured_period_s, 1.0 / med
            if abs(f_meas / f_cfg - 1.0) > self.RATE_TOLERANCE:
                self.rate_mismatch = (f'configured imu_rate_hz {f_cfg:g} but the stamps say '
                                      f'{f_meas:.4g} Hz (median of {len(iv)} intervals)')
        else:
            self.nominal_period_s = med
        self.measured_period_s = med  # last: readers in other threads see a complete state

    def update(self, result: Any) -> None:
        """Use a new calibration from the next sample on (keeps the rate-derivative memory).

        One attribute assignment swaps everything, so a thread reading it concurrently sees
        either the old or the new calibration, never a mix.
        """
        s = result.sigma
        sq = tuple(tuple(float(v) ** 2 for v in np.ravel(x)) for x in (
            s.gyro_bias_rad_s, s.gyro_scale_misalignment, s.gyro_scale_asymmetry,
            s.gyro_g_sensitivity_rad_s_per_m_s2, s.accel_bias_m_s2, s.accel_scale_misalignment,
            s.accel_scale_asymmetry, s.accel_quadratic_per_m_s2, s.size_effect_m))
        self._cal = (result, sq)

    @property
    def result(self) -> Any:
        """The calibration in use."""
        return self._cal[0]

    def reset(self) -> None:
        """Forget the previous sample (after a gap, a time jump or a reset)."""
        self._prev = None

    def __call__(self, stamp_ns: int, gyro: tuple[float, float, float],
                 accel: tuple[float, float, float]) -> tuple[tuple[float, ...], ...]:
        """``(omega, f, gyro_var, accel_var)`` of one sample, each 3 floats."""
        result, sq = self._cal
        period = self.nominal_period_s
        prev = self._prev
        dt_s = period
        wd = (0.0, 0.0, 0.0)
        if prev is not None:
            dn = stamp_ns - prev[0]
            if self.measured_period_s is None and dn > 0:
                self._learn(dn)
            d = dn * 1e-9
            if period is not None and 0.0 < d <= GAP_PERIODS * period:
                p = prev[1]
                wd = ((gyro[0] - p[0]) / d, (gyro[1] - p[1]) / d, (gyro[2] - p[2]) / d)
                dt_s = d
        if dt_s is None:  # rate not known yet: zero rate derivative, provisional period
            dt_s = self._provisional_s
        self._prev = (stamp_ns, gyro)
        omega, f = self._compensate_one(result.errors, gyro, accel, wd)
        gvar, avar = self._variances(sq, omega, f, wd, dt_s)
        return omega, f, gvar, avar

    def _variances(self, sq: tuple[tuple[float, ...], ...], w: tuple[float, ...],
                   f: tuple[float, ...], wd: tuple[float, ...],
                   dt_s: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Diagonal variances of the compensated rate and specific force (see class doc).

        Hand-written per component: numpy on 3-vectors costs more than the arithmetic.
        """
        g_b2, g_k2, g_a2, g_g2, a_b2, a_k2, a_a2, a_q2, a_r2 = sq
        w2 = (w[0] * w[0], w[1] * w[1], w[2] * w[2])
        f2 = (f[0] * f[0], f[1] * f[1], f[2] * f[2])
        ng = self._gyro_n2 / dt_s
        na = self._accel_n2 / dt_s
        # d f_i / d r_ij = M[i][j], M = skew(omega_dot) + skew(omega)^2  (CONTRACT 3)
        ww = w2[0] + w2[1] + w2[2]
        m = ((w2[0] - ww, w[0] * w[1] - wd[2], w[0] * w[2] + wd[1]),
             (w[1] * w[0] + wd[2], w2[1] - ww, w[1] * w[2] - wd[0]),
             (w[2] * w[0] - wd[1], w[2] * w[1] + wd[0], w2[2] - ww))
        gvar = []
        avar = []
        for i in range(3):
            r = 3 * i
            gvar.append(ng + g_b2[i] + g_a2[i] * w2[i]
                        + g_k2[r] * w2[0] + g_k2[r + 1] * w2[1] + g_k2[r + 2] * w2[2]
                        + g_g2[r] * f2[0] + g_g2[r + 1] * f2[1] + g_g2[r + 2] * f2[2])
            mi = m[i]
            avar.append(na + a_b2[i] + a_a2[i] * f2[i] + a_q2[i] * f2[i] * f2[i]
                        + a_k2[r] * f2[0] + a_k2[r + 1] * f2[1] + a_k2[r + 2] * f2[2]
                        + a_r2[r] * mi[0] * mi[0] + a_r2[r + 1] * mi[1] * mi[1]
                        + a_r2[r + 2] * mi[2] * mi[2])
        return tuple(gvar), tuple(avar)
