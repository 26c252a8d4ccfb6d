"""Coarse alignment and the filter's start: the first stationary window, levelling, P0.

The navigation starts at rest: in the first window of ``init_window_s`` during which no joint
moves by more than ``stationary_joint_tolerance_rad`` (or six of its own encoder-noise sigmas
there, where that is larger: :func:`still_run`), the attitude is the fixture's
(``R_enu_imu(q)`` with the mounting rotation) levelled by the mean compensated specific force
(at rest the specific force is the reaction to gravity, "up": the rotation taking it to
ENU's z), heading from the fixture kinematics (a turntable's heading is its encoder reading;
with a raw unit the mounting rotation comes from the coarse start, METHODS.md section 4).
The same window gives the IMU's sample period
and the number of samples per chunk. The initial covariance: tilt, heading (never below the
mounting prior about z), velocity from the config, the calibration states from the prior.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from .. import sensor_model as sm
from . import error_model as em
from .buffers import encoder_noise_rad, window_noise_rad
from .config import EstimatorConfig
from .ekf import chunk_transition_rows
from .error_model import StateLayout

if TYPE_CHECKING:
    from ..fixture import Fixture

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


#: joint travel that counts as rest, in the encoders' own noise sigmas (:func:`still_run`)
STILL_NOISE_SIGMAS = 6.0


def still_run(jt: IntArray, jq: FloatArray, window_ns: int, tol_rad: float,
              noise_sigmas: float = 0.0) -> tuple[int, int | None]:
    """The first window of joint samples that lasts ``window_ns`` (at the median sample
    spacing) and in which every joint stays within ``tol_rad`` of its mean over the window,
    or within ``noise_sigmas`` of its own encoder noise there where that is larger (the rms
    of the window's second differences over sqrt(6)).

    Each window is judged on its own samples only, so the answer does not depend on how the
    samples arrived (pushes of 50 ms live, 40 s batches offline). The test it replaces, a run
    of sample-to-sample steps below ``tol_rad``, depended on the joint rate: at 1 kHz a move's
    last half second at up to 0.1 rad/s passed for rest, and a navigation unit aligned there
    came out with its g-sensitivity 8.7 sigma off. Mean, largest and smallest value over
    every window at once (a cumulative sum, ``scipy.ndimage`` running extrema).

    The noise term (session 21): encoders with 50 urad of noise never stayed within the
    fixed 0.1 mrad over 2 s, and the plain command refused every such bag ("no stationary
    window"). A window in motion cannot pass for rest through it: a constant rate leaves no
    second differences, and a constant acceleration takes the joint ``alpha T^2 / 3`` from
    its mean over the window against ``noise_sigmas alpha dt^2 / sqrt(6)`` (``T / dt`` >=
    20 samples). A step does leave second differences; the noise is therefore the smaller of
    their rms and their median-based estimate (:func:`.buffers.encoder_noise_rad`), which a
    step does not move.

    Returns
    -------
    start_j, stop_j :
        Indices of the window's first and last sample; ``stop_j`` is None when no window is
        still yet, and ``start_j`` then is the first sample whose window is not complete yet
        (nothing before it can start one: the caller drops it).
    """
    from scipy.ndimage import maximum_filter1d, minimum_filter1d
    n = len(jt)
    if n < 2:
        return 0, None
    dt = float(np.median(np.diff(jt)))
    m = int(math.ceil(window_ns / dt)) + 1 if dt > 0 else n + 1  # samples per window
    if n < m:
        return 0, None
    c = np.concatenate([np.zeros((1, jq.shape[1])), np.cumsum(jq, axis=0)])
    mean = (c[m:] - c[:-m]) / m  # window i: samples i .. i + m - 1
    h = m // 2  # a centred running extremum of size m at i + m // 2 covers i .. i + m - 1
    hi = maximum_filter1d(jq, m, axis=0, mode='nearest')[h:h + n - m + 1]
    lo = minimum_filter1d(jq, m, axis=0, mode='nearest')[h:h + n - m + 1]
    fixed = np.all((hi - mean <= tol_rad) & (mean - lo <= tol_rad), axis=1)
    if noise_sigmas > 0.0 and m >= 4:
        # the rms noise over every window at once lets a window with a step in it pass (a
        # jump of s reads as s sqrt(12 / (m - 2)) of noise); the windows it lets through
        # beyond the fixed tolerance are checked in order with the median-based noise
        tol = np.maximum(tol_rad, noise_sigmas * window_noise_rad(jq, m))
        loose = np.all((hi - mean <= tol) & (mean - lo <= tol), axis=1)
        first = int(np.argmax(fixed)) if fixed.any() else len(fixed)
        for i in np.flatnonzero(loose[:first]).tolist():
            t_i = np.maximum(tol_rad, np.minimum(
                tol[i], noise_sigmas * encoder_noise_rad(jq[i:i + m])))
            if np.all((hi[i] - mean[i] <= t_i) & (mean[i] - lo[i] <= t_i)):
                fixed[i] = True
                break
    ok = np.flatnonzero(fixed)
    if not len(ok):
        return n - m + 1, None
    return int(ok[0]), int(ok[0]) + m - 1


def still_tolerance_rad(jt: IntArray, jq: FloatArray, window_s: float,
                        config_tol_rad: float) -> float | None:
    """The joint travel that counts as rest from here on: ``config_tol_rad``, or
    :data:`STILL_NOISE_SIGMAS` times the largest encoder noise of the first still window
    (:func:`still_run` with the noise term) where that is larger; None while there is no such
    window. The coarse start's stationary windows, the filter's stillness tests and its
    ledger use it; taken from the first still window of the record, the value is the same
    however the samples arrive, for the coarse start (on the held data) and the filter alike.
    """
    start, stop = still_run(jt, jq, int(window_s * 1e9), config_tol_rad, STILL_NOISE_SIGMAS)
    return None if stop is None else window_tolerance_rad(jq[start:stop + 1], config_tol_rad)


def window_tolerance_rad(jq_window: FloatArray, config_tol_rad: float) -> float:
    """``config_tol_rad`` or :data:`STILL_NOISE_SIGMAS` times the largest encoder noise of the
    still window ``jq_window`` (its samples, n x joints), whichever is larger; the noise as
    :func:`still_run` judged it (the smaller of the rms and the median-based estimate)."""
    m = len(jq_window)
    if m < 4:
        return float(config_tol_rad)
    noise = np.minimum(window_noise_rad(jq_window, m)[0], encoder_noise_rad(jq_window))
    return max(float(config_tol_rad), STILL_NOISE_SIGMAS * float(np.max(noise)))


@dataclass(frozen=True)
class Alignment:
    """The result of a coarse alignment on one stationary window."""

    nominal_dt_s: float  # median sample period of the window
    samples_per_chunk: int  # IMU samples between two measurement updates
    R_enu_imu: FloatArray  # (3, 3) levelled attitude at the window
    gyro_rad_s: FloatArray  # (N, 3) compensated window samples (for noise estimation)
    accel_m_s2: FloatArray  # (N, 3)


def level(R_enu_imu_fixture: FloatArray, f_imu_m_s2: FloatArray) -> FloatArray:
    """Level the fixture attitude with the mean specific force at rest: the smallest rotation
    taking ``R f`` (up, at rest) to ENU's z, applied on the left (tilt in ENU; the heading
    about z is the fixture's)."""
    up = R_enu_imu_fixture @ f_imu_m_s2
    up /= np.linalg.norm(up)
    axis = np.cross(up, [0.0, 0.0, 1.0])
    s = np.linalg.norm(axis)
    ang = math.atan2(s, up[2])
    R_lev = Rotation.from_rotvec(axis / s * ang).as_matrix() if s > 0 else np.eye(3)
    return R_lev @ R_enu_imu_fixture


def align(t_ns: IntArray, gyro_rad_s: FloatArray, accel_m_s2: FloatArray, q_rad: FloatArray,
          errors: Any, mounting_rotvec_rad: FloatArray, fixture: Fixture,
          update_rate_hz: float) -> Alignment | None:
    """Coarse alignment on a stationary window.

    Parameters
    ----------
    t_ns, gyro_rad_s, accel_m_s2 :
        The raw IMU samples of the window (interval means).
    q_rad :
        Mean joint positions over the window (fixture order).
    errors :
        :class:`~imu_calib_ros.core.sensor_model.SensorErrors` to compensate with (the
        current estimate).
    mounting_rotvec_rad :
        Mounting rotation estimate (IMU frame): ``R_enu_imu = R_fixture(q) exp(mounting)``.
    fixture, update_rate_hz :
        Kinematics; rate of the measurement updates (samples per chunk).

    Returns
    -------
    Alignment or None
        None when the window holds fewer than three samples.
    """
    dts = np.diff(t_ns)
    if len(dts) < 2:
        return None
    nominal_dt = float(np.median(dts)) * 1e-9
    rate = 1.0 / nominal_dt
    n = max(1, int(round(rate / update_rate_hz)))
    w_c, f_c = sm.compensate(errors, gyro_rad_s, accel_m_s2, np.zeros_like(gyro_rad_s))
    R_fix = fixture.R_enu_imu(q_rad) @ Rotation.from_rotvec(mounting_rotvec_rad).as_matrix()
    return Alignment(nominal_dt, n, level(R_fix, f_c.mean(axis=0)), w_c, f_c)


def initial_covariance(layout: StateLayout, prior: dict[str, FloatArray],
                       config: EstimatorConfig) -> FloatArray:
    """``P0`` in the filter's scaled units: tilt, heading (at least the mounting prior about
    z, which the levelling cannot see), velocity at rest, the groups' prior sigmas."""
    p0 = np.zeros(layout.n)
    p0[0:2] = config.initial_tilt_sigma_rad
    p0[2] = max(config.initial_heading_sigma_rad, float(prior['mounting'][2]))
    p0[3:6] = config.initial_velocity_sigma_m_s
    for g in layout.groups:
        p0[layout.slices[g]] = prior[g]
    return np.diag((p0 / layout.scale) ** 2)


def level_coupling(layout: StateLayout, R_enu_imu: FloatArray, errors: Any, w_c: FloatArray,
                   f_c: FloatArray, dt_s: float, omega_ie_enu: FloatArray) -> FloatArray:
    """``M`` (scaled units) with ``P0 <- M P0 M^T``: the levelled tilt carries the
    accelerometer errors.

    Levelling makes the navigated specific force vertical, so the tilt error is whatever
    cancels the accelerometer error of the window: ``V_psi psi_h + V_a x_a = 0`` in the
    horizontal rows of the window's velocity transition (the filter's own rows,
    :func:`~.ekf.chunk_transition_rows`, so the signs are the filter's), i.e.
    ``psi_h = A x_a + n`` with ``A = -V_psi^-1 V_a``. A diagonal ``P0`` claimed the tilt
    known to ``initial_tilt_sigma_rad`` whatever the accelerometer prior: with an unmeasured
    bias of a raw unit (100 mg prior) the true tilt error is up to 0.1 rad, invisible at the
    first pose and a large, unmodelled velocity error at the first rotation (a three-pose
    plan: NIS 198 per dof with the gate off, the nav biases 100-160 sigma off).
    """
    n = len(f_c)
    M = np.eye(layout.n)
    ai = layout.accel_state_idx
    if n == 0 or not ai.size:
        return M
    Mg, Ma = em.compensated_jacobians(errors, w_c, np.zeros_like(w_c), f_c)
    R = np.broadcast_to(R_enu_imu, (n, 3, 3))
    rows = chunk_transition_rows(layout, R[None], (R @ f_c[..., None])[None, ..., 0],
                                 Mg[None], Ma[None], np.full((1, n), dt_s), omega_ie_enu)[0]
    s = layout.scale
    V = rows[3:5] * (s[None, :] / s[3:5, None])  # horizontal velocity rows, scaled units
    M[0:2, ai] = -np.linalg.solve(V[:, 0:2], V[:, ai])
    return M
