"""The prior of the calibration states: its sigmas, its mean, and the correction of later passes.

The prior sigmas come from the coarse start (issue 11: ``prior_inflation`` x its sigma, never
narrower than :data:`COARSE_FLOOR` nor than the grade hint) or, without one, from the grade
(``auto_start: false``); values nobody measured get :data:`RAW_PRIOR`, the largest raw errors
the product is specified for. The prior mean is where the first pass starts: the coarse start,
else no sensor errors, with the nominal lever arm. A later pass (Savage, "Improved strapdown
IMU calibration procedures", sect. 8) relinearises about the previous estimate but keeps this
prior: started there with the prior covariance ``P0`` it would count the data twice (its
prior mean is already the data's answer), so what the re-centred prior mean added is taken
off again. For constant states that is ``P P0^-1 (start - prior mean)`` (information form:
``P^-1 x = P0^-1 m + sum H^T R^-1 z``); a bias under a random walk forgets its prior, so the
estimator carries the filter's own slope (``ErrorStateFilter.sens``,
``CalibrationEstimator._prior_correction``; the closed form moved a raw MEMS unit's gyro bias
by 5.4 sigma).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from .. import parameters as registry
from . import error_model as em
from .coarse import CoarseStart
from .config import EstimatorConfig

if TYPE_CHECKING:
    from ..fixture import Fixture
    from ..imu_grade import ImuGrade
    from .result import Estimate

FloatArray = NDArray[np.float64]
# the filter's working point: theta_gyro (22,), theta_accel (26,) in error_model order, the
# lever arm (3,) [m] and the mounting rotation vector (3,) [rad], both in the IMU frame
WorkingPoint = tuple[FloatArray, FloatArray, FloatArray, FloatArray]

# Wide priors of an uncalibrated unit (SI), for what the coarse start does not measure:
# the largest raw errors the product is specified for (issue 11: MEMS scale 3 %, misalignment
# 30 mrad, gyro bias 1 deg/s, accel bias 100 mg, size effect 2 cm); the registry's.
RAW_PRIOR: dict[str, float] = {g.name: g.raw_prior for g in registry.SENSOR_GROUPS
                               if g.raw_prior is not None}
# Least prior around a coarse value, for the model errors of the coarse fit (accelerometer
# asymmetry and quadratic terms are not in it; they shift bias and scale by ~aa g, which the
# fit's residuals, hence its sigmas, also show); the registry's.
COARSE_FLOOR: dict[str, float] = {g.name: g.coarse_floor for g in registry.SENSOR_GROUPS
                                  if g.coarse_floor is not None}


def prior_sigmas(grade: ImuGrade | None, config: EstimatorConfig,
                 start: CoarseStart | None = None, table: bool = True
                 ) -> dict[str, FloatArray]:
    """One-sigma prior of every group in SI.

    Without a coarse start: the grade's sigmas x ``prior_sigma_scale`` (the old behaviour,
    ``auto_start: false``). With one (issue 11): ``prior_inflation`` x the coarse sigma, never
    below :data:`COARSE_FLOOR` nor the grade hint; values the data did not determine get the
    grade hint's sigma if one was given, else :data:`RAW_PRIOR`. A group with sigma 0 is no
    state (the caller drops it): the sampling kernels where their regressors would carry the
    noise that drives the innovations (:func:`gyro_kernel_estimable`; the accelerometers'
    off a ``table``, on a general chain).
    """
    k = config.prior_sigma_scale
    hint: dict[str, FloatArray] = {}
    if grade is not None and grade.sigma is not None:  # a grade without sigma (a measured
        # noise model) gives no hint
        vals = registry.grade_group_sigmas(grade.sigma)  # the registry's grade field per group
        hint = {n: np.full(em.GROUP_INFO[n][1], k * v) for n, v in vals.items()}
        # the filter estimates the total bias = turn-on constant + Gauss-Markov part
        hint['gyro_bias'] = np.hypot(hint['gyro_bias'], grade.gyro_bias_instability_rad_s)
        hint['accel_bias'] = np.hypot(hint['accel_bias'], grade.accel_bias_instability_m_s2)
    res: dict[str, FloatArray]
    if start is None:
        res = dict(hint) if hint else {n: np.full(em.GROUP_INFO[n][1], v)
                                       for n, v in RAW_PRIOR.items()}
    else:
        res = {}
        for name, raw in RAW_PRIOR.items():
            side = em.GROUP_INFO[name][4]
            cols = em.gyro_cols(name) if side == 'g' else em.accel_cols(name)
            sig = (start.sigma_gyro if side == 'g' else start.sigma_accel)[cols]
            measured = np.isfinite(sig)
            p = np.where(measured,
                         np.maximum(config.prior_inflation * np.nan_to_num(sig, posinf=0.0),
                                    COARSE_FLOOR[name]), raw)
            if name in hint:
                # the hint where the data measured nothing (the user's knowledge of the unit),
                # else never narrower than it; a grade that says "none" (sigma 0: optical
                # gyros have no G) drops the group
                h = hint[name]
                p = np.where(h > 0, np.where(measured, np.maximum(p, h), h), 0.0)
            res[name] = p
    res['time_offset'] = np.full(1, config.time_offset_sigma_s)
    if start is not None:
        kernel = gyro_kernel_estimable(start.gyro_noise_rad_s_rt_hz, start.imu_period_s)
    else:
        kernel = grade is not None and gyro_kernel_estimable(grade.gyro_noise_rad_s_rt_hz, 0.0)
    res['gyro_sample_kernel'] = np.full(1, config.sample_kernel_sigma if kernel else 0.0)
    # on a general chain (``table`` False) the arm's Jacobians take the samples as their
    # specific force, and the accelerometers' kernel regressor would be their second
    # difference: errors in variables, as for noisy gyros; the declared type's is assumed
    res['accel_sample_kernel'] = np.full(1, config.sample_kernel_sigma if table else 0.0)
    res['lever_arm'] = np.full(3, config.lever_arm_sigma_m)
    mount = config.mounting_sigma_rad
    if start is not None:
        ms = start.mounting_sigma_rad
        mount = max(mount, config.prior_inflation * ms if math.isfinite(ms) else 0.2)
    res['mounting'] = np.full(3, mount)
    return res


def prior_vector(prior: dict[str, FloatArray], groups: tuple[str, ...]) -> FloatArray:
    """The prior sigmas of ``groups`` in state order (SI), empty without groups."""
    return np.concatenate([prior[g] for g in groups]) if groups else np.zeros(0)


def nominal_lever_arm(fixture: Fixture) -> FloatArray:
    """The nominal fixture's reference-point offset from the axes, IMU frame [m]."""
    if not getattr(fixture, 'concurrent', True):  # a general chain: from its anchor
        return fixture.lever_arm_imu_m  # type: ignore[no-any-return]
    q0 = np.zeros(fixture.n_joints)
    return fixture.R_enu_imu(q0).T @ fixture.p_enu_m(q0)


