"""Streaming calibration estimator: strapdown navigator + augmented-state error EKF (issue 3).

One implementation serves the live node (single samples) and offline replay (batches):
samples are buffered and processed in *chunks* of ``n = imu_rate / update_rate`` samples
between two measurement updates, and chunks in *blocks* of ``config.block_chunks``:

1. compensate the block's raw samples with the current estimate (``sensor_model.compensate``;
   the size effect with ``omega_dot`` from central differences of neighbouring mean rates,
   METHODS.md "cuts across", so one sample of look-ahead is kept);
2. ``Strapdown.propagate`` over the whole block (vectorised);
3. build every chunk's transition matrix by vectorised sums (:mod:`.ekf`);
4. per chunk: one block-form ``predict`` and one gated Joseph-form ``update`` (:mod:`.ekf`)
   with the lever-arm zero-velocity measurement ``v_enu = R_enu_imu (omega_eb_imu x rho)``
   (and, with encoder aiding, the attitude from the fixture kinematics with the mounting
   rotation);
5. feed the error state back at the block end (navigator correction, new compensation).

Inside a block the error state is carried (not fed back), which is exact for a linear model
and keeps the errors small enough for the linearisation (a block is 5 s by default: per-block
Python overhead dominated at 1 s; 5 s blocks replay 1.6x faster and move no nav-grade or MEMS
state by more than 0.04 sigma, 10 s blocks moved a MEMS state by 0.34 sigma).
"""
from __future__ import annotations

import bisect
import logging
import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from .. import sensor_model as sm
from ..calibration import CalibrationResult
from ..errors import InputError
from ..input_guard import GuardConfig, InputGuard
from ..rotation import skew
from ..strapdown import Strapdown
from ..types import ImuBatch, ImuSample, JointBatch, JointSample
from . import error_model as em
from .coarse import CoarseStart, NoRotation, coarse_start
from .config import EstimatorConfig
from .ekf import ErrorStateFilter, chunk_transition_rows, process_noise

FloatArray = NDArray[np.float64]
_LOG = logging.getLogger('imu_calib_ros.estimator')
MEAS_SCALE = 1e-6  # velocity measurements in um/s, attitude in urad inside the filter

# CONTRACT 4 keys and the state groups that make them up
CONTRACT_KEYS: dict[str, tuple[str, ...]] = {
    'gyroscope.bias': ('gyro_bias',),
    'gyroscope.scale_misalignment': ('gyro_scale', 'gyro_misalignment'),
    'gyroscope.scale_asymmetry': ('gyro_asymmetry',),
    'gyroscope.g_sensitivity': ('gyro_g_sensitivity',),
    'accelerometer.bias': ('accel_bias',),
    'accelerometer.scale_misalignment': ('accel_scale', 'accel_misalignment'),
    'accelerometer.scale_asymmetry': ('accel_asymmetry',),
    'accelerometer.quadratic': ('accel_quadratic',),
    'accelerometer.size_effect': ('size_effect',),
}


# Wide priors of an uncalibrated unit (SI), for what the coarse start does not measure:
# the largest raw errors the product is specified for (issue 11: MEMS scale 3 %, misalignment
# 30 mrad, gyro bias 1 deg/s, accel bias 100 mg, size effect 2 cm).
RAW_PRIOR: dict[str, float] = {
    'gyro_bias': 1.75e-2, 'gyro_scale': 3e-2, 'gyro_asymmetry': 3e-3,
    'gyro_misalignment': 3e-2, 'gyro_g_sensitivity': 1.8e-5, 'accel_bias': 1.0,
    'accel_scale': 3e-2, 'accel_asymmetry': 3e-3, 'accel_misalignment': 3e-2,
    'accel_quadratic': 1e-4, 'size_effect': 2e-2}
# Least prior around a coarse value, for the model errors of the coarse fit (accelerometer
# asymmetry and quadratic terms are not in it; they shift bias and scale by ~aa g, which the
# fit's residuals, hence its sigmas, also show).
COARSE_FLOOR: dict[str, float] = {
    'gyro_bias': 4.8e-9, 'gyro_scale': 1e-5, 'gyro_asymmetry': 1e-5,
    'gyro_misalignment': 1e-5, 'gyro_g_sensitivity': 1e-8, 'accel_bias': 1e-3,
    'accel_scale': 2e-4, 'accel_misalignment': 2e-4, 'accel_asymmetry': 3e-3,
    'accel_quadratic': 1e-4, 'size_effect': 2e-2}


# Least bias random walk of a MEMS unit without a grade, per sqrt(s), as a fraction of its
# white-noise density: gyro 0.035 (a Gauss-Markov instability of N/4 rad/s over 100 s, e.g.
# 0.42 deg/sqrt(h) -> 6 deg/h; MTi-1 datasheet 10 deg/h, industrial units 1-3 deg/h at 0.1-0.3
# deg/sqrt(h)), accelerometer 0.015 (MTi-1: 30 ug over 100 s at 120 ug/sqrt(Hz) is 0.035).
MEMS_BIAS_WALK = (0.035, 0.015)


def prior_sigmas(grade: Any, config: EstimatorConfig,
                 start: CoarseStart | None = None) -> dict[str, FloatArray]:
    """One-sigma prior of every group in SI.

    Without a coarse start: the grade's sigmas x ``prior_sigma_scale`` (the old behaviour,
    ``auto_start: false``). With one (issue 11): ``prior_inflation`` x the coarse sigma, never
    below :data:`COARSE_FLOOR` nor the grade hint; values the data did not determine get the
    grade hint's sigma if one was given, else :data:`RAW_PRIOR`.
    """
    k = config.prior_sigma_scale
    hint: dict[str, FloatArray] = {}
    if grade is not None:
        s = grade.sigma
        vals = {
            'gyro_bias': s.gyro_bias_rad_s, 'gyro_scale': s.gyro_scale,
            'gyro_asymmetry': s.gyro_asymmetry, 'gyro_misalignment': s.gyro_misalignment_rad,
            'gyro_g_sensitivity': s.gyro_g_sensitivity, 'accel_bias': s.accel_bias_m_s2,
            'accel_scale': s.accel_scale, 'accel_asymmetry': s.accel_asymmetry,
            'accel_misalignment': s.accel_misalignment_rad,
            'accel_quadratic': s.accel_quadratic, 'size_effect': s.size_effect_m}
        hint = {n: np.full(em.GROUP_INFO[n][1], k * float(v)) for n, v in vals.items()}
        # the filter estimates the total bias = turn-on constant + Gauss-Markov part
        hint['gyro_bias'] = np.hypot(hint['gyro_bias'], grade.gyro_bias_instability_rad_s)
        hint['accel_bias'] = np.hypot(hint['accel_bias'], grade.accel_bias_instability_m_s2)
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
    res['lever_arm'] = np.full(3, config.lever_arm_sigma_m)
    mount = config.mounting_sigma_rad
    if start is not None:
        ms = start.mounting_sigma_rad
        mount = max(mount, config.prior_inflation * ms if math.isfinite(ms) else 0.2)
    res['mounting'] = np.full(3, mount)
    return res


@dataclass(frozen=True)
class Estimate:
    """Full estimate in SI: sensor parameters, auxiliary states and their covariance."""

    theta_gyro: FloatArray  # (21,) full gyro parameter vector (error_model order)
    theta_accel: FloatArray  # (26,) full accel parameter vector
    lever_arm_imu_m: FloatArray  # (3,) reference point offset from the axes, IMU frame
    mounting_rotvec_rad: FloatArray  # (3,) mounting rotation estimate, IMU frame
    labels: tuple[str, ...]  # labels of the calibration states (no psi, dv)
    values: FloatArray  # (m,) SI values of those states
    covariance: FloatArray  # (m, m) SI covariance of those states


