"""Kozlov & Kapralov's size-effect calibration by heading oscillations, as a processor.

Kozlov, Kapralov, "Millimeter-level calibration of IMU size effect" (seed ``000``).
Pipeline:

1. stationary windows (:mod:`.windows`) split the recording; each motion between two
   windows in which one joint oscillates harmonically about a (near-)vertical axis with one
   IMU axis (near-)vertical is a cycle. The motion interval comes from the joint rate (the
   rest before and after is excluded: a cosine fitted across it is biased), and the
   amplitude A, period T, centre angle and phase are fitted to that joint's states
   (``q = q_c + a cos(W t) + b sin(W t)``, scipy least squares with W free);
2. the IMU data, compensated with ``initial`` if given (size effect excluded), is navigated
   (core/strapdown.py) from the end of the window before the cycle, at rest, with the
   attitude of the fixture's kinematics levelled by that window's mean specific force
   (which removes the mounting tilt, ~1 mrad, from the gravity leakage);
3. mean horizontal acceleration per period = velocity change over one whole period / T,
   between the rest phases of the fitted cosine (there the reference point's velocity about
   the axis, ``omega x rho``, is zero); the cycle mean is the mean over its whole periods;
4. per IMU axis up, with two periods: ``y = c1 c2 / (c2 - c1) R_c^T (<a>(T1) - <a>(T2))``
   (eq. 10 corrected, METHODS.md section 2; ``R_c`` the levelled attitude at the centre
   heading; rotation and signs derived for ENU/IMU frames in core/kozlov.py). For an
   exactly vertical axis k, ``y_m = r_nm`` on the horizontal axes (m, n); the six
   coordinates are solved by weighted least squares from all y with the model rows taken
   from ``kozlov.size_effect_mean_acceleration_enu`` (which keeps the terms of a tilted up
   axis: a 2.5 mrad mounting tilt otherwise biases r by ~50 um). The instrumental part ``e``
   (accelerometer bias averaged over the swing, gravity leakage of a constant tilt, gyro
   misalignment coupling of the swing) depends on the phase only, not on T, and cancels.
   With one period only, ``y = c R_c^T <a>`` (``e`` not removed, said in ``extra``).
   The navigator's Coriolis term on its own growing velocity error (2 Omega x dv turns the
   drift by ~0.4 % per minute, a 70 um bias) is added back before averaging.

Checked by simulation (test_methods_oscillation.py): nav-grade IMU, kozlov_oscillation
plan at 100 Hz, noise-free: every coordinate within 8 um of the truth; with noise, 12 seeds,
RMS of error / sigma = 0.95 with sigma ~ 42 um. Remaining systematic error: the mounting
heading error (not observable here, ~1 mrad) rotates the pair (r_ij, r_ji) by that angle.

Sigmas from the noise (white-noise densities measured in the windows, as the SRT does), per
horizontal component of a cycle mean over the duration D starting tau after the
navigation start, after levelling over a window of length T_w::

    var<a> = VRW^2 / D + VRW^2 / T_w + g^2 ARW^2 (tau + D / 3)

(velocity random walk over D; levelling error; gravity leakage of the tilt random walk,
whose mean over D has the variance of its value at the start plus D/3 of the increments).
The scatter of the per-period means is reported (``chi2_periods``), not used: the periods
share the tilt random walk, so they are not independent.

Everything but the six size-effect coordinates is written as fixed (CONTRACT 4) at the
``initial`` value (zero without one) and the grade's sigma.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.integrate
import scipy.optimize
from numpy.typing import NDArray
from scipy.ndimage import uniform_filter1d
from scipy.spatial.transform import Rotation

from .. import parameters as registry
from ..errors import InputError
from ..kozlov import kozlov_c, kozlov_difference_factor, size_effect_mean_acceleration_enu
from ..types import ImuBatch, JointBatch, sample_intervals_ns
from .windows import Window, joint_positions, stationary_windows

if TYPE_CHECKING:
    from ..calibration import CalibrationResult
    from ..fixture import Fixture
    from ..imu_grade import ImuGrade
    from ..sensor_model import SensorErrors

FloatArray = NDArray[np.float64]

__all__ = ['Cycle', 'fit_harmonic', 'find_cycles', 'period_mean_accelerations',
           'mean_acceleration_sigma', 'estimate', 'calibrate']


@dataclass(frozen=True)
class Cycle:
    """One oscillation cycle (between two stationary windows).

    Attributes
    ----------
    window_before, window_after : int
        Indices of the stationary windows before and after the motion.
    joint : int
        Index of the oscillating joint.
    amplitude_rad, period_s, centre_rad : float
        Fitted harmonic parameters of the joint angle.
    t_first_s : float
        First rest phase (fitted cosine at its start value) at or after the motion start,
        seconds from the first IMU stamp: the start of the first whole period.
    n_periods : int
        Whole periods inside the motion from ``t_first_s``.
    up_axis : int
        IMU axis (0, 1, 2) closest to the vertical at the centre heading.
    q_centre_rad : (n,) ndarray
        Joint angles at the centre heading (the other joints as in the window before).
    rms_fit_rad : float
        RMS residual of the harmonic fit.
    """

    window_before: int
    window_after: int
    joint: int
    amplitude_rad: float
    period_s: float
    centre_rad: float
    t_first_s: float
    n_periods: int
    up_axis: int
    q_centre_rad: FloatArray
    rms_fit_rad: float


def fit_harmonic(t_s: FloatArray, q: FloatArray) -> tuple[float, float, float, float]:
    """Fit ``q = q_c + A cos(W (t - t0))`` to samples of a moving joint: (A, T, q_c, t0).

    The samples must cover the motion only (a rest before or after is not harmonic). Start
    from the zero crossings of ``q - mean`` and a linear fit at that W, then scipy least
    squares on (q_c, a, b, W). ``A > 0``; ``t0`` is the first maximum at or after ``t_s[0]``
    minus less than one period (the phase zero nearest after ``t_s[0] - T/2``).

    Raises
    ------
    InputError
        Fewer than three zero crossings (not an oscillation).
    """
    t_s = np.asarray(t_s, float)
    q = np.asarray(q, float)
    x = q - q.mean()
    s = np.signbit(x)
    crossings = t_s[1:][s[1:] != s[:-1]]
    if crossings.size < 3:
        raise InputError('oscillation segment has fewer than two half periods')
    w0 = math.pi / float(np.median(np.diff(crossings)))
    tau = t_s - t_s[0]

    def design(w: float) -> FloatArray:
        return np.stack([np.ones_like(tau), np.cos(w * tau), np.sin(w * tau)], axis=1)

    c0, a0, b0 = np.linalg.lstsq(design(w0), q, rcond=None)[0]

    def resid(p: FloatArray) -> FloatArray:
        c, a, b, w = p
        return c + a * np.cos(w * tau) + b * np.sin(w * tau) - q

    sol = scipy.optimize.least_squares(resid, [c0, a0, b0, w0], x_scale=[1, 1, 1, w0 * 1e-3],
                                       xtol=1e-14, ftol=1e-14, gtol=1e-14)
    c, a, b, w = sol.x
    w = abs(w)
    A = float(np.hypot(a, b))
    phase0 = float(np.arctan2(b, a))  # q = c + A cos(w tau - phase0)
    t0 = float(t_s[0] + phase0 / w)
    return A, float(2 * np.pi / w), float(c), t0


def _motion_interval(t_s: FloatArray, qk: FloatArray, rate_tol_rad_s: float) -> tuple[int, int]:
    """Index range ``[j0, j1)`` of the samples between the first and last one that move."""
    qd = np.gradient(qk, t_s)
    k = max(1, int(round(0.05 / max(float(np.median(np.diff(t_s))), 1e-6))))
    qd = uniform_filter1d(qd, k, mode='nearest')
    moving = np.flatnonzero(np.abs(qd) > rate_tol_rad_s)
    if moving.size == 0:
        return 0, 0
    return int(moving[0]), int(moving[-1]) + 1


def find_cycles(imu: ImuBatch, joints: JointBatch, fixture: Fixture, windows: list[Window],
                vertical_tol_rad: float = 0.1, rate_tol_rad_s: float = 2e-3,
                max_rms_fraction: float = 0.01) -> list[Cycle]:
    """Harmonic single-joint oscillations about a vertical axis between consecutive windows.

    Parameters
    ----------
    imu, joints : ImuBatch, JointBatch
        The recording (time zero = first IMU stamp).
    fixture : Fixture
        Joint names, axes and kinematics.
    windows : list of Window
        Stationary windows in time order (:func:`.windows.stationary_windows`).
    vertical_tol_rad : float
        Tolerance on the joint axis and on one IMU axis being vertical.
    rate_tol_rad_s : float
        Joint rate above which a joint sample counts as moving.
    max_rms_fraction : float
        Largest RMS residual of the harmonic fit, as a fraction of the amplitude.
    """
    names = tuple(fixture.joint_names)
    q = joint_positions(joints, names)
    tj = (joints.stamps_ns - imu.stamps_ns[0]) * 1e-9
    cycles = []
    for iw, (w0, w1) in enumerate(zip(windows[:-1], windows[1:])):
        sel = np.flatnonzero((tj > w0.t1_s) & (tj < w1.t0_s))
        if sel.size < 10:
            continue
        ptp = np.ptp(q[sel], axis=0)
        k = int(np.argmax(ptp))
        if np.any(np.delete(ptp, k) > 1e-3) or ptp[k] < np.radians(10):
            continue  # not a single-joint motion of useful size (e.g. an orientation move)
        j0, j1 = _motion_interval(tj[sel], q[sel, k], rate_tol_rad_s)
        if j1 - j0 < 10:
            continue
        ts, qs = tj[sel][j0:j1], q[sel, k][j0:j1]
        try:
            A, T, qc, t0 = fit_harmonic(ts, qs)
        except InputError:
            continue  # a single-joint move, not an oscillation
        rms = float(np.sqrt(np.mean((qs - (qc + A * np.cos(2 * np.pi / T * (ts - t0)))) ** 2)))
        if rms > max_rms_fraction * A:
            continue  # not harmonic
        q_c = w0.q_rad.copy()
        q_c[k] = qc
        axis_enu = fixture.joint_axes_enu(q_c)[k]
        if abs(axis_enu[2]) < math.cos(vertical_tol_rad):
            continue
        up = fixture.R_enu_imu(q_c).T @ np.array([0.0, 0.0, 1.0])
        ax = int(np.argmax(np.abs(up)))
        if abs(up[ax]) < math.cos(vertical_tol_rad):
            continue
        # first rest phase at or after the motion start; whole periods up to its end (the
        # rate threshold and smoothing make the moving interval a few samples short)
        t_first = t0 + T * math.ceil((ts[0] - t0) / T - 0.05)
        n_per = int(math.floor((ts[-1] - t_first) / T + 0.05))
        if n_per < 1:
            continue
        cycles.append(Cycle(iw, iw + 1, k, A, T, qc, t_first, n_per, ax, q_c, rms))
    return cycles


def period_mean_accelerations(t_s: FloatArray, v_enu_m_s: FloatArray, t_first_s: float,
                              period_s: float, n_periods: int) -> FloatArray:
    """Mean acceleration over each whole period: ``(v(t_p + T) - v(t_p)) / T``, ``(n, 3)``.

    Velocities at the period boundaries are interpolated linearly between samples.
    """
    tb = t_first_s + period_s * np.arange(n_periods + 1)
    vb = np.stack([np.interp(tb, t_s, v_enu_m_s[:, j]) for j in range(3)], axis=1)
    return np.diff(vb, axis=0) / period_s


def mean_acceleration_sigma(vrw_m_s2_rt_hz: float, arw_rad_s_rt_hz: float, g_m_s2: float,
                            duration_s: float, delay_s: float, level_window_s: float) -> float:
    """One-sigma noise of a horizontal mean navigated acceleration [m/s^2] (module doc).

    Parameters
    ----------
    vrw_m_s2_rt_hz, arw_rad_s_rt_hz : float
        Accelerometer and gyro white-noise densities.
    g_m_s2 : float
        Gravity.
    duration_s : float
        Averaging duration D (whole periods).
    delay_s : float
        Time tau from the navigation start to the start of the averaging.
    level_window_s : float
        Length of the levelling window T_w.
    """
    var = (vrw_m_s2_rt_hz ** 2 / duration_s + vrw_m_s2_rt_hz ** 2 / level_window_s
           + (g_m_s2 * arw_rad_s_rt_hz) ** 2 * (delay_s + duration_s / 3.0))
    return float(np.sqrt(var))


#: the six size-effect coordinates (r_xy, r_xz, r_yx, r_yz, r_zx, r_zy), CONTRACT 3 order
_OFF = registry.parameter('accelerometer.size_effect').entries  # r_i[j], registry order
_BASIS = tuple(np.where(np.arange(9).reshape(3, 3) == 3 * n + m, 1.0, 0.0) for n, m in _OFF)


def _mean_accel(r: FloatArray, R_c: FloatArray, cyc: Cycle) -> FloatArray:
    """Period-mean ENU acceleration of lever arms ``r`` in a cycle (core/kozlov.py)."""
    return size_effect_mean_acceleration_enu(r, R_c, cyc.amplitude_rad, cyc.period_s)


def _levelled(R_enu_imu: FloatArray, f_mean_imu: FloatArray) -> FloatArray:
    """Rotate ``R_enu_imu`` by the smallest rotation that puts the mean specific force up."""
    f_enu = R_enu_imu @ f_mean_imu
    f_enu = f_enu / np.linalg.norm(f_enu)
    axis = np.cross(f_enu, [0.0, 0.0, 1.0])
    ang = math.atan2(float(np.linalg.norm(axis)), float(f_enu[2]))
    if np.linalg.norm(axis) < 1e-15:
        return R_enu_imu
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * ang).as_matrix() @ R_enu_imu


@dataclass(frozen=True)
class OscillationOptions:
    """Options of Kozlov & Kapralov's method (:func:`estimate`); a misspelt one is a
    TypeError.

    Attributes
    ----------
    min_window_s : float
        Shortest stationary window.
    """

    min_window_s: float = 4.0


def estimate(imu: ImuBatch, joints: JointBatch, fixture: Fixture,
             grade: ImuGrade | None = None, options: OscillationOptions = OscillationOptions(),
             *, initial: CalibrationResult | None = None,
             ) -> tuple[SensorErrors, SensorErrors, list[str], dict[str, Any]]:
    """Size effect from harmonic heading oscillations (Kozlov & Kapralov).

    Parameters
    ----------
    imu, joints : ImuBatch, JointBatch
        Recording of a plan like ``kozlov_oscillation`` (three-axis table).
    fixture : Fixture
        Nominal fixture (kinematics, site).
    grade : ImuGrade, optional
        Only for the assumed sigmas of the parameters written as fixed.
    options : OscillationOptions
        The shortest stationary window.
    initial : CalibrationResult, optional
        Compensation applied before navigating (its size effect is ignored).

    Returns
    -------
    errors, sigma : SensorErrors
    fixed : list of str
    extra : dict
        ``extra['oscillation']['cycles']``: per cycle A, T, up axis, per-period mean
        accelerations, navigated velocity (decimated, for the Fig. 4 analogue plot).

    Raises
    ------
    InputError
        No harmonic oscillation about a vertical axis between stationary windows.
    """
    from ..sensor_model import SensorErrors, compensate
    from ..strapdown import Strapdown
    from .srt import FIELD_KEYS, _fields, noise_densities

    windows = stationary_windows(imu, joints, fixture, min_duration_s=options.min_window_s)
    cycles = find_cycles(imu, joints, fixture, windows)
    if not cycles:
        raise InputError('no harmonic oscillation about a vertical axis between stationary '
                         'windows (record the kozlov_oscillation plan on a three-axis table)')
    base = _fields(initial.errors) if initial is not None else _fields(SensorErrors.zeros())
    comp = dict(base)
    comp['size_effect_m'] = np.zeros((3, 3))
    omega, f = compensate(SensorErrors(**comp), imu.gyro_rad_s, imu.accel_m_s2,
                          stamps_ns=imu.stamps_ns)
    omega, f = np.asarray(omega, float), np.asarray(f, float)
    arw, vrw = noise_densities(imu.stamps_ns, omega, f, windows)
    g = float(fixture.site.gravity)
    t_all = (imu.stamps_ns - imu.stamps_ns[0]) * 1e-9
    dt_all = sample_intervals_ns(imu.stamps_ns)[0] * 1e-9  # CONTRACT 1 gap rule
    info: list[dict[str, Any]] = []
    per_cycle: list[tuple[Cycle, FloatArray, float, FloatArray]] = []
    z = np.array([0.0, 0.0, 1.0])
    for cyc in cycles:
        wb, wa = windows[cyc.window_before], windows[cyc.window_after]
        a, b = wb.i1 - 1, wa.i1  # start at the last sample of the window, at rest
        R0 = _levelled(fixture.R_enu_imu(wb.q_rad), f[wb.i0:wb.i1].mean(axis=0))
        nav = Strapdown(fixture.site, R0)
        out = nav.propagate(dt_all[a + 1:b], omega[a + 1:b], f[a + 1:b])
        t_nav = t_all[a:b]
        v_nav = np.vstack([np.zeros((1, 3)), out.v_enu_m_s])
        # the navigator turns its growing velocity error by -2 Omega x v (Coriolis); ~1 % of
        # the effect over a minute: add it back so that only the specific force is averaged
        cor = 2.0 * np.cross(np.asarray(fixture.site.omega_ie_enu, float), v_nav)
        v_corr = v_nav + scipy.integrate.cumulative_trapezoid(cor, t_nav, axis=0, initial=0)
        acc = period_mean_accelerations(t_nav, v_corr, cyc.t_first_s, cyc.period_s,
                                        cyc.n_periods)
        mean = acc.mean(axis=0)
        dur = cyc.n_periods * cyc.period_s
        sig_h = mean_acceleration_sigma(vrw, arw, g, dur, cyc.t_first_s - t_all[a],
                                        wb.duration_s)
        # attitude at the centre heading: the levelled start turned about the joint axis
        axis_enu = fixture.joint_axes_enu(cyc.q_centre_rad)[cyc.joint]
        Rc = Rotation.from_rotvec(axis_enu * (cyc.centre_rad - wb.q_rad[cyc.joint])
                                  ).as_matrix() @ R0
        per_cycle.append((cyc, mean, sig_h, Rc))
        dev = (acc - mean)[:, :2]
        chi2 = float(np.sum(dev ** 2) / (sig_h ** 2 * cyc.n_periods)) if cyc.n_periods > 1 \
            else float('nan')
        step = max(1, (b - a) // 2000)
        info.append({'joint': fixture.joint_names[cyc.joint],
                     'up_axis': 'xyz'[cyc.up_axis],
                     'up_sign': int(np.sign((Rc.T @ z)[cyc.up_axis])),
                     'amplitude_deg': math.degrees(cyc.amplitude_rad),
                     'period_s': cyc.period_s, 'n_periods_used': int(cyc.n_periods),
                     'fit_rms_rad': cyc.rms_fit_rad,
                     'kozlov_c_s2': kozlov_c(cyc.amplitude_rad, cyc.period_s),
                     'mean_accel_enu_m_s2': mean.tolist(),
                     'sigma_horizontal_m_s2': sig_h,
                     'chi2_periods': chi2,
                     'period_accel_enu_m_s2': acc.tolist(),
                     'nav_t_s': t_nav[::step].tolist(),
                     'nav_v_enu_m_s': v_nav[::step].tolist()})
    # rows y = c1 c2 / (c2 - c1) R_c^T (<a>(T1) - <a>(T2)) (or c R_c^T <a>), horizontal IMU
    # axes; model rows from kozlov.size_effect_mean_acceleration_enu, which keeps the terms
    # of a tilted up axis (the mounting tilt, ~1 mrad, would bias r by ~0.5 %)
    rows_H, rows_y, rows_s, used = [], [], [], []
    observed = np.zeros((3, 3), bool)
    for ax in range(3):
        group = [p for p in per_cycle if p[0].up_axis == ax]
        if not group:
            continue
        group.sort(key=lambda p: p[0].period_s)
        (c1, a1, s1, R1), (c2, a2, s2, R2) = group[0], group[-1]
        i, j = (ax + 1) % 3, (ax + 2) % 3
        if c2.period_s > 1.2 * c1.period_s:
            fac = kozlov_difference_factor(0.5 * (c1.amplitude_rad + c2.amplitude_rad),
                                           c1.period_s, c2.period_s)
            y = fac * (R1.T @ a1 - R2.T @ a2)
            H = np.stack([fac * (R1.T @ _mean_accel(b, R1, c1) - R2.T @ _mean_accel(b, R2, c2))
                          for b in _BASIS], axis=1)
            sd = abs(fac) * math.hypot(s1, s2)
            how = f'two-period difference T={c1.period_s:.2f}/{c2.period_s:.2f} s'
        else:
            fac = kozlov_c(c1.amplitude_rad, c1.period_s)
            y = fac * (R1.T @ a1)
            H = np.stack([fac * (R1.T @ _mean_accel(b, R1, c1)) for b in _BASIS], axis=1)
            sd = abs(fac) * s1
            how = f'single period T={c1.period_s:.2f} s (instrumental part not removed)'
        rows_y.append(y[[i, j]])
        rows_H.append(H[[i, j]])
        rows_s += [sd, sd]
        observed[j, i] = observed[i, j] = True
        used.append({'up_axis': 'xyz'[ax], 'method': how, 'factor_s2': fac,
                     'y_m': y[[i, j]].tolist()})
    est_cols = np.array([observed[n, m] for n, m in _OFF])
    Hm = np.vstack(rows_H)
    ws = 1.0 / np.asarray(rows_s)
    r0 = np.array([base['size_effect_m'][n, m] for n, m in _OFF])
    yv = np.concatenate(rows_y) - Hm[:, ~est_cols] @ r0[~est_cols]
    Hw = Hm[:, est_cols] * ws[:, None]
    x = np.linalg.lstsq(Hw, yv * ws, rcond=None)[0]
    cov = np.linalg.inv(Hw.T @ Hw)
    r = np.zeros((3, 3))
    r_sig = np.full((3, 3), np.nan)
    for val, sd, (n, m) in zip(x, np.sqrt(np.diag(cov)), [p for p, e in zip(_OFF, est_cols)
                                                          if e]):
        r[n, m], r_sig[n, m] = val, sd
    assumed = registry.grade_sigmas(grade)
    sig = {k: v.copy() for k, v in assumed.items()} if initial is None else _fields(
        initial.sigma)
    errs = dict(base)
    est_mask = ~np.isnan(r_sig)
    errs['size_effect_m'] = np.where(est_mask, r, base['size_effect_m'])
    sig['size_effect_m'] = np.where(est_mask, r_sig, sig['size_effect_m'])
    np.fill_diagonal(errs['size_effect_m'], 0.0)
    np.fill_diagonal(sig['size_effect_m'], 0.0)
    fixed = [key for fld, key in FIELD_KEYS.items() if fld != 'size_effect_m']
    if not est_mask[~np.eye(3, dtype=bool)].all():
        fixed.append('accelerometer.size_effect')
    extra = {'method': 'oscillation',
             'oscillation': {'cycles': info, 'estimates': used,
                             'noise': {'gyro_rad_s_rt_hz': arw, 'accel_m_s2_rt_hz': vrw},
                             'estimated_size_effect': est_mask.tolist()}}
    return SensorErrors(**errs), SensorErrors(**sig), fixed, extra


def calibrate(imu: ImuBatch, joints: JointBatch, fixture: Fixture,
              grade: ImuGrade | None = None, options: OscillationOptions = OscillationOptions(),
              *, initial: CalibrationResult | None = None) -> CalibrationResult:
    """Kozlov & Kapralov's method as a CalibrationResult (CONTRACT 4); arguments as
    :func:`estimate`."""
    from ..calibration import CalibrationResult
    errors, sigma, fixed, extra = estimate(imu, joints, fixture, grade, options,
                                           initial=initial)
    return CalibrationResult(errors=errors, sigma=sigma, frame_id=imu.frame_id or 'imu_link',
                             fixed=tuple(fixed), extra=extra)