def sample_kernel_mean(config: EstimatorConfig) -> float:
    """The prior mean of the sampling kernels (:func:`.error_model.sample_kernel_column`): 0
    for interval means (CONTRACT 1's default); for declared point samples the kernel of what
    the estimator makes of them, the trapezoid of each sample and the one before
    (:func:`.buffers.point_to_mean`: two points half a period either side of the interval's
    middle, variance ``dt^2 / 4``, so ``1 - 12 / 4 = -2``)."""
    return -2.0 if config.imu_sample_type == 'point' else 0.0


#: a sampling kernel this many sigmas from the declared one is named (:func:`kernel_note`)
KERNEL_NOTE_SIGMAS = 4.0
#: the gyros' sampling kernel is a state only where their noise per sample is at most this
#: [rad/s] (:func:`gyro_kernel_estimable`)
KERNEL_GYRO_SAMPLE_NOISE_RAD_S = 1e-4


def gyro_kernel_estimable(noise_rad_s_rt_hz: float, period_s: float) -> bool:
    """Whether the gyros' sampling kernel can be a state: their white noise per sample,
    ``N / sqrt(dt)`` (``dt`` 10 ms when not known), at most
    :data:`KERNEL_GYRO_SAMPLE_NOISE_RAD_S`.

    The kernel's regressor is the samples' own second difference
    (:func:`.propagation.propagate_block`), whose noise the attitude shares: errors in
    variables that pull the kernel towards +12 as that noise grows against the rate's
    curvature. Session 24, interval means at 100-200 Hz, the kernel a state for every unit:
    consumer MEMS +9.1..+11.6 (sigmas 0.3-0.7; one gyro scale 4.9 sigma off with exit 0),
    industrial MEMS +0.9..+5.9, tactical +0.3..+2.8 (sigmas 0.7-1.8), navigation units at
    100 Hz to 2 kHz within their sigmas. 1e-4 rad/s a sample is 1e-5 rad/s/sqrt(Hz) at
    100 Hz, 3.2e-6 at 1 kHz (navigation units: 0.6-1.5e-6, tactical 1.5-4.4e-5). A gyro
    noisier than that hides the kernel anyway: through a ramp of 1 rad/s^2 at 100 Hz it
    moves the attitude by 4e-6 rad, against 1e-5 rad of the noise's at the limit over the
    ramp's second. A gyro whose noise nobody measured (no coarse start, no grade): not."""
    if not math.isfinite(noise_rad_s_rt_hz) or noise_rad_s_rt_hz < 0:
        return False
    dt = period_s if period_s > 0 else 0.01
    return noise_rad_s_rt_hz / math.sqrt(dt) <= KERNEL_GYRO_SAMPLE_NOISE_RAD_S