class CalibrationEstimator:
    """Streaming augmented-state error EKF (see the module docstring).

    Parameters
    ----------
    fixture:
        The nominal fixture (kinematics for alignment, lever arm prior, encoder aiding).
    grade:
        :class:`~imu_calib_ros.core.imu_grade.ImuGrade`: prior sigmas and noise densities.
    config:
        :class:`EstimatorConfig`.
    initial:
        Optional starting :class:`Estimate` (a previous pass, Savage sect. 8): the
        compensation (the linearisation point) starts there; the prior is still the
        grade's, centred where pass 1 started (see :meth:`estimate_state`).
    """

    def __init__(self, fixture: Any, grade: Any = None, config: EstimatorConfig | None = None,
                 initial: Estimate | None = None, start: CoarseStart | None = None) -> None:
        self.fixture = fixture
        self.grade = grade  # a hint (prior floors, noise with noise_source 'grade'), or None
        self.config = config or EstimatorConfig()
        self._initial = initial
        self._given_start = start
        self._joint_names = tuple(fixture.joint_names)
        self.reset()

    def _configure(self) -> None:
        """Priors, encoder aiding and the state layout from the config, grade and start."""
        cfg = self.config
        st = self.start
        aiding = cfg.attitude_aiding or (
            st is not None and cfg.aiding_gyro_noise_rad_s_rt_hz > 0
            and st.gyro_noise_rad_s_rt_hz > cfg.aiding_gyro_noise_rad_s_rt_hz)
        self.attitude_aiding = bool(aiding)
        self._prior = prior_sigmas(self.grade, cfg, st)
        groups = cfg.estimated_groups
        if self.attitude_aiding and 'mounting' not in groups:
            groups = groups + ('mounting',)
        self.dropped_groups = tuple(g for g in groups if not np.all(self._prior[g] > 0.0))
        self.layout = em.StateLayout.build(
            tuple(g for g in groups if g not in self.dropped_groups))
        self._prior_shift = self._shift_of(self._initial)

    # ------------------------------------------------------------------ public API
    def reset(self) -> None:
        """Forget all data; back to waiting for a stationary window (and, without a given
        start, to holding the first data for the coarse start)."""
        self.start = self._given_start
        # issue 11: without a start, hold the first data until the coarse start is determined
        self._bootstrapping = self.config.auto_start and self.start is None
        self._boot: list[tuple[Any, ...]] = []
        self._boot_span = (0, 0)  # first and newest IMU stamp held
        self._boot_next_check_s = 0.0
        self.restarts = 0
        self._configure()
        self._reset_filter_side()
        self.frame_id = ''  # header.frame_id of the first accepted IMU data
        self._running = False
        self._nav: Strapdown | None = None
        self._filter: ErrorStateFilter | None = None
        self._imu_t: list[NDArray[np.int64]] = []
        self._imu_w: list[FloatArray] = []
        self._imu_f: list[FloatArray] = []
        self._jt: list[int] = []
        self._jq: list[FloatArray] = []
        self._last_joint_q: FloatArray | None = None
        self._joint_min: FloatArray | None = None
        self._joint_max: FloatArray | None = None
        self._prev: tuple[int, FloatArray, FloatArray] | None = None
        self._last_imu_stamp: int | None = None
        self._nominal_dt = 0.0
        self._n = 1
        self._q1_s: FloatArray | None = None
        self._bias_q = (0.0, 0.0)
        self._bias_q_seed = (0.0, 0.0)
        self._bias_q_scale = 1.0
        self.counters: dict[str, int] = {
            'imu_samples': 0, 'joint_samples': 0, 'imu_processed': 0, 'chunks': 0,
            'imu_dropped_before_alignment': 0, 'imu_out_of_order': 0, 'imu_non_finite': 0,
            'joint_out_of_order': 0, 'joint_missing_names': 0, 'joint_non_finite': 0, 'gaps': 0,
            'attitude_updates_without_joints': 0,
            'imu_dropped_at_gap': 0, 'gaps_bridged': 0, 'gaps_reinitialised': 0,
            'divergences': 0, 'restarts': self.restarts, 'realignments': 0,
            'bias_noise_adaptations': 0}
        self._t0_ns: int | None = None
        self._t_last_ns: int | None = None
        # bad input and faults (issue 6, core/input_guard.py)
        gcfg = getattr(self, 'guard_config', None) or GuardConfig()
        self.guard_config: GuardConfig = gcfg
        self._guard = InputGuard(gcfg, self.fixture.site.gravity, self._joint_names,
                                 self.fixture.joint_axes_enu)
        self._diverged: str | None = None
        self._good: deque[Estimate] = deque(
            maxlen=2 + -(-gcfg.nis_window // self.config.block_chunks))
        self._last_good_state: Estimate | None = None
        self._last_good_cache: tuple[int, Any] | None = None
        self._nis_hist: deque[tuple[int, int, float]] = deque()
        self._kept_cal_P: FloatArray | None = None

    def _reset_filter_side(self) -> None:
        """Start point, compensation, noise, joint latency: what the coarse start sets."""
        self._theta_g, self._theta_a, self._rho, self._mount = self._start_point()
        self._errors = self._make_errors()
        self._noise = self._noise_densities()
        self._point_prev: tuple[int, FloatArray, FloatArray] | None = None
        self._latency_ns = 0 if self.start is None else int(round(
            self.start.joint_latency_s * 1e9))
        self._settle_until_ns: int | None = None
        self._unsettled = False  # feedback after every update at the next alignment
        self._gated_run = 0
        self._cascade = False

    def reset_navigation(self) -> None:
        """Restart the navigation after a backward time jump (a looping bag, ``use_sim_time``).

        Drops the navigation states, the filter's navigation block and every buffered IMU and
        joint sample, and resets the input guard's stamp memory (the earlier stamps that now
        come are accepted; its rejection counters are kept). The calibration states and their
        covariance block are kept, as after a long gap (``_on_gap``, policy
        'reinitialise'), and the filter re-aligns at the next stationary window.
        """
        self._drop_navigation()
        self._imu_t, self._imu_w, self._imu_f = [], [], []
        self._jt, self._jq = [], []
        self._last_joint_q = None
        self._last_imu_stamp = None
        self._t_last_ns = None
        self._guard.reset_stamps()
        self.counters['navigation_resets'] = self.counters.get('navigation_resets', 0) + 1

    def configure_guard(self, guard_config: GuardConfig) -> None:
        """Set the bad-input / gap / divergence limits (:class:`GuardConfig`) and reset."""
        self.guard_config = guard_config
        self.reset()

    def push_imu(self, sample: ImuSample) -> None:
        """Add one IMU sample (live node); processing happens when a chunk is complete.

        Bad samples are rejected by the :class:`~imu_calib_ros.core.input_guard.InputGuard`
        (counted by reason in ``health()['rejected']``) and never reach the filter.
        """
        self.push_imu_batch(ImuBatch(np.array([sample.stamp_ns], np.int64),
                                     np.asarray(sample.gyro_rad_s, float).reshape(1, 3),
                                     np.asarray(sample.accel_m_s2, float).reshape(1, 3),
                                     sample.frame_id))

    def push_imu_batch(self, batch: ImuBatch) -> None:
        """Add many IMU samples (same code path as :meth:`push_imu`, vectorised)."""
        if len(batch):
            self._push_imu_arrays(np.asarray(batch.stamps_ns, np.int64),
                                  np.asarray(batch.gyro_rad_s, float).reshape(-1, 3),
                                  np.asarray(batch.accel_m_s2, float).reshape(-1, 3),
                                  batch.frame_id)

    def push_joint(self, sample: JointSample) -> None:
        """Add one joint-state sample (names in any order; other joints ignored)."""
        q = self._guard.check_joint(int(sample.stamp_ns), tuple(sample.names),
                                    sample.positions_rad)
        if q is not None and self._bootstrapping:
            self._hold(('joints', np.array([sample.stamp_ns], np.int64), q[None, :]))
        elif q is not None:  # joint stamps minus the measured latency: the instants they describe
            self._append_joint_q(int(sample.stamp_ns) - self._latency_ns, q)
        self._sync_input_counters()

    def push_joint_batch(self, batch: JointBatch) -> None:
        """Add many joint-state samples: the same verdicts, unwrapping and buffers as
        :meth:`push_joint` one by one, vectorised (input guard ``check_joint_batch``)."""
        t, q = self._guard.check_joint_batch(batch.stamps_ns, tuple(batch.names),
                                             batch.positions_rad)
        if len(t) and self._bootstrapping:
            self._hold(('joints', t, q))
        elif len(t):
            self._append_joint_batch(t - self._latency_ns, q)
        self._sync_input_counters()

    def flush(self) -> None:
        """Process every complete chunk (end of a bag), ignoring the joint look-ahead, and
        check the filter's health over that last stretch too."""
        if self._bootstrapping:
            self._finish_bootstrap(final=True)
        self._process(final=True)
        self._check_divergence()

    # ------------------------------------------------------------------ coarse start (issue 11)
    def _hold(self, item: tuple[Any, ...]) -> None:
        """Hold input the guard kept until the coarse start is determined (then replayed in
        push order: the filter sees exactly what it would have seen with the start known)."""
        self._boot.append(item)
        if item[0] != 'imu':
            return
        t0 = self._boot_span[0] or int(item[1][0])
        self._boot_span = (t0, max(self._boot_span[1], int(item[1][-1])))
        span = (self._boot_span[1] - t0) * 1e-9
        cfg = self.config
        # checked at fixed data times (bootstrap_min_s, then every 20 s or 25 %) on the data up to
        # then: the same start whatever the push pattern (single samples, batches)
        while self._bootstrapping and span >= max(cfg.bootstrap_min_s,
                                                  self._boot_next_check_s):
            at = max(cfg.bootstrap_min_s, self._boot_next_check_s)
            self._boot_next_check_s = max(at + 20.0, 1.25 * at)  # ~12 checks up to 600 s
            self._finish_bootstrap(final=at >= cfg.bootstrap_max_s,
                                   t_cut_ns=t0 + int(at * 1e9))

    def _held_arrays(self, t_cut_ns: int | None = None) -> tuple[Any, ...] | None:
        """The held input as clean arrays for :func:`coarse_start` (finite, stamp order,
        fixture joints unwrapped, point samples as interval means), or None if too little."""
        imu = [b for b in self._boot if b[0] == 'imu']
        jb = [b for b in self._boot if b[0] == 'joints']
        if not imu or not jb:
            return None
        t = np.concatenate([b[1] for b in imu])
        w = np.concatenate([b[2] for b in imu])
        f = np.concatenate([b[3] for b in imu])
        if t_cut_ns is not None:
            k = int(np.searchsorted(t, t_cut_ns, side='right'))
            t, w, f = t[:k], w[:k], f[:k]
        if self.config.imu_sample_type == 'point':
            w, f = _point_to_mean(w, f, None)
        tj = np.concatenate([b[1] for b in jb])
        qj = np.concatenate([b[2] for b in jb])
        if t_cut_ns is not None:
            k = int(np.searchsorted(tj, t_cut_ns, side='right'))
            tj, qj = tj[:k], qj[:k]
        k = np.arange(len(tj))
        qj = np.unwrap(qj[k], axis=0)
        if len(t) < 100 or len(tj) < 4:
            return None
        return t, w, f, tj, qj

    def _finish_bootstrap(self, final: bool, t_cut_ns: int | None = None) -> None:
        """Measure the coarse start from the held data (up to ``t_cut_ns``); when it is
        determined (or at the end of the data), configure the filter around it and replay the
        held input."""
        arrays = self._held_arrays(t_cut_ns)
        st = None
        if arrays is not None:
            try:
                st = coarse_start(*arrays, self.fixture,
                                  tol_rad=self.config.stationary_joint_tolerance_rad)
            except NoRotation:
                pass  # at the end: no start; the caller's "no motion" check names it
            except (ValueError, np.linalg.LinAlgError) as exc:
                if final:  # the data contradict the fixture: say which, never guess
                    raise InputError(str(exc)) from None
        if st is None and not final:
            return
        if st is not None and not final and not st.determined():
            return  # not yet determined: gather more
        held, self._boot = self._boot, []
        self._bootstrapping = False
        self.start = st
        self._configure()
        self._reset_filter_side()
        if st is not None:
            _LOG.info('coarse start: %s', st.summary())
            self._check_grade_hint(st)
        for item in held:
            if item[0] == 'imu':
                self._accept_imu(*item[1:])
            elif len(item[1]):
                self._append_joint_batch(item[1] - self._latency_ns, item[2])

    def _check_grade_hint(self, st: CoarseStart) -> None:
        """One line when the data disagree with the grade the user gave (noise densities)."""
        gr = self.grade
        if gr is None:
            return
        for what, got, hint in (('gyro', st.gyro_noise_rad_s_rt_hz, gr.gyro_noise_rad_s_rt_hz),
                                ('accelerometer', st.accel_noise_m_s2_rt_hz,
                                 gr.accel_noise_m_s2_rt_hz)):
            if hint > 0 and not 0.5 <= got / hint <= 2.0:
                _LOG.warning('the data disagree with the IMU grade %s: %s white noise %.3g is '
                             '%.2g x the grade\'s %.3g (using %s)', gr.name, what, got,
                             got / hint, hint, 'the data\'s' if self.config.noise_source ==
                             'data' else 'the grade\'s')

    def _noise_densities(self) -> tuple[float, float]:
        """White-noise densities for Q: measured (coarse start) or the grade's."""
        st, gr = self.start, self.grade
        if st is not None and (self.config.noise_source == 'data' or gr is None):
            return st.gyro_noise_rad_s_rt_hz, st.accel_noise_m_s2_rt_hz
        if gr is not None:
            return gr.gyro_noise_rad_s_rt_hz, gr.accel_noise_m_s2_rt_hz
        return 1e-4, 1e-3  # nothing measured yet and no grade: MEMS-like until the start

    def filter_accepted(self, kind: str) -> int:
        """Accepted updates of one kind (``'velocity'`` or ``'attitude'``)."""
        return 0 if self._filter is None else self._filter.counters.accepted.get(kind, 0)

    @property
    def is_running(self) -> bool:
        """True once the coarse alignment is done and the filter runs."""
        return self._running

    def _nominal_lever_arm(self) -> FloatArray:
        """The nominal fixture's reference-point offset from the axes, IMU frame."""
        q0 = np.zeros(self.fixture.n_joints)
        return self.fixture.R_enu_imu(q0).T @ self.fixture.p_enu_m(q0)

    def _start_point(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(theta_gyro, theta_accel, lever arm, mounting)`` the filter starts from: the
        starting estimate's, else the prior mean (fresh arrays)."""
        init = self._initial
        if init is None:
            return self._coarse_point()
        return (init.theta_gyro.copy(), init.theta_accel.copy(), init.lever_arm_imu_m.copy(),
                init.mounting_rotvec_rad.copy())

    def _coarse_point(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The prior mean: the coarse start (issue 11), else no sensor errors; the nominal
        lever arm in the (mounted) IMU frame; the measured mounting rotation, else none."""
        st = self.start
        if st is None:
            return (np.zeros(em.N_GYRO), np.zeros(em.N_ACCEL), self._nominal_lever_arm(),
                    np.zeros(3))
        R_m = Rotation.from_rotvec(st.mounting_rotvec_rad).as_matrix()
        # a group the filter does not estimate keeps its assumed value, zero (CONTRACT 4):
        # a coarse G of 1.4e-7 (rad/s)/(m/s^2) kept under a grade that has no G acted as an
        # unmodelled 0.3 deg/h bias (6 sigma)
        tg, ta = np.zeros(em.N_GYRO), np.zeros(em.N_ACCEL)
        lay = self.layout
        tg[lay.gyro_cols] = st.theta_gyro[lay.gyro_cols]
        ta[lay.accel_cols] = st.theta_accel[lay.accel_cols]
        return tg, ta, R_m.T @ self._nominal_lever_arm(), st.mounting_rotvec_rad.copy()

    def _prior_mean(self) -> FloatArray:
        """Where pass 1 starts (:meth:`_coarse_point`), as calibration-state values."""
        return self._values_of(*self._coarse_point())

    def _shift_of(self, initial: Estimate | None) -> FloatArray | None:
        """``initial.values`` minus the prior mean (None without a starting estimate)."""
        if initial is None:
            return None
        labels = tuple(self.layout.labels()[6:])
        if tuple(initial.labels) != labels:
            raise ValueError('the starting estimate has other states than this estimator '
                             '(a pass with another configuration?)')
        return np.asarray(initial.values, float) - self._prior_mean()

    def _prior_correction(self, P: FloatArray) -> FloatArray:
        """What re-centring the prior on the starting estimate added to the estimate.

        A pass that starts from a previous pass's estimate with the grade's prior covariance
        ``P0`` (Savage sect. 8, PSINS's passes) would count the data twice: its prior mean
        is already the data's answer. For constant states the posterior mean is linear in
        the prior mean with slope ``P P0^-1`` (information form: ``P^-1 x = P0^-1 m +
        sum H^T R^-1 z``), so ``P P0^-1 (start - prior mean)`` is taken off again: the pass
        relinearises about the previous estimate but keeps the grade's prior. The biases'
        random walk makes the slope smaller than that; for the shipped grades either the
        walk or ``P P0^-1`` is negligible (nav: 0.0005 deg/h over a 0.01 deg/h prior; MEMS:
        a 6 deg/h posterior under a 720 deg/h prior).
        """
        assert self._prior_shift is not None
        p0 = np.concatenate([self._prior[g] for g in self.layout.groups])
        return P @ (self._prior_shift / p0 ** 2)

    def estimate_state(self) -> Estimate:
        """The current estimate (SI) with the covariance of the calibration states.

        After a start from a previous pass, the values are those of the grade's prior
        (:meth:`_prior_correction`); the navigator keeps compensating with its own.
        """
        lay = self.layout
        idx = np.arange(6, lay.n)
        s = lay.scale[idx]
        if self._filter is not None:
            P = self._filter.P[np.ix_(idx, idx)] * np.outer(s, s)
        elif self._kept_cal_P is not None:  # between a navigation reset and the re-alignment
            P = self._kept_cal_P * np.outer(s, s)
        else:
            P = np.diag(np.concatenate([self._prior[g] for g in lay.groups]) ** 2) \
                if lay.groups else np.zeros((0, 0))
        values = self._state_values()
        tg, ta, rho, mount = (self._theta_g.copy(), self._theta_a.copy(), self._rho.copy(),
                              self._mount.copy())
        if self._prior_shift is not None and values.size:
            values = values - self._prior_correction(P)
            tg, ta, rho, mount = self._with_values(values, tg, ta, rho, mount)
        return Estimate(tg, ta, rho, mount, tuple(lay.labels()[6:]), values, P)

    def _with_values(self, values: FloatArray, tg: FloatArray, ta: FloatArray,
                     rho: FloatArray, mount: FloatArray) -> tuple[FloatArray, ...]:
        """The parameter arrays with the calibration states set to ``values`` (the inverse
        of :meth:`_state_values`; entries that are not states keep their values)."""
        lay = self.layout
        full = np.concatenate([np.zeros(6), values])
        tg, ta = tg.copy(), ta.copy()
        tg[lay.gyro_cols] = full[lay.gyro_state_idx]
        ta[lay.accel_cols] = full[lay.accel_state_idx]
        if 'lever_arm' in lay.slices:
            rho = full[lay.slices['lever_arm']].copy()
        if 'mounting' in lay.slices:
            mount = full[lay.slices['mounting']].copy()
        return tg, ta, rho, mount

    def _frame(self) -> str:
        """The frame of the calibration: the configured one, else that of the data."""
        return self.guard_config.frame_id or self.frame_id or 'imu_link'

    def estimate(self, frame_id: str | None = None) -> Any:
        """The calibration as a :class:`~imu_calib_ros.core.calibration.CalibrationResult`.

        Estimated groups carry their filter sigma; the others their assumed value (zero) and
        prior sigma, and are listed as fixed (CONTRACT 4). ``frame_id`` None: the configured
        frame, else the ``header.frame_id`` of the data, else ``imu_link``.
        """
        st = self.estimate_state()
        return self._result_from_state(st, frame_id or self._frame(),
                                       lambda sd: {'estimator': self._extra(st, sd)})

    def compensator(self) -> Callable[..., tuple[FloatArray, FloatArray]]:
        """A function ``(gyro (N,3), accel (N,3), omega_dot=None) -> (omega, f)`` that applies
        the current estimate (frozen at the time of the call)."""
        errors = self._errors

        def compensate(gyro: FloatArray, accel: FloatArray,
                       omega_dot: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
            return sm.compensate(errors, np.atleast_2d(gyro), np.atleast_2d(accel), omega_dot)
        return compensate

    def health(self, now_ns: int | None = None) -> dict[str, Any]:
        """Counters, gate statistics, covariance health and a status (for diagnostics).

        Keys added for bad input and faults (issue 6): ``status`` in {'OK', 'WARN', 'ERROR',
        'STALE'} with a one-line ``message``; ``rejected`` {reason: count} of input samples
        (:data:`~imu_calib_ros.core.input_guard.IMU_REASONS` and ``JOINT_REASONS``),
        ``rejected_total``, ``flagged`` {'gap', 'long_gap'}; ``diverged`` (bool),
        ``divergence_reason``, ``units_error``; ``last_good``: the
        :class:`~imu_calib_ros.core.calibration.CalibrationResult` of the last healthy block
        (frozen at divergence) or None. ``gate_accepted``/``gate_rejected`` count measurement
        updates by kind. ``now_ns`` (the caller's clock) enables STALE: no IMU sample accepted
        within ``stale_after_s``.
        """
        out: dict[str, Any] = dict(self.counters)
        out['running'] = self._running
        out['dropped_groups'] = list(self.dropped_groups)
        g = self._guard
        out['rejected'] = dict(g.rejected)
        out['rejected_total'] = g.rejected_total
        out['flagged'] = dict(g.flagged)
        out['diverged'] = self._diverged is not None
        out['divergence_reason'] = self._diverged or ''
        out['units_error'] = g.units_error or ''
        out['status'], out['message'] = self._status(now_ns)
        out['last_good'] = self._last_good_result()
        if self._filter is not None:
            c = self._filter.counters
            out['accepted'] = dict(c.accepted)
            out['gate_accepted'] = dict(c.accepted)
            out['gate_rejected'] = dict(c.rejected)
            out['mean_nis'] = {k: c.nis_sum[k] / max(c.accepted.get(k, 0), 1)
                               for k in c.nis_sum}
            P = self._filter.P
            out['covariance_min_eigenvalue_scaled'] = float(np.linalg.eigvalsh(P).min())
            out['covariance_asymmetry'] = float(np.abs(P - P.T).max())
        if self._t0_ns is not None and self._t_last_ns is not None:
            out['processed_s'] = (self._t_last_ns - self._t0_ns) * 1e-9
        return out

    # ------------------------------------------------------------------ input handling
    def _name_index(self, names: tuple[str, ...]) -> NDArray[np.intp] | None:
        try:
            return np.array([list(names).index(n) for n in self._joint_names], np.intp)
        except ValueError:
            return None

    def _append_joint_q(self, stamp_ns: int, q: FloatArray) -> None:
        if not np.all(np.isfinite(q)):
            self.counters['joint_non_finite'] += 1
            return
        if self._jt and stamp_ns <= self._jt[-1]:
            self.counters['joint_out_of_order'] += 1
            return
        if self._last_joint_q is not None:  # unwrap against the previous sample
            q = q + 2 * np.pi * np.round((self._last_joint_q - q) / (2 * np.pi))
        self._last_joint_q = q
        self._jt.append(stamp_ns)
        self._jq.append(q)
        if self._joint_min is None or self._joint_max is None:
            self._joint_min, self._joint_max = q.copy(), q.copy()
        else:
            self._joint_min = np.minimum(self._joint_min, q)
            self._joint_max = np.maximum(self._joint_max, q)
        self.counters['joint_samples'] += 1

    def _append_joint_batch(self, t: NDArray[np.int64], q: FloatArray) -> None:
        """:meth:`_append_joint_q` for many samples the guard accepted (finite, stamps
        strictly increasing and above every earlier accepted stamp), vectorised."""
        if self._jt and int(t[0]) <= self._jt[-1]:  # cannot happen behind the guard
            for ti, qi in zip(t.tolist(), q):
                self._append_joint_q(ti, qi)
            return
        two_pi = 2 * np.pi
        # unwrap: sample k moves by 2 pi m_k, m_k = m_(k-1) + round((q_(k-1) - q_k) / 2 pi);
        # np.unwrap's formula differs in the last bit, so the sequential rule is used and
        # checked below (a mismatch, only at exactly half turns, falls back to the loop)
        last = self._last_joint_q
        if last is not None:
            ref_raw = np.vstack([last[None, :], q[:-1]])
            m = np.cumsum(np.round((ref_raw - q) / two_pi), axis=0)
        else:
            m = np.vstack([np.zeros((1, q.shape[1])),
                           np.cumsum(np.round((q[:-1] - q[1:]) / two_pi), axis=0)])
        qu = q + two_pi * m
        if last is None:
            qu[0] = q[0]  # the first sample is kept as it is (single push)
            ref, q_chk, qu_chk = qu[:-1], q[1:], qu[1:]
        else:
            ref, q_chk, qu_chk = np.vstack([last[None, :], qu[:-1]]), q, qu
        if not np.array_equal(q_chk + two_pi * np.round((ref - q_chk) / two_pi), qu_chk):
            for ti, qi in zip(t.tolist(), q):
                self._append_joint_q(ti, qi)
            return
        self._last_joint_q = qu[-1]
        self._jt.extend(t.tolist())
        self._jq.extend(qu)
        self._joint_range(qu)
        self.counters['joint_samples'] += len(t)

    def _joint_range(self, q: FloatArray) -> None:
        """Track the smallest and largest accepted (unwrapped) position of every joint."""
        lo, hi = q.min(axis=0), q.max(axis=0)
        if self._joint_min is None or self._joint_max is None:
            self._joint_min, self._joint_max = lo, hi
        else:
            self._joint_min = np.minimum(self._joint_min, lo)
            self._joint_max = np.maximum(self._joint_max, hi)

    @property
    def joint_travel_rad(self) -> float:
        """Largest range (max - min) of any joint's accepted, unwrapped positions [rad]."""
        if self._joint_min is None or self._joint_max is None:
            return 0.0
        return float(np.max(self._joint_max - self._joint_min))

    def _append_imu(self, t: NDArray[np.int64], w: FloatArray, f: FloatArray) -> None:
        """Buffer samples the input guard accepted (finite, strictly increasing stamps)."""
        if not len(t):
            return
        self._last_imu_stamp = int(t[-1])
        self._imu_t.append(t)
        self._imu_w.append(w)
        self._imu_f.append(f)

    def _take_imu(self) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
        if len(self._imu_t) > 1:
            self._imu_t = [np.concatenate(self._imu_t)]
            self._imu_w = [np.concatenate(self._imu_w)]
            self._imu_f = [np.concatenate(self._imu_f)]
        if not self._imu_t:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3))
        return self._imu_t[0], self._imu_w[0], self._imu_f[0]

    def _keep_imu_from(self, k: int) -> None:
        t, w, f = self._take_imu()
        self._imu_t, self._imu_w, self._imu_f = [t[k:]], [w[k:]], [f[k:]]

    # ------------------------------------------------------------------ bad input and faults
    def _push_imu_arrays(self, t: NDArray[np.int64], w: FloatArray, f: FloatArray,
                         frame_id: str) -> None:
        """Input guard, then buffer and process; a long gap splits the batch (issue 6)."""
        self.counters['imu_samples'] += len(t)
        verdict = self._guard.check_imu(t, w, f, frame_id, diverged=self._diverged is not None)
        self._sync_input_counters()
        keep = verdict.keep
        if frame_id and not self.frame_id and keep.any():
            self.frame_id = frame_id  # the calibration belongs to the frame of its data
        if not keep.any():
            return
        t, w, f = t[keep], w[keep], f[keep]
        if self._bootstrapping:
            self._hold(('imu', t, w, f, verdict.gaps, verdict.long_gaps))
            return
        self._accept_imu(t, w, f, verdict.gaps, verdict.long_gaps)

    def _accept_imu(self, t: NDArray[np.int64], w: FloatArray, f: FloatArray, gap_idx: Any,
                    long_gap_idx: Any) -> None:
        """Samples the guard kept: to interval means, split at gaps, processed by blocks."""
        if self.config.imu_sample_type == 'point':  # CONTRACT 1: point samples as means
            raw_last = (int(t[-1]), w[-1].copy(), f[-1].copy())
            w, f = _point_to_mean(w, f, self._point_prev)
            self._point_prev = raw_last
        # A long gap applies gap_policy; a short gap (> gap_periods nominal periods) during
        # which the table turned also loses the turn (CONTRACT 1), which no navigator can
        # bridge: it re-initialises the navigation too (calibration states are kept).
        gaps = {int(i) for i in long_gap_idx}
        gaps.update(int(i) for i in gap_idx)
        long_gaps = {int(i) for i in long_gap_idx}
        bounds = sorted({0, *gaps, len(t)})
        for a, b in zip(bounds[:-1], bounds[1:]):
            if a in gaps and self._last_imu_stamp is not None:
                t_before, t_after = self._last_imu_stamp, int(t[a])
                if a in long_gaps or not self._joints_still(t_before, t_after):
                    self._on_gap(t_before, t_after)
            # one block at a time, so that divergence is checked after every block
            i = a
            while i < b and self._diverged is None:
                step = self.config.block_chunks * self._n if self._running else 1000
                j = min(i + step, b)  # never past the next gap
                self._append_imu(t[i:j], w[i:j], f[i:j])
                self._advance()
                i = j
            if self._diverged is not None and i < len(t):
                self._guard.rejected['filter_diverged'] += len(t) - i
                return

    def _sync_input_counters(self) -> None:
        """The estimator's historical counters, derived from the guard's reasons."""
        r = self._guard.rejected
        c = self.counters
        c['imu_non_finite'] = r['non_finite']
        c['imu_out_of_order'] = (r['duplicate_stamp'] + r['out_of_order']
                                 + r['time_jump_backward'])
        c['joint_missing_names'] = r['joint_missing_names']
        c['joint_non_finite'] = r['joint_non_finite']
        c['joint_out_of_order'] = r['joint_duplicate_stamp'] + r['joint_out_of_order']

    def _advance(self) -> None:
        """Align if needed (restoring kept calibration covariance), process, check health."""
        if not self._running:
            if not self._try_initialise():
                return
            self._restore_calibration_covariance()
        chunks = self.counters['chunks']
        self._process()
        if self.counters['chunks'] != chunks:
            self._check_divergence()

    def _restore_calibration_covariance(self) -> None:
        """After a re-initialisation: the calibration block of P is the one before the gap."""
        if self._kept_cal_P is not None and self._filter is not None:
            self._filter.P[6:, 6:] = self._kept_cal_P
            self._kept_cal_P = None

    def _on_gap(self, t_before_ns: int, t_after_ns: int) -> None:
        """A gap longer than ``guard_config.max_gap_s`` between two accepted samples, or a
        shorter one during which the joints moved (or whose joint data is not there yet).

        The data before the gap is processed first (a partial chunk at its end is dropped and
        counted in ``imu_dropped_at_gap``). Policy ``'bridge'`` (only when the joints did not
        move across the gap: the motion during the gap is lost, CONTRACT 1): inflate the
        navigation covariance by ``bridge_*_sigma`` and the bias covariance by the bias
        random walk over the gap; the interval itself is handled like any gap by the block
        code (one nominal period, coning/sculling memory reset). Otherwise, or with policy
        ``'reinitialise'``: drop the navigator and the filter, keep the calibration states
        and their covariance block, and re-align at the next stationary window.
        """
        if not self._running or self._filter is None:
            return
        self._process(final=True)
        self._check_divergence()
        if self._diverged is not None or self._filter is None:
            return
        left = len(self._take_imu()[0])
        if left:
            self.counters['imu_dropped_at_gap'] += left
            self._keep_imu_from(left)
        cfg = self.guard_config
        if cfg.gap_policy == 'bridge' and self._joints_still(t_before_ns, t_after_ns):
            lay = self.layout
            s = lay.scale
            gap_s = (t_after_ns - t_before_ns) * 1e-9
            P = self._filter.P
            P[0:3, 0:3] += np.eye(3) * (cfg.bridge_attitude_sigma_rad / s[0]) ** 2
            P[3:6, 3:6] += np.eye(3) * (cfg.bridge_velocity_sigma_m_s / s[3]) ** 2
            assert self._q1_s is not None
            for grp in ('gyro_bias', 'accel_bias'):  # bias random walk continues in the gap
                if grp in lay.slices:
                    sl = lay.slices[grp]
                    P[sl, sl] += self._q1_s[sl, sl] * gap_s
            self.counters['gaps_bridged'] += 1
            return
        self._drop_navigation()
        k = int(np.searchsorted(np.array(self._jt, np.int64), t_after_ns))
        del self._jt[:k]
        del self._jq[:k]
        self.counters['gaps_reinitialised'] += 1

    def _drop_navigation(self) -> None:
        """Drop the navigator and the filter; keep the calibration states and their
        covariance block (``_kept_cal_P``, put back by
        :meth:`_restore_calibration_covariance` at the next coarse alignment). Shared by
        :meth:`_on_gap` (policy 'reinitialise') and :meth:`reset_navigation`."""
        if self._filter is not None:  # else a block kept earlier is still waiting: keep it
            self._kept_cal_P = self._filter.P[6:, 6:].copy()
        self._running = False
        self._nav = None
        self._filter = None
        self._prev = None
        self._nis_hist.clear()  # cumulative counts of the dropped filter: a new window

    def _joints_still(self, t_before_ns: int, t_after_ns: int) -> bool:
        """True if joint samples cover the gap and show no motion beyond the tolerance."""
        if not self._jt:
            return False
        jt = np.array(self._jt, np.int64)
        jq = np.array(self._jq)
        i0 = int(np.searchsorted(jt, t_before_ns, side='right')) - 1
        i1 = int(np.searchsorted(jt, t_after_ns, side='right'))
        if i0 < 0 or jt[i1 - 1] < t_after_ns - int(0.5e9):
            return False
        travel = np.abs(jq[i0:i1] - jq[i0]).max()
        return bool(travel <= self.config.stationary_joint_tolerance_rad)

    def _check_divergence(self) -> None:
        """Windowed NIS, positive definiteness, physical ranges; snapshot when healthy."""
        if self._filter is None or self._diverged is not None:
            return
        cfg = self.guard_config
        filt = self._filter
        lay = self.layout
        vals = self._state_values()
        reason = None
        v = self._nav.v_enu_m_s if self._nav is not None else np.zeros(3)
        if not (np.all(np.isfinite(filt.P)) and np.all(np.isfinite(filt.x))
                and np.all(np.isfinite(vals)) and np.all(np.isfinite(v))):
            reason = 'non-finite state or covariance'
        else:
            try:
                np.linalg.cholesky(filt.P)
            except np.linalg.LinAlgError:
                reason = ('covariance lost positive definiteness (min eigenvalue '
                          f'{float(np.linalg.eigvalsh(filt.P).min()):.3g})')
        if reason is None and float(np.linalg.norm(v)) > cfg.max_velocity_m_s:
            reason = f'navigated velocity {float(np.linalg.norm(v)):.3g} m/s out of range'
        if reason is None:
            prior = np.concatenate([self._prior[g] for g in lay.groups]) if lay.groups \
                else np.zeros(0)
            dev = np.abs(vals - self._prior_mean())  # from the prior mean (coarse start)
            over = dev > cfg.state_range_sigmas * prior
            if over.any():
                i = int(np.argmax(dev / np.where(prior > 0, prior, np.inf)))
                reason = (f'state {lay.labels()[6 + i]} = {vals[i]:.3g} beyond '
                          f'{cfg.state_range_sigmas:g} prior sigmas from its prior mean')
        if reason is None:
            reason = self._nis_window_reason()
        if reason is not None:
            self._declare_divergence(reason)
        else:
            self._good.append(self.estimate_state())
            self._adapt_bias_noise()

    def _nis_window_reason(self) -> str | None:
        """Gate rejections or mean NIS over the last ``nis_window`` updates out of bounds."""
        assert self._filter is not None
        cfg = self.guard_config
        c = self._filter.counters
        tot = (sum(c.accepted.values()), sum(c.rejected.values()), sum(c.nis_sum.values()))
        hist = self._nis_hist
        hist.append(tot)
        n = tot[0] + tot[1]
        while len(hist) > 1 and n - (hist[1][0] + hist[1][1]) >= cfg.nis_window:
            hist.popleft()
        a0, r0, s0 = hist[0]
        n_win = n - a0 - r0
        if n_win < cfg.nis_window:
            return None
        rej = tot[1] - r0
        if rej > cfg.max_rejected_fraction * n_win:
            return f'{rej} of the last {n_win} measurement updates failed the chi-square gate'
        acc = tot[0] - a0
        if acc:
            mean = (tot[2] - s0) / acc / 3.0  # all our measurements are 3-D
            if mean > cfg.max_mean_nis_per_dof:
                return f'mean NIS per dof {mean:.3g} over the last {acc} updates'
        return None

    def _restart(self, reason: str) -> None:
        """A diverged filter restarts from the coarse start with its prior covariance
        inflated (x2 per restart) and re-aligns at the next stationary window (issue 11)."""
        self.restarts += 1
        self.counters['restarts'] = self.restarts
        self._unsettled = True
        _LOG.warning('calibration filter diverged (%s): restart %d of %d from the start point '
                     'with inflated covariance', reason, self.restarts, self.config.max_restarts)
        self._theta_g, self._theta_a, self._rho, self._mount = self._start_point()
        self._errors = self._make_errors()
        self._drop_navigation()
        lay = self.layout
        infl = 2.0 ** self.restarts
        self._kept_cal_P = np.diag((np.concatenate(
            [self._prior[g] for g in lay.groups]) * infl / lay.scale[6:]) ** 2) \
            if lay.groups else np.zeros((0, 0))
        self._good.clear()
        self._gated_run = 0
        self._cascade = False

    def _declare_divergence(self, reason: str) -> None:
        """Restart (up to ``max_restarts``); then latch ERROR, roll the estimate back to the
        last good snapshot and stop the filter."""
        if self.restarts < self.config.max_restarts:
            self._restart(reason)
            return
        self._diverged = reason
        self.counters['divergences'] += 1
        st = self._good[0] if self._good else None
        self._last_good_state = st
        lay = self.layout
        if st is not None:
            self._theta_g, self._theta_a = st.theta_gyro.copy(), st.theta_accel.copy()
            self._rho, self._mount = st.lever_arm_imu_m.copy(), st.mounting_rotvec_rad.copy()
            if self._prior_shift is not None and st.values.size:
                # the snapshot holds reported (prior-corrected) values; the navigator's working
                # point is the uncorrected one that estimate_state() corrects again
                self._theta_g, self._theta_a, self._rho, self._mount = self._with_values(
                    st.values + self._prior_correction(st.covariance), self._theta_g,
                    self._theta_a, self._rho, self._mount)
        else:  # nothing good yet: back to the starting point
            self._theta_g, self._theta_a, self._rho, self._mount = self._start_point()
        self._errors = self._make_errors()
        if self._filter is not None:
            P = np.zeros((lay.n, lay.n))
            s = lay.scale[6:]
            if st is not None:
                P[6:, 6:] = st.covariance / np.outer(s, s)
            else:
                P[6:, 6:] = np.diag((np.concatenate(
                    [self._prior[g] for g in lay.groups]) / s) ** 2) if lay.groups else 0.0
            P[0:6, 0:6] = np.eye(6)
            self._filter.P = P
            self._filter.x = np.zeros(lay.n)
        n_buf = len(self._take_imu()[0])
        if n_buf:
            self._keep_imu_from(n_buf)
        logging.getLogger('imu_calib_ros.estimator').error(
            'calibration filter diverged (%s): estimate rolled back to the last good block',
            reason)

    def _status(self, now_ns: int | None) -> tuple[str, str]:
        """('OK'|'WARN'|'ERROR'|'STALE', one-line message)."""
        g = self._guard
        cfg = self.guard_config
        if self._diverged is not None:
            return 'ERROR', f'filter diverged: {self._diverged}; use the last good calibration'
        if g.units_error is not None:
            return 'ERROR', g.units_error
        if now_ns is not None and (g.last_kept_ns is None
                                   or now_ns - g.last_kept_ns > cfg.stale_after_s * 1e9):
            return 'STALE', 'no IMU samples accepted recently'
        if g.rejected['joint_missing_names'] and self.counters['joint_samples'] == 0:
            return 'WARN', ('joint states lack the fixture joints '
                            f'{", ".join(self._joint_names)} (got '
                            f'{", ".join(g.unknown_joint_names) or "none"})')
        newest = g.last_stamp_ns
        if g.last_event_ns is not None and newest is not None \
                and newest - g.last_event_ns <= cfg.warn_hold_s * 1e9:
            bad = {k: v for k, v in g.rejected.items() if v}
            what = ', '.join(f'{k} {v}' for k, v in sorted(bad.items())) or 'none'
            return 'WARN', f'bad input: rejected {what}; gaps {g.flagged["gap"]}'
        return 'OK', 'ok'

    def _last_good_result(self) -> Any:
        """CalibrationResult of the last good snapshot (cached), or None."""
        st = self._last_good_state if self._diverged is not None else (
            self._good[-1] if self._good else None)
        if st is None:
            return None
        if self._last_good_cache is None or self._last_good_cache[0] != id(st):
            self._last_good_cache = (id(st), self._result_from_state(
                st, self._frame(),
                lambda sd: {'estimator': {
                    'last_good_snapshot': True,
                    'lever_arm_imu_m': [float(v) for v in st.lever_arm_imu_m],
                    'estimated_groups': list(self.layout.groups)}}))
        return self._last_good_cache[1]

    def _result_from_state(self, st: Estimate, frame_id: str,
                           extra_of: Callable[[FloatArray], dict[str, Any]]) -> Any:
        """An estimate as a CalibrationResult: estimated groups carry their sigma, the others
        their prior sigma and are listed as fixed; ``extra_of(sd)`` gives the extra keys."""
        lay = self.layout
        sig_g = np.zeros(em.N_GYRO)
        sig_a = np.zeros(em.N_ACCEL)
        for grp in em.GYRO_GROUPS:
            sig_g[em.gyro_cols(grp)] = self._prior[grp]
        for grp in em.ACCEL_GROUPS:
            sig_a[em.accel_cols(grp)] = self._prior[grp]
        sd = np.sqrt(np.clip(np.diag(st.covariance), 0.0, None))
        for grp in lay.groups:
            sl = slice(lay.slices[grp].start - 6, lay.slices[grp].stop - 6)
            if grp in em.GYRO_GROUPS:
                sig_g[em.gyro_cols(grp)] = sd[sl]
            elif grp in em.ACCEL_GROUPS:
                sig_a[em.accel_cols(grp)] = sd[sl]
        errors = em.errors_from_theta(st.theta_gyro, st.theta_accel, sm.SensorErrors)
        sigma = em.errors_from_theta(sig_g, sig_a, sm.SensorErrors)
        fixed = tuple(k for k, gs in CONTRACT_KEYS.items()
                      if not any(grp in lay.groups for grp in gs))
        return CalibrationResult(errors=errors, sigma=sigma, frame_id=frame_id, fixed=fixed,
                                 extra=extra_of(sd))

    # ------------------------------------------------------------------ alignment
    def _try_initialise(self) -> bool:
        """Coarse alignment on the first stationary window (levelling + fixture heading)."""
        t, w, f = self._take_imu()
        if len(t) < 3 or len(self._jt) < 2:
            return False
        cfg = self.config
        jt = np.array(self._jt, np.int64)
        jq = np.array(self._jq)
        win_ns = int(cfg.init_window_s * 1e9)
        moving = np.any(np.abs(np.diff(jq, axis=0)) > cfg.stationary_joint_tolerance_rad, axis=1)
        # first joint sample from which the joints stay put for a whole window
        mv = np.nonzero(moving)[0]  # motion between sample i and i + 1
        starts = np.concatenate([[0], mv + 1])
        stops = np.concatenate([mv, [len(jt) - 1]])  # last sample of each still run
        ok = np.nonzero(jt[stops] - jt[starts] >= win_ns)[0]
        if ok.size == 0:
            # still waiting: keep only the current still run (bounded memory)
            start_j = int(starts[-1])
            t_start = jt[start_j]
            k0 = int(np.searchsorted(t, t_start))
            if k0 > 0:
                self.counters['imu_dropped_before_alignment'] += k0
                self._keep_imu_from(k0)
            self._jt, self._jq = self._jt[start_j:], self._jq[start_j:]
            return False
        start_j = int(starts[ok[0]])
        t_start = jt[start_j]
        k0 = int(np.searchsorted(t, t_start))
        if k0 > 0:
            self.counters['imu_dropped_before_alignment'] += k0
            self._keep_imu_from(k0)
            t, w, f = self._take_imu()
        if len(t) < 3 or t[-1] < t_start + win_ns:
            return False
        stop_j = int(stops[ok[0]])
        k1 = int(np.searchsorted(t, t_start + win_ns, side='right'))
        tw, ww, fw = t[:k1], w[:k1], f[:k1]
        dts = np.diff(tw)
        if len(dts) < 2:
            return False
        self._nominal_dt = float(np.median(dts)) * 1e-9
        rate = 1.0 / self._nominal_dt
        self._n = max(1, int(round(rate / cfg.update_rate_hz)))
        j1 = min(stop_j + 1, int(np.searchsorted(jt, t_start + win_ns, side='right')))
        q_mean = jq[start_j:j1].mean(axis=0)  # the window only: same for any push pattern
        w_c, f_c = sm.compensate(self._errors, ww, fw, np.zeros_like(ww))
        f_mean = f_c.mean(axis=0)
        R_fix = self.fixture.R_enu_imu(q_mean) @ Rotation.from_rotvec(self._mount).as_matrix()
        up = R_fix @ f_mean
        up /= np.linalg.norm(up)
        axis = np.cross(up, [0.0, 0.0, 1.0])
        s = np.linalg.norm(axis)
        ang = math.atan2(s, up[2])
        R_lev = Rotation.from_rotvec(axis / s * ang).as_matrix() if s > 0 else np.eye(3)
        R0 = R_lev @ R_fix
        if cfg.noise_source == 'data' and self.start is None:
            self._noise = self._noise_from_data(w_c, f_c)
        if self._unsettled:  # after a gate cascade or a restart: the start is poor
            self._settle_until_ns = int(t[0]) + int(cfg.settle_s * 1e9)
            self._unsettled = False
        self._nav = Strapdown(self.fixture.site, R0)
        self._start_filter()
        self._running = True
        self._t0_ns = int(t[0])
        self._prev = None
        return True

    def _noise_from_data(self, w: FloatArray, f: FloatArray) -> tuple[float, float]:
        """White-noise densities from the stationary window (Allan deviation at the shortest
        tau, where white noise dominates: N = sigma_A(tau) sqrt(tau))."""
        import allantools
        rate = 1.0 / self._nominal_dt
        out = []
        for x in (w, f):
            dens = []
            for a in range(3):
                taus, adev, _, _ = allantools.oadev(x[:, a], rate=rate, data_type='freq',
                                                    taus=np.array([self._nominal_dt * 2]))
                dens.append(adev[0] * math.sqrt(taus[0]))
            out.append(float(np.sqrt(np.mean(np.square(dens)))))
        return out[0], out[1]

    def _start_filter(self) -> None:
        cfg = self.config
        lay = self.layout
        p0 = np.zeros(lay.n)
        p0[0:2] = cfg.initial_tilt_sigma_rad
        p0[2] = max(cfg.initial_heading_sigma_rad, float(self._prior['mounting'][2]))
        p0[3:6] = cfg.initial_velocity_sigma_m_s
        for g in lay.groups:
            p0[lay.slices[g]] = self._prior[g]
        P0 = np.diag((p0 / lay.scale) ** 2)
        self._filter = ErrorStateFilter(lay, P0, cfg.gate_probability)
        gr = self.grade
        qg = qa = 0.0
        if gr is not None:
            qg = (2.0 * gr.gyro_bias_instability_rad_s ** 2 / gr.gyro_bias_correlation_s
                  + gr.gyro_bias_random_walk_rad_s2_rt_hz ** 2)
            qa = (2.0 * gr.accel_bias_instability_m_s2 ** 2 / gr.accel_bias_correlation_s
                  + gr.accel_bias_random_walk_m_s3_rt_hz ** 2)
        st = self.start
        if st is not None:  # item 5: the random walk the data show, if larger
            qg = max(qg, st.gyro_bias_random_walk_rad_s2_rt_hz ** 2)
            qa = max(qa, st.accel_bias_random_walk_m_s3_rt_hz ** 2)
            if gr is None and st.gyro_noise_rad_s_rt_hz > self.config.aiding_gyro_noise_rad_s_rt_hz:
                # a MEMS unit and no grade: never assume its biases constant (the stationary
                # windows of a short plan cannot show a 100 s instability)
                qg = max(qg, (MEMS_BIAS_WALK[0] * st.gyro_noise_rad_s_rt_hz) ** 2)
                qa = max(qa, (MEMS_BIAS_WALK[1] * st.accel_noise_m_s2_rt_hz) ** 2)
        self._bias_q = (max(qg, self._bias_q_seed[0]), max(qa, self._bias_q_seed[1]))
        self._set_process_noise()

    def _set_process_noise(self) -> None:
        """Q per second (scaled) from the white noise and the bias walk x its adaptation."""
        lay = self.layout
        k = self.config.noise_scale
        qg, qa = (q * self._bias_q_scale for q in self._bias_q)
        q1 = process_noise(lay, 1.0, k * self._noise[0], k * self._noise[1], qg, qa)
        self._q1_s = np.diag(np.diag(q1) / lay.scale ** 2)

    def _adapt_bias_noise(self) -> None:
        """Item 5: a bias drift nobody declared shows as innovations larger than the filter
        predicts. When the mean NIS per dof over the last ``nis_window`` updates stands out of
        its chi-square spread (4 sigma) or gated updates appear, the biases' random walk is
        doubled (seeded, when none was measured, at 1e-3 of the white noise density per
        sqrt(s), gyro, and 1e-2, accelerometer): covariance matching, one way only."""
        c = self._filter.counters if self._filter is not None else None
        hist = self._nis_hist
        if c is None or len(hist) < 2:
            return
        a0, r0, s0 = hist[0]
        a1, r1, s1 = hist[-1]
        acc, rej = a1 - a0, r1 - r0
        if acc + rej < self.guard_config.nis_window:
            return
        mean = (s1 - s0) / max(acc, 1) / 3.0
        if mean < 1.0 + 4.0 * math.sqrt(2.0 / (3.0 * max(acc, 1))) and rej == 0:
            return
        if not any(self._bias_q):  # kept across re-alignments, like the scale
            self._bias_q_seed = ((1e-3 * self._noise[0]) ** 2, (1e-2 * self._noise[1]) ** 2)
            self._bias_q = self._bias_q_seed
        elif self._bias_q_scale < 2.0 ** 30:
            self._bias_q_scale *= 2.0
        else:
            return
        self.counters['bias_noise_adaptations'] += 1
        self._set_process_noise()
        self._nis_hist.clear()  # judge the new Q on fresh updates

    # ------------------------------------------------------------------ processing
    def _process(self, final: bool = False) -> None:
        if not self._running:
            if not self._try_initialise():
                return
        t, w, f = self._take_imu()
        n = self._n
        need = n + 1  # one sample of look-ahead for the central differences
        if len(t) < need:
            return
        n_chunks = (len(t) - 1) // n
        aiding = self.attitude_aiding
        if aiding and not final and self._jt:
            # wait for joint states beyond a chunk end (unless they stopped coming)
            t_j = self._jt[-1]
            wait_ns = int(self.config.max_pending_s * 1e9)
            if t[-1] - t_j < wait_ns:
                ends = t[n - 1:n * n_chunks:n]
                n_chunks = int(np.searchsorted(ends, t_j, side='right'))
        done = 0
        while done < n_chunks and self._running:
            k0 = done * n
            # feedback after every update while settling (large uncertainty, issue 11), then
            # blocks of block_chunks; whole blocks only, so that pushes and batches agree
            settle = self._settle_until_ns
            bc = 1 if settle is not None and t[k0] < settle else self.config.block_chunks
            b = min(bc, n_chunks - done) if final else bc
            if done + b > n_chunks:
                break
            k1 = k0 + b * n
            self._run_block(t[k0:k1 + 1], w[k0:k1 + 1], f[k0:k1 + 1], b)
            done += b
            if self._cascade:
                self._realign()
                break
        if done:
            self._keep_imu_from(done * n)
            self._trim_joints()

    def _realign(self) -> None:
        """A run of gated updates means the navigation left the linear region, not that every
        measurement is wrong (METHODS.md section 4): drop the navigation states, keep the
        calibration states and their covariance, re-align at the next stationary window."""
        self._cascade = False
        self._gated_run = 0
        self.counters['realignments'] += 1
        self._unsettled = True
        _LOG.warning('%d measurement updates in a row failed the gate: navigation re-aligned '
                     'at the next stationary window (calibration kept)',
                     self.config.cascade_updates)
        self._drop_navigation()

    def _trim_joints(self) -> None:
        if self._t_last_ns is None or len(self._jt) < 3:
            return
        k = bisect.bisect_left(self._jt, self._t_last_ns) - 2  # the list may hold a whole run
        if k > 0:
            del self._jt[:k]
            del self._jq[:k]

    def _run_block(self, t: NDArray[np.int64], w: FloatArray, f: FloatArray, B: int) -> None:
        """Process ``B`` chunks: ``t, w, f`` hold ``B n`` samples plus one look-ahead."""
        assert self._nav is not None and self._filter is not None and self._q1_s is not None
        n = self._n
        m = B * n
        nom = self._nominal_dt
        lay = self.layout
        # intervals; a gap (> 1.5 nominal periods) is a sample of one nominal period
        if self._prev is None:
            t_prev, w_prev, f_prev = int(t[0]) - int(round(nom * 1e9)), w[0], f[0]
        else:
            t_prev, w_prev, f_prev = self._prev
        tt = np.concatenate([[t_prev], t]).astype(np.int64)
        dt_all = np.diff(tt) * 1e-9  # (m + 1,)
        gap = dt_all > 1.5 * nom
        n_gaps = int(gap[:m].sum())
        dt_all = np.where(gap, nom, dt_all)
        ww = np.vstack([w_prev, w])  # (m + 2, 3): previous, block, look-ahead
        ff = np.vstack([f_prev, f])
        # central differences of mean rates: omega_dot at the interval (Kozlov eq. 1 term)
        den = (dt_all[:-1] + dt_all[1:])[:, None]
        # of the compensated rates: with raw ones, a raw unit's 0.5 % scale error made the
        # size effect 1 % (6 sigma) wrong (issue 11); the gyro part needs no omega_dot
        ww = sm.compensate(self._errors, ww, ff, np.zeros_like(ww))[0]
        wd = (ww[2:] - ww[:-2]) / den  # (m, 3)
        fd = (ff[2:] - ff[:-2]) / den
        wd_all = np.vstack([wd, wd[-1:]])  # look-ahead: reuse
        w_c, f_c = sm.compensate(self._errors, w, f, wd_all)
        tau = self._theta_a[em.accel_cols('time_offset')][0]
        if tau != 0.0:
            f_c = f_c - tau * np.vstack([fd, fd[-1:]])
        dt = dt_all[:m]
        if n_gaps:
            self.counters['gaps'] += n_gaps
            self._nav.reset_memory()
        R_start = self._nav.R_enu_imu
        nav = self._nav.propagate(dt, w_c[:m], f_c[:m])
        R_mid = 0.5 * (np.concatenate([R_start[None], nav.R_enu_imu[:-1]]) + nav.R_enu_imu)
        # sensor Jacobians on the compensated samples
        Mg, Ma = em.compensated_jacobians(self._errors, w_c[:m], wd, f_c[:m], fd)
        om = self.fixture.site.omega_ie_enu
        rows = chunk_transition_rows(lay, R_mid.reshape(B, n, 3, 3),
                                     nav.f_enu_m_s2.reshape(B, n, 3),
                                     Mg.reshape(B, n, 3, em.N_GYRO),
                                     Ma.reshape(B, n, 3, em.N_ACCEL), dt.reshape(B, n), om)
        s = lay.scale
        rows_s = rows * (s[None, None, :] / s[None, 0:6, None])
        T = dt.reshape(B, n).sum(axis=1)
        # zero-velocity measurement with the lever arm, at each chunk end
        ends = np.arange(n - 1, m, n)
        R_end = nav.R_enu_imu[ends]
        w_end = 0.5 * (w_c[ends] + w_c[ends + 1])  # rate at the chunk-end instant
        w_eb = w_end - om @ R_end  # R_end^T omega_ie per chunk end
        u = w_eb @ skew(self._rho)  # omega_eb x rho (np.cross costs 10x on (B, 3))
        Ru = (R_end @ u[:, :, None])[:, :, 0]
        z_v = (nav.v_enu_m_s[ends] - Ru) / MEAS_SCALE
        H_v = np.zeros((B, 3, lay.n))
        H_v[:, :, 3:6] = np.eye(3)
        H_v[:, :, 0:3] = skew(Ru)
        if 'lever_arm' in lay.slices:
            H_v[:, :, lay.slices['lever_arm']] = -R_end @ skew(w_eb)
        H_v *= s[None, None, :] / MEAS_SCALE
        R_v = np.eye(3) * (self.config.velocity_sigma_m_s / MEAS_SCALE) ** 2
        # attitude from the encoders (with the mounting rotation)
        z_a = H_a = None
        have_att = np.zeros(B, bool)
        if self.attitude_aiding and self._jt:
            te = t[ends]
            have_att = (te >= self._jt[0]) & (te <= self._jt[-1])
            self.counters['attitude_updates_without_joints'] += int((~have_att).sum())
            if have_att.any():
                # only the joint samples around this block: the buffer may hold a whole run
                te_in = te[have_att]
                j0 = max(bisect.bisect_right(self._jt, int(te_in[0])) - 3, 0)
                j1 = bisect.bisect_left(self._jt, int(te_in[-1])) + 3
                jt = np.array(self._jt[j0:j1], np.int64)
                jq = np.array(self._jq[j0:j1])
                rel = (te - jt[0]).astype(float) * 1e-9
                jrel = (jt - jt[0]).astype(float) * 1e-9
                q_end = _interp_joints(rel, jrel, jq)
                R_pred = self.fixture.R_enu_imu(q_end) @ Rotation.from_rotvec(
                    self._mount).as_matrix()
                z_a = Rotation.from_matrix(R_end @ np.swapaxes(R_pred, 1, 2)).as_rotvec()
                z_a /= MEAS_SCALE
                H_a = np.zeros((B, 3, lay.n))
                H_a[:, :, 0:3] = np.eye(3)
                if 'mounting' in lay.slices:
                    H_a[:, :, lay.slices['mounting']] = -R_end
                H_a *= s[None, None, :] / MEAS_SCALE
        R_a = np.eye(3) * (self.config.attitude_sigma_rad / MEAS_SCALE) ** 2
        filt = self._filter
        q1_diag_s = np.diag(self._q1_s)
        for b in range(B):
            filt.predict_rows(rows_s[b], q1_diag_s * T[b])
            if filt.update('velocity', z_v[b], H_v[b], R_v):
                self._gated_run = 0
            else:
                self._gated_run += 1
                self._cascade = self._gated_run >= self.config.cascade_updates
            if have_att[b]:
                filt.update('attitude', z_a[b], H_a[b], R_a)  # type: ignore[index]
        if n_gaps:  # motion during a gap is lost: widen the navigation uncertainty
            filt.P[0:3, 0:3] += np.eye(3) * (1e-3 / lay.scale[0]) ** 2 * n_gaps
            filt.P[3:6, 3:6] += np.eye(3) * (1e-2 / lay.scale[3]) ** 2 * n_gaps
        self._feedback()
        self._prev = (int(t[m - 1]), w[m - 1], f[m - 1])
        self._t_last_ns = int(t[m - 1])
        self.counters['imu_processed'] += m
        self.counters['chunks'] += B

    def _feedback(self) -> None:
        """Apply the error state to the navigator and the parameter estimates; zero it."""
        assert self._filter is not None and self._nav is not None
        lay = self.layout
        x = self._filter.x * lay.scale
        self._nav.correct(x[0:3], x[3:6])
        self._theta_g[lay.gyro_cols] -= x[lay.gyro_state_idx]
        self._theta_a[lay.accel_cols] -= x[lay.accel_state_idx]
        if 'lever_arm' in lay.slices:
            self._rho = self._rho - x[lay.slices['lever_arm']]
        if 'mounting' in lay.slices:
            self._mount = (Rotation.from_rotvec(self._mount)
                           * Rotation.from_rotvec(-x[lay.slices['mounting']])).as_rotvec()
        self._filter.x = np.zeros(lay.n)
        self._errors = self._make_errors()

    def _make_errors(self) -> Any:
        return em.errors_from_theta(self._theta_g, self._theta_a, sm.SensorErrors)

    def _state_values(self) -> FloatArray:
        return self._values_of(self._theta_g, self._theta_a, self._rho, self._mount)

    def _values_of(self, tg: FloatArray, ta: FloatArray, rho: FloatArray,
                   mount: FloatArray) -> FloatArray:
        """Calibration-state values (no psi, dv) of parameter arrays."""
        lay = self.layout
        out = np.zeros(lay.n)
        out[lay.gyro_state_idx] = tg[lay.gyro_cols]
        out[lay.accel_state_idx] = ta[lay.accel_cols]
        if 'lever_arm' in lay.slices:
            out[lay.slices['lever_arm']] = rho
        if 'mounting' in lay.slices:
            out[lay.slices['mounting']] = mount
        return out[6:]

    def _extra(self, est: Estimate, sd: FloatArray) -> dict[str, Any]:
        lay = self.layout
        out: dict[str, Any] = {
            'lever_arm_imu_m': [float(v) for v in est.lever_arm_imu_m],
            'mounting_rotvec_rad': [float(v) for v in est.mounting_rotvec_rad],
            'time_offset_s': float(est.theta_accel[em.accel_cols('time_offset')][0]),
            'estimated_groups': list(lay.groups),
            'attitude_aiding': self.attitude_aiding,
        }
        if self.start is not None:  # what the data chose (issue 11)
            out['coarse_start'] = self.start.summary()
        for g in ('lever_arm', 'mounting', 'time_offset'):
            if g in lay.slices:
                sl = slice(lay.slices[g].start - 6, lay.slices[g].stop - 6)
                out[f'{g}_sigma'] = [float(v) for v in sd[sl]]
        h = self.health()
        out['health'] = {k: v for k, v in h.items()
                         if isinstance(v, (int, float, bool, str))}
        return out


def _interp_joints(t_s: FloatArray, tj_s: FloatArray, qj: FloatArray) -> FloatArray:
    """Joint angles at ``t_s`` by a cubic spline through the samples (linear interpolation
    through a 20 Hz record of an accelerating move biased the gyro scale by 44-77 ppm;
    issue 11), clamped to the record's ends."""
    if len(tj_s) < 4:
        return np.stack([np.interp(t_s, tj_s, qj[:, i]) for i in range(qj.shape[1])], axis=1)
    from scipy.interpolate import CubicSpline
    return CubicSpline(tj_s, qj, axis=0)(np.clip(t_s, tj_s[0], tj_s[-1]))


def _point_to_mean(w: FloatArray, f: FloatArray,
                   prev: tuple[int, FloatArray, FloatArray] | None
                   ) -> tuple[FloatArray, FloatArray]:
    """Point samples as interval means (CONTRACT 1 option): the trapezoid of each sample and
    the one before it, exact for rates linear over the interval (the first sample, without a
    predecessor, stands for itself)."""
    w0 = w[:1] if prev is None else prev[1][None, :]
    f0 = f[:1] if prev is None else prev[2][None, :]
    return (0.5 * (w + np.vstack([w0, w[:-1]])), 0.5 * (f + np.vstack([f0, f[:-1]])))


def check_finite(x: FloatArray, what: str) -> None:
    """Raise :class:`InputError` if ``x`` holds NaN or inf."""
    if not np.all(np.isfinite(x)):
        raise InputError(f'{what}: non-finite values')