def kernel_note(estimator_extra: dict[str, Any], config: EstimatorConfig) -> str | None:
    """One line when a sampling kernel the data chose is not the declared
    ``imu_sample_type``'s (beyond :data:`KERNEL_NOTE_SIGMAS` of its sigma), else None: what
    the samples are, and whether the filter took them so. A kernel that was no state (a
    noisy gyro's, an arm's accelerometers') was assumed at the declared type's: then the
    line says to declare the type."""
    mean = sample_kernel_mean(config)
    got, assumed = [], []
    for side, what in (('gyro', 'gyros'), ('accel', 'accelerometers')):
        k, sd = estimator_extra.get(f'{side}_sample_kernel'), \
            estimator_extra.get(f'{side}_sample_kernel_sigma')
        if k is None or not sd:
            assumed.append(what)
            continue
        got.append((what, float(k), float(sd[0])))
    if not any(abs(k - mean) > KERNEL_NOTE_SIGMAS * sd for _, k, sd in got):
        return None
    line = (f'the IMU samples are not what imu_sample_type ({config.imu_sample_type}) says: '
            'the sampling kernels came out '
            + ', '.join(f'{what} {k:.2f} +- {sd:.2f}' for what, k, sd in got)
            + f' (expected {mean:g}; 0 interval means, 1 point samples'
            + (', -2 the trapezoids of declared point samples' if mean else '')
            + ', below 0 a smoothing filter)')
    if not assumed:
        return line + '; the filter estimated them, so the calibration holds'
    line += (f'; the {" and ".join(assumed)}\' kernel was not estimated here but assumed at '
             f'{mean:g}')
    if all(abs(k - 1.0) <= KERNEL_NOTE_SIGMAS * sd for _, k, sd in got):  # point samples
        return line + (": declare the samples' type (--config with imu_sample_type: point) "
                       'and run again')
    # a smoothing filter's kernel (or another): no type to declare covers it
    return line + (', and is likely as far off (a smoothing filter in the sensor?), which no '
                   "imu_sample_type covers: record the sensor's interval means, or with its "
                   'filter at a wider bandwidth')


def prior_point(fixture: Fixture, start: CoarseStart | None,
                layout: em.StateLayout, sample_kernel: float = 0.0) -> WorkingPoint:
    """The prior mean as fresh parameter arrays: the coarse start (issue 11), else no sensor
    errors; the nominal lever arm in the (mounted) IMU frame; the measured mounting rotation,
    else none; the sampling kernels ``sample_kernel`` (:func:`sample_kernel_mean`), states or
    not. Another group the filter does not estimate keeps its assumed value, zero (CONTRACT
    4): a coarse G of 1.4e-7 (rad/s)/(m/s^2) kept under a grade that has no G acted as an
    unmodelled 0.3 deg/h bias (6 sigma)."""
    tg, ta = np.zeros(em.N_GYRO), np.zeros(em.N_ACCEL)
    if start is None:
        lever, mount = nominal_lever_arm(fixture), np.zeros(3)
    else:
        R_m = Rotation.from_rotvec(start.mounting_rotvec_rad).as_matrix()
        tg[layout.gyro_cols] = start.theta_gyro[layout.gyro_cols]
        ta[layout.accel_cols] = start.theta_accel[layout.accel_cols]
        lever, mount = R_m.T @ nominal_lever_arm(fixture), start.mounting_rotvec_rad.copy()
    # the declared type's kernels, states or not (a kernel that is no state is assumed)
    tg[em.gyro_cols('gyro_sample_kernel')] = sample_kernel
    ta[em.accel_cols('accel_sample_kernel')] = sample_kernel
    return tg, ta, lever, mount


def prior_shift(initial: Estimate | None, labels: tuple[str, ...],
                prior_mean: FloatArray) -> FloatArray | None:
    """``initial.values`` minus the prior mean (None without a starting estimate).

    Raises
    ------
    ValueError
        The starting estimate has other states than ``labels``.
    """
    if initial is None:
        return None
    if tuple(initial.labels) != labels:
        raise ValueError('the starting estimate has other states than this estimator '
                         '(a pass with another configuration?)')
    return np.asarray(initial.values, float) - prior_mean
