"""Streaming calibration estimator: strapdown navigator + augmented-state error EKF (issue 3).

One implementation serves the live node (single samples) and offline replay (batches). The
step loop, in the order a sample meets it:

1. **push**: the input guard (:mod:`~imu_calib_ros.core.input_guard`) drops and counts bad
   samples (:meth:`CalibrationEstimator._push_imu_arrays`);
2. **hold or accept**: without a start the first data are held until the coarse start is
   determined (:mod:`.bootstrap`), then handed back in push order; accepted samples are
   split at gaps (:meth:`~CalibrationEstimator._accept_imu`) and buffered (:mod:`.buffers`);
3. **align** at the first stationary window (:mod:`.alignment`), then **blocks**: samples in
   *chunks* of ``n = imu_rate / update_rate`` between two measurement updates, chunks in
   blocks of ``config.block_chunks`` (:meth:`~CalibrationEstimator._process`);
4. per block, **propagate** (:mod:`.propagation`: compensation with the current estimate,
   ``Strapdown.propagate``, each chunk's transition rows), then per chunk one **predict**
   and gated **updates** (:mod:`.ekf`) with the zero-velocity-with-lever-arm and, with
   encoder aiding, the encoder-attitude measurements (:mod:`.measurements`);
5. **feedback** of the error state at the block end (navigator correction, new
   compensation);
6. **health** after every block (:mod:`.health`): a healthy block is a snapshot and may adapt
   the bias noise (:mod:`.noise`); a cascade of gated updates re-aligns, a divergence
   restarts from the coarse start and at last rolls back to the last good snapshot.

Inside a block the error state is carried (not fed back), which is exact for a linear model
and keeps the errors small enough for the linearisation (a block is 5 s by default: per-block
Python overhead dominated at 1 s; 5 s blocks replay 1.6x faster and move no nav-grade or MEMS
state by more than 0.04 sigma, 10 s blocks moved a MEMS state by 0.34 sigma). While the
uncertainty is large (``settle_s`` after a re-alignment or restart) every chunk is a block.

The prior (:mod:`.priors`) and the result (:mod:`.result`: :class:`Estimate`, the CONTRACT 4
file) have their own modules; the names they used to have here are re-exported.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from .. import sensor_model as sm
from ..errors import InputError
from ..input_guard import GuardConfig, InputGuard
from ..joint_merge import JointMerger
from ..rotation import rotvec_to_matrix, skew
from ..stamp_clock import scatter_hint
from ..strapdown import Strapdown
from ..types import ImuBatch, ImuSample, JointBatch, JointSample
from . import error_model as em
from .alignment import (STILL_NOISE_SIGMAS, align, initial_covariance, level_coupling,
                        still_run, window_tolerance_rad)
from .bootstrap import Bootstrap
from .buffers import ImuBuffer, JointBuffer, encoder_noise_rad, point_to_mean
from .coarse import BASE_TILT_PRIOR_RAD, CoarseStart, implausible, timing_group_size
from .config import EstimatorConfig
from .ekf import ErrorStateFilter
from .history import EstimateHistory
from .health import (NisWindow, bridge_gap, bridge_motion_covariance,
                     interpolated_gap_variance, numerical_fault, restart_covariance,
                     rollback_covariance, snapshots, state_out_of_range, status,
                     widen_for_gaps, widen_navigation)
from .chain_consider import ChainConsider
from .measurements import (MEAS_SCALE, MEASUREMENT_DOF, chain_attitude_covariance,
                           chain_velocity_covariance, encoder_attitude, link_error_chains,
                           noise_covariance, to_filter_units, zero_velocity)
from .noise import (MEMS_BIAS_WALK, ProcessNoise, bias_random_walk, bias_walk_sources,
                    check_grade_hint, instability_covered, white_noise_densities,
                    white_noise_from_window)
from .priors import (COARSE_FLOOR, RAW_PRIOR, WorkingPoint, prior_point,
                     prior_shift, prior_sigmas, prior_vector, sample_kernel_mean)
from .propagation import Block, omega_dot_half_span, propagate_block
from .result import (CONTRACT_KEYS, Estimate, calibration_result, estimator_extra,
                     parameter_covariance, snapshot_extra, values_of, with_values)

__all__ = ['CalibrationEstimator', 'Estimate', 'prior_sigmas', 'CONTRACT_KEYS', 'RAW_PRIOR',
           'COARSE_FLOOR', 'MEMS_BIAS_WALK', 'MEAS_SCALE']

FloatArray = NDArray[np.float64]
_LOG = logging.getLogger('imu_calib_ros.estimator')
MIN_NIS_UPDATES = 100  # least accepted updates of a kind for its whole-run NIS to count
# A chain joint's rate is clamped to zero where it stays within the stillness tolerance
# (still_tolerance_rad: stationary_joint_tolerance_rad, or six encoder-noise sigmas where
# larger) over at least this either side of an update (buffers.JointBuffer.motion_at): the
# clamp is then wrong by at most ~tol / window at a move's start or end (+-3 samples at
# 100 Hz: up to 3e-3 rad/s at the 0.1 mrad setting, 2-3 mm/s at the end of an arm, gated
# against a tactical unit's zero-velocity noise and read as bias walk by the NIS adaptation;
# proportionally more on noisier encoders). The filter waits for joint states this
# far beyond a chunk end (live and offline alike).
CHAIN_STILL_HALF_WINDOW_S = 0.25
#: the latest joint samples whose second differences give the encoders' noise (and the
#: fewest that do), :meth:`CalibrationEstimator._rate_weight`
ENCODER_NOISE_SAMPLES = 4000
ENCODER_NOISE_MIN = 50
#: rms derivative of a cubic spline through unit white noise at unit spacing, at instants
#: spread over the intervals (1.17 at the knots; numerical, scipy's not-a-knot spline)
SPLINE_RATE_NOISE = 1.57
RATE_WEIGHT_EVERY = 20  # blocks between two estimates of the encoders' weight
#: the prior of the base tilt's residual states: this many of the coarse fit's sigmas, at
#: least TILT_PRIOR_FLOOR_RAD (the coarse fit's model is the windows' alone), at most the
#: coarse fit's own prior (coarse.BASE_TILT_PRIOR_RAD: a small-angle state)
TILT_PRIOR_SIGMAS = 10.0
TILT_PRIOR_FLOOR_RAD = 5e-4
#: joint states a motion bridge waits for beyond its end (JointBuffer.spline_error_at reads 8)
BRIDGE_JOINTS_AHEAD = 9


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
    start:
        Optional :class:`~.coarse.CoarseStart` (a previous pass's): no data are held to
        measure one.
    """

    # the working point the navigator compensates with (the feedback moves it)
    _theta_g: FloatArray  # (22,) gyro parameters, error_model order
    _theta_a: FloatArray  # (26,) accelerometer parameters
    _rho: FloatArray  # (3,) lever arm, IMU frame [m]
    _mount: FloatArray  # (3,) mounting rotation vector, IMU frame [rad]
    _joint_offsets: FloatArray  # (k,) a general chain's joint zero offsets [rad] (issue 15)
    _errors: Any  # SensorErrors of the above (what sensor_model.compensate takes)
    _point_prev: tuple[int, FloatArray, FloatArray] | None  # last raw point sample

    def __init__(self, fixture: Any, grade: Any = None, config: EstimatorConfig | None = None,
                 initial: Estimate | None = None, start: CoarseStart | None = None) -> None:
        self.fixture = fixture  # on the base as it stands once the coarse start measured it
        self._nominal_fixture = fixture  # as the fixture file says
        self._prior_mean_cache: tuple[tuple[Any, Any, Any], FloatArray] | None = None
        self.grade = grade  # a hint (prior floors, noise with noise_source 'grade'), or None
        self.config = config or EstimatorConfig()
        self._initial = initial
        self._given_start = start
        self._joint_names = tuple(fixture.joint_names)
        self._chain_fixtures: tuple[Any, ...] | None = None  # general chains (issue 15)
        # the arm errors' share of the mounting and lever arm (issue 15 item 4)
        self._consider = None if fixture.concurrent else ChainConsider(fixture)
        self.reset()

    # ------------------------------------------------------------------ public API
    def reset(self) -> None:
        """Forget all data; back to waiting for a stationary window (and, without a given
        start, to holding the first data for the coarse start)."""
        cfg = self.config
        self.start = self._given_start
        # issue 11: without a start, hold the first data until the coarse start is determined
        self._boot: Bootstrap | None = (Bootstrap(cfg) if cfg.auto_start and self.start is None
                                        else None)
        self.restarts = 0
        self.counters: dict[str, int] = {
            'imu_samples': 0, 'joint_samples': 0, 'imu_processed': 0, 'chunks': 0,
            'imu_dropped_before_alignment': 0, 'imu_out_of_order': 0, 'imu_non_finite': 0,
            'joint_out_of_order': 0, 'joint_missing_names': 0, 'joint_non_finite': 0, 'gaps': 0,
            'attitude_updates_without_joints': 0,
            'imu_dropped_at_gap': 0, 'gaps_bridged': 0, 'gaps_reinitialised': 0,
            'gaps_interpolated': 0, 'gaps_bridged_in_motion': 0, 'imu_interpolated': 0,
            'updates_skipped_in_gaps': 0,
            'divergences': 0, 'restarts': self.restarts, 'realignments': 0,
            'bias_noise_adaptations': 0, 'bias_walk_raised': 0}
        self._configure()
        self._process_noise = ProcessNoise(cfg.noise_scale)
        self._reset_filter_side()
        self.frame_id = ''  # header.frame_id of the first accepted IMU data
        self._running = False
        self._nav: Strapdown | None = None
        self._filter: ErrorStateFilter | None = None
        self._imu = ImuBuffer()
        self._joints = JointBuffer(self.counters)
        # joint travel that counts as rest, from the first still window (still_tolerance_rad)
        self._still_tol: float | None = None
        self._prev: tuple[Any, FloatArray, FloatArray] | None = None  # last raw samples used
        self._half_span = 1  # samples each side of an omega_dot difference (propagation)
        self._rate_a: float | None = None  # the encoders' weight in the lever arm's rate
        self._rate_calls = 0
        self._nominal_dt = 0.0
        self._n = 1  # samples per chunk
        self._t0_ns: int | None = None
        self._t_last_ns: int | None = None
        # bad input and faults (issue 6, core/input_guard.py)
        gcfg = getattr(self, 'guard_config', None) or GuardConfig()
        self.guard_config: GuardConfig = gcfg
        self._guard = InputGuard(gcfg, self.fixture.site.gravity, self._joint_names,
                                 self.fixture.angular_axes_enu)
        self._merger: JointMerger | None = None  # joint states one axis at a time
        # the stamps the start's held data were revised to, for this pass too
        self._revised: tuple[Any, Any] = (None, None) if self.start is None \
            else self.start.stamp_revisions
        self._guard.imu_clock.hindsight, self._guard.joint_clock.hindsight = self._revised
        self._diverged: str | None = None
        self._good: deque[Estimate] = snapshots(gcfg, cfg.block_chunks)  # healthy blocks
        self._last_good_state: Estimate | None = None
        self._last_good_cache: tuple[int, Any] | None = None
        self._nis = NisWindow(gcfg.nis_window)
        self._kept_cal_P: FloatArray | None = None  # calibration block of P while re-aligning
        self._kept_sens: FloatArray | None = None  # and of the filter's prior sensitivity
        self._good_sens: deque[FloatArray | None] = deque(maxlen=self._good.maxlen)
        self._level_M: FloatArray | None = None  # the alignment's tilt coupling, to apply once
        # the gate counters of every filter of the run (a new filter at every (re-)alignment,
        # restart and re-initialisation), for the whole-run NIS (self-check, covariance scale)
        self._run_counters: list[Any] = []
        self.first_filter_dropped: int | None = None  # imu_dropped_before_alignment then
        # issue 12: values, sigmas and NIS against time (extra.history of the result)
        self.history = EstimateHistory()

    def reset_navigation(self) -> None:
        """Restart the navigation after a backward time jump (a looping bag, ``use_sim_time``).

        Drops the navigation states, the filter's navigation block and every buffered IMU and
        joint sample (those waiting to be merged too), and resets the input guard's stamp
        memory (the earlier stamps that now come are accepted; its rejection counters are
        kept). The calibration states and their covariance block are kept, as after a long
        gap (``_on_gap``, policy 'reinitialise'), and the filter re-aligns at the next
        stationary window.
        """
        self._drop_navigation()
        self._imu = ImuBuffer()
        self._joints.clear()
        self._t_last_ns = None
        self._guard.reset_stamps()
        self._merger = None  # its series hold the stamps before the jump
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
        """Add one joint-state sample (names in any order; other joints ignored; a sample
        with only some of the fixture joints goes through :class:`~..joint_merge.JointMerger`)."""
        if self._partial(sample.names):
            self._push_partial(np.array([sample.stamp_ns], np.int64), tuple(sample.names),
                               np.asarray(sample.positions_rad, float)[None, :])
            return
        q = self._guard.check_joint(int(sample.stamp_ns), tuple(sample.names),
                                    sample.positions_rad)
        t = self._guard.last_joint_clock_ns  # on the sender's clock (stamps taken on receipt)
        if q is not None and self._boot is not None:
            self._boot.hold_joints(np.array([t], np.int64), q[None, :])
        elif q is not None:  # joint stamps minus the measured latency: the instants they describe
            self._record_joints(t, q)
        self._sync_input_counters()

    def push_joint_batch(self, batch: JointBatch) -> None:
        """Add many joint-state samples: the same verdicts, unwrapping and buffers as
        :meth:`push_joint` one by one, vectorised (input guard ``check_joint_batch``)."""
        if self._partial(batch.names):
            self._push_partial(np.asarray(batch.stamps_ns, np.int64), tuple(batch.names),
                               np.asarray(batch.positions_rad, float))
            return
        self._accept_joints(batch.stamps_ns, tuple(batch.names), batch.positions_rad)

    @property
    def partial_joints_seen(self) -> tuple[str, ...]:
        """The fixture joints that came in joint states carrying only some of them."""
        m = self._merger
        return () if m is None else tuple(n for n in self._joint_names if n in m.seen)

    def _partial(self, names: Any) -> bool:
        """Some of the fixture joints but not all (one publisher per axis)."""
        have = set(names)
        wanted = self._joint_names
        return any(n in have for n in wanted) and not all(n in have for n in wanted)

    def _push_partial(self, t: Any, names: tuple[str, ...], q: Any) -> None:
        if self._merger is None:
            self._merger = JointMerger(self._joint_names)
        m = self._merger
        before = dict(m.rejected)
        t_full, q_full = m.push(t, names, q)
        for reason, k in m.rejected.items():
            self._guard.count_rejected(reason, k - before[reason])
        if len(t_full):
            self._accept_joints(t_full, self._joint_names, q_full)
        else:
            self._sync_input_counters()

    def _accept_joints(self, stamps_ns: Any, names: tuple[str, ...], positions: Any) -> None:
        t, q = self._guard.check_joint_batch(stamps_ns, names, positions)
        if len(t) and self._boot is not None:
            self._boot.hold_joints(t, q)
        elif len(t):
            self._record_joints(t, q)
        self._sync_input_counters()

    def flush(self) -> None:
        """Process every complete chunk (end of a bag), ignoring the joint look-ahead, and
        check the filter's health over that last stretch too."""
        if self._boot is not None:
            self._finish_bootstrap(final=True)
        self._joints.flush_group()
        self._process(final=True, end=True)
        self._check_divergence()
        self._record_history(force=True)

    def filter_accepted(self, kind: str) -> int:
        """Accepted updates of one kind (``'velocity'`` or ``'attitude'``)."""
        return 0 if self._filter is None else self._filter.counters.accepted.get(kind, 0)

    @property
    def is_running(self) -> bool:
        """True once the coarse alignment is done and the filter runs."""
        return self._running

    @property
    def joint_travel_rad(self) -> float:
        """Largest range (max - min) of any joint's accepted, unwrapped positions [rad]."""
        return self._joints.travel_rad

    def estimate_state(self) -> Estimate:
        """The current estimate (SI) with the covariance of the calibration states.

        After a start from a previous pass, the values are those of the grade's prior
        (:meth:`_prior_correction`); the navigator keeps compensating with its own.
        """
        lay = self.layout
        idx = np.arange(6, lay.n)
        s = lay.scale[idx]
        if self._filter is not None:
            P = self._filter.P[6:, 6:] * np.outer(s, s)  # idx: the states from 6 on
        elif self._kept_cal_P is not None:  # between a navigation reset and the re-alignment
            P = self._kept_cal_P * np.outer(s, s)
        else:
            P = np.diag(prior_vector(self._prior, lay.groups) ** 2) \
                if lay.groups else np.zeros((0, 0))
        values = self._state_values()
        tg, ta, rho, mount = (self._theta_g.copy(), self._theta_a.copy(), self._rho.copy(),
                              self._mount.copy())
        if self._prior_shift is not None and values.size:
            values = values - self._prior_correction()
            tg, ta, rho, mount = with_values(lay, values, tg, ta, rho, mount)
        if self._consider is not None and self._filter is not None:
            P = self._with_chain_consider(P)
        return Estimate(tg, ta, rho, mount, tuple(lay.labels()[6:]), values, P)

    def _with_chain_consider(self, P: FloatArray) -> FloatArray:
        """``P`` with the arm errors' share of the mounting and lever arm added to their
        blocks (:mod:`.chain_consider`; the reported covariance only, never the filter's)."""
        assert self._consider is not None
        cfg = self.config
        # estimated offsets are in the filter's P: only the link errors are considered
        sigma_q = 0.0 if self.layout.n_joint_offsets else cfg.chain_joint_offset_sigma_rad
        C_mu, C_rho = self._consider.covariance(sigma_q, cfg.chain_link_sigma_m)
        P = P.copy()
        for group, C in (('mounting', C_mu), ('lever_arm', C_rho)):
            if group in self.layout.slices:
                sl = self.layout.slices[group]
                s = slice(sl.start - 6, sl.stop - 6)
                P[s, s] += C
        return P

    def estimate(self, frame_id: str | None = None) -> Any:
        """The calibration as a :class:`~imu_calib_ros.core.calibration.CalibrationResult`.

        Estimated groups carry their filter sigma; the others their assumed value (zero) and
        prior sigma, and are listed as fixed (CONTRACT 4). ``frame_id`` None: the configured
        frame, else the ``header.frame_id`` of the data, else ``imu_link``.
        """
        st = self.estimate_state()
        scale = self.covariance_scale()
        if scale > 1.0:  # the reported covariance (covariance_scale): never the filter's own
            st = dataclasses.replace(st, covariance=st.covariance * scale)
        return calibration_result(
            st, self.layout, self._prior, frame_id or self._frame(),
            lambda sd: {'estimator': {**estimator_extra(st, sd, self.layout, self.health(),
                                                        self.attitude_aiding, self.start),
                                      'covariance_scale': float(scale),
                                      'bias_walk': self.bias_walk_summary(),
                                      **self._offset_names(),
                                      'settings_changed': self._settings_changed(),
                                      # CONTRACT 4 order, 4 digits (the report's envelope)
                                      'parameter_covariance': [
                                          [float(f'{v:.4g}') for v in row] for row in
                                          parameter_covariance(st, self.layout, self._prior)]},
                        **({'history': h} if (h := self.history.as_dict()) else {})})

    def _record_joints(self, t_ns: Any, q: FloatArray) -> None:
        """Accepted joint states into the joint record (:meth:`_recorded`; one state: a
        stamp and its angles, else arrays of them). Joint stamps the
        joint clock gave up on (taken on receipt, scattered by their delays): the record
        averages them in groups from then on (:meth:`.buffers.JointBuffer.set_group`), as
        many as the coarse start's (:func:`.coarse.timing_group_size`, at most 0.1 s of
        them: none below 20 Hz)."""
        jc = self._guard.joint_clock
        if jc.scattered and self._joints.group == 1:
            k = timing_group_size(jc.period_ns * 1e-9, jc.timing_sigma_ns * 1e-9)
            if k > 1:
                self._joints.set_group(k, jc.period_ns)
        if np.ndim(t_ns) == 0:
            self._joints.append(*self._recorded(t_ns, q))
        else:
            self._joints.extend(*self._recorded(t_ns, q))

    @property
    def still_tolerance_rad(self) -> float:
        """Joint travel that counts as rest (:func:`.alignment.still_tolerance_rad`): the
        config's until the first alignment, then the larger of it and six encoder-noise
        sigmas of that alignment's window."""
        return (self.config.stationary_joint_tolerance_rad if self._still_tol is None
                else self._still_tol)

    def _recorded(self, t_ns: Any, q: FloatArray) -> tuple[Any, FloatArray]:
        """Joint stamps and angles as the joint record holds them: the stamps minus the
        measured latency (the instants they describe), the angles plus the table's encoder
        zeros the coarse start measured."""
        return t_ns - self._latency_ns, q + self._joint_zero

    @property
    def offset_joints(self) -> tuple[int, ...]:
        """The joints whose zero offsets are states (:func:`.error_model.joint_offset_joints`)."""
        return tuple(self._offset_joints)

    def joint_offsets_rad(self) -> FloatArray:
        """The current zero offset of every joint (n,) [rad] against its encoder reading: the
        coarse start's encoder zeros plus the states' estimates where they are states."""
        out = np.array(self._joint_zero, float)
        if self._offset_joints and self.layout.n_joint_offsets:
            out[list(self._offset_joints)] += self._joint_offsets[:len(self._offset_joints)]
        return out

    def _tilt_rotvec(self) -> FloatArray:
        """The tilt states' estimate as an ENU rotation vector (3,) (the ``joint_offset``
        states after the joints' own): zero without them."""
        if not len(self._tilt_axes) or not self.layout.n_joint_offsets:
            return np.zeros(3)
        return self._joint_offsets[len(self._offset_joints):] @ self._tilt_axes

    def base_tilt_rad(self) -> FloatArray:
        """The table base's tilt from level ``(t_e, t_n)`` [rad]: the coarse start's plus
        the tilt states' estimate where they are states."""
        t = np.zeros(2) if self.start is None else np.array(self.start.base_tilt_rad, float)
        return t + self._tilt_rotvec()[:2]

    def _offset_names(self) -> dict[str, Any]:
        """The joints of the ``joint_offset_rad`` extra (a general chain), by name."""
        t = self.base_tilt_rad()
        tilt = {} if self.start is None or not np.any(t) else {
            'base_tilt_rad': [float(v) for v in t]}
        if not self._offset_joints and not len(self._tilt_axes):
            return tilt
        return {'joint_offset_joints': [self.fixture.joint_names[j]
                                        for j in self._offset_joints]
                + [f'base tilt about {"east" if a[0] else "north"}' for a in self._tilt_axes],
                **tilt}

    def _settings_changed(self) -> dict[str, Any]:
        """The estimator settings that differ from the shipped defaults (the report's header:
        with what the file was made)."""
        default = EstimatorConfig()
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self.config):
            v = getattr(self.config, f.name)
            if v != getattr(default, f.name):
                out[f.name] = v if isinstance(v, (bool, int, float, str)) else str(v)
        return out

    @property
    def stamps_error(self) -> str:
        """The input guard's latched refusal of IMU stamps whose scatter makes most of the
        stream gaps (:attr:`~..input_guard.InputGuard.stamps_error`), or ''."""
        return self._guard.stamps_error or ''

    @property
    def units_error(self) -> str:
        """The input guard's latched refusal of IMU values in the wrong units (g for m/s^2,
        deg/s for rad/s: :attr:`~..input_guard.InputGuard.units_error`), or ''."""
        return self._guard.units_error or ''

    def stamp_hint(self) -> str:
        """A clause naming IMU or joint stamps that scatter about their rate too much to be
        put back on the sender's clock (:func:`~..stamp_clock.scatter_hint`), or ''."""
        g = self._guard
        return scatter_hint({'IMU': g.imu_clock, 'joint': g.joint_clock})

    @property
    def encoder_noise_at_rest_rad(self) -> float:
        """The joint encoders' noise in the (last) alignment window [rad], 0 before one."""
        return self._encoder_scatter_rad

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
        out['status'], out['message'] = status(self._diverged, g, self.guard_config,
                                               self.counters['joint_samples'],
                                               self._joint_names, now_ns)
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

    # ------------------------------------------------------------------ the step loop
    def _push_imu_arrays(self, t: NDArray[np.int64], w: FloatArray, f: FloatArray,
                         frame_id: str) -> None:
        """Push: input guard, then hold (bootstrap) or accept."""
        self.counters['imu_samples'] += len(t)
        verdict = self._guard.check_imu(t, w, f, frame_id, diverged=self._diverged is not None)
        self._sync_input_counters()
        keep = verdict.keep
        if frame_id and not self.frame_id and keep.any():
            self.frame_id = frame_id  # the calibration belongs to the frame of its data
        if not keep.any():
            return
        t, w, f = t[keep], w[keep], f[keep]
        if verdict.stamps_ns is not None:  # stamps taken on receipt: the IMU's own clock
            t = verdict.stamps_ns
        if self._boot is not None:
            self._boot.hold_imu(t, w, f, verdict.gaps, verdict.long_gaps)
            for final, t_cut_ns in self._boot.checks_due():
                if self._finish_bootstrap(final, t_cut_ns):
                    break
            return
        self._accept_imu(t, w, f, verdict.gaps, verdict.long_gaps)

    def _accept_imu(self, t: NDArray[np.int64], w: FloatArray, f: FloatArray, gap_idx: Any,
                    long_gap_idx: Any) -> None:
        """Samples the guard kept: to interval means, split at gaps, processed by blocks."""
        # A long gap applies gap_policy; a short gap (> gap_periods nominal periods) during
        # which the table turned is bridged with the encoders (or re-initialises the
        # navigation; calibration states are kept either way).
        gaps = {int(i) for i in long_gap_idx}
        gaps.update(int(i) for i in gap_idx)
        long_gaps = {int(i) for i in long_gap_idx}
        if self.config.imu_sample_type == 'point':  # CONTRACT 1: point samples as means
            raw_last = (int(t[-1]), w[-1].copy(), f[-1].copy())
            w_raw, f_raw = w, f
            w, f = point_to_mean(w, f, self._point_prev)
            self._point_prev = raw_last
            if gaps:  # the sample after a gap has no neighbour to average with: itself
                gi = np.fromiter(sorted(gaps), np.intp)
                w[gi], f[gi] = w_raw[gi], f_raw[gi]
        bounds = sorted({0, *gaps, len(t)})
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            t_before = self._imu.last_stamp_ns
            if a in gaps and t_before is not None:
                t_after = int(t[a])
                if a not in long_gaps and self._fill_gap(t_before, t_after, w[a], f[a]):
                    pass
                elif a in long_gaps or self.guard_config.bridge_motion \
                        or not self._joints.still_between(t_before, t_after,
                                                          self.still_tolerance_rad):
                    # with bridge_motion every short gap is bridged (at rest the encoders
                    # show no turn): whether the joints moved is not known live until their
                    # states after the gap come, and a batch must do what the stream does
                    self._on_gap(t_before, t_after, a in long_gaps, w[a], f[a])
            # one block at a time, so that divergence is checked after every block
            i = a
            while i < b and self._diverged is None:
                step = self.config.block_chunks * self._n if self._running else 1000
                j = min(i + step, b)  # never past the next gap
                self._imu.append(t[i:j], w[i:j], f[i:j])
                self._advance()
                i = j
            if self._diverged is not None and i < len(t):
                self._guard.rejected['filter_diverged'] += len(t) - i
                return

    def _advance(self) -> None:
        """Align if needed (restoring kept calibration covariance), process, check health."""
        if not self._running:
            if not self._try_initialise():
                return
            self._restore_calibration_covariance()
            if self._level_M is not None and self._filter is not None:
                # the tilt the levelling left carries the accelerometer errors (P0 or the
                # kept calibration block): alignment.level_coupling
                M = self._level_M
                self._filter.P = M @ self._filter.P @ M.T
                if self._filter.sens is not None:  # the same linear map
                    self._filter.sens = M @ self._filter.sens
                self._level_M = None
        chunks = self.counters['chunks']
        self._process()
        if self.counters['chunks'] != chunks:
            self._check_divergence()

    def _process(self, final: bool = False, end: bool = False) -> None:
        """Run the buffered samples through the filter, whole blocks only (``final``: also a
        last partial block, and without waiting for joint states; ``end``: the end of the
        data, no more joint states will come)."""
        if not self._running:
            if not self._try_initialise():
                return
        if self._pending_bridge is not None:
            try:
                if not self._bridge_motion(final, end):
                    return
            except sm.ImplausibleErrors as exc:
                self._declare_divergence(f'implausible sensor errors at the working point '
                                         f'({exc})')
                return
        t, w, f = self._imu.take()
        n = self._n
        h = self._half_span  # look-ahead for the rate differences (propagation)
        need = n + h
        if len(t) < need:
            return
        n_chunks = (len(t) - h) // n
        if (self.attitude_aiding or not self.fixture.concurrent) and not final \
                and len(self._joints):
            # wait for joint states beyond a chunk end (unless they stopped coming)
            t_j = self._joints.t_ns[-1]
            wait_ns = int(self.config.max_pending_s * 1e9)
            if t[-1] - t_j < wait_ns:
                ends = t[n - 1:n * n_chunks:n]
                # a chain's still-joint clamp looks CHAIN_STILL_HALF_WINDOW_S ahead
                lead = 0 if self.fixture.concurrent else int(CHAIN_STILL_HALF_WINDOW_S * 1e9)
                n_chunks = int(np.searchsorted(ends, t_j - lead, side='right'))
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
            try:
                self._run_block(t[k0:k1 + h], w[k0:k1 + h], f[k0:k1 + h], b)
            except sm.ImplausibleErrors as exc:
                # the working point left what a sensor can be (a poor start, a wrong input):
                # a divergence of the filter, not a crash of the run
                if done:
                    self._imu.keep_from(done * n)
                    self._joints.trim(self._t_last_ns)
                self._declare_divergence(f'implausible sensor errors at the working point '
                                         f'({exc})')
                return
            done += b
            if self._cascade:
                self._realign()
                break
        if done:
            self._imu.keep_from(done * n)
            self._joints.trim(self._t_last_ns)

    def _run_block(self, t: NDArray[np.int64], w: FloatArray, f: FloatArray, B: int) -> None:
        """Process ``B`` chunks: ``t, w, f`` hold ``B n`` samples plus one look-ahead."""
        q1_s = self._process_noise.q1_s
        assert self._nav is not None and self._filter is not None and q1_s is not None
        cfg = self.config
        lay = self.layout
        m = B * self._n
        om = self.fixture.site.omega_ie_enu
        blk = self._propagate(t, w, f, B, self._n)
        self.counters['gaps'] += blk.n_gaps
        # zero velocity with the lever arm, and the encoder attitude, at each chunk end
        chain = None if self.fixture.concurrent else self._chain_motion(t[blk.ends])
        w_end = blk.omega_ib_end_rad_s
        if chain is None and self.attitude_aiding and len(self._joints):
            w_end = self._encoder_rate_imu(t[blk.ends], blk.R_enu_imu_end, w_end)
        z_v, H_v = to_filter_units(*zero_velocity(
            blk.v_enu_end_m_s, blk.R_enu_imu_end, w_end, om, self._rho, lay,
            None if chain is None else chain[3], None if chain is None else chain[6]),
            lay.scale)
        R_v = noise_covariance(cfg.velocity_sigma_m_s)
        z_a, H_a, have_att = self._encoder_attitude(t[blk.ends], blk.R_enu_imu_end)
        # the encoders' own noise where it is above the setting (under a consumer unit with
        # 0.2 mrad of encoder noise the fixed 0.1 mrad gated 13 of 3592 updates: refused)
        R_a = noise_covariance(max(cfg.attitude_sigma_rad, self._encoder_scatter_rad))
        R_ab = self._latency_attitude_covariance(blk, R_a) if have_att.any() else None
        if chain is not None:  # a general chain: its errors bound in the noise (issue 15)
            R_vb = R_v[None] + chain[4] / MEAS_SCALE ** 2
            R_ab = (R_a[None] if R_ab is None else R_ab) + chain[5] / MEAS_SCALE ** 2
            if self._consider is not None:
                cov, q_c, R_end = chain[0], chain[1], blk.R_enu_imu_end
                self._consider.add_velocity(q_c[cov], chain[2][cov], R_end[cov])
                if 'mounting' in lay.slices and not lay.n_joint_offsets:
                    att = cov & have_att
                    self._consider.add_attitude(q_c[att], R_end[att])
        filt = self._filter
        q1_diag_s = np.diag(q1_s)
        t_ends = t[blk.ends]
        for b in range(B):
            filt.predict_rows(blk.rows_s[b], blk.chunk_noise_s(q1_diag_s, b))
            while self._gap_widening and self._gap_widening[0][1] <= t_ends[b]:
                _, _, var_att, var_vel = self._gap_widening.pop(0)
                widen_navigation(filt.P, lay, var_att, var_vel)
            if self._gap_widening and self._gap_widening[0][0] <= t_ends[b]:
                self.counters['updates_skipped_in_gaps'] += 1  # inside a filled gap
                continue
            if chain is not None:
                assert R_ab is not None  # set with the chain's share above
                R_v, R_a = R_vb[b], R_ab[b]
                if not chain[0][b]:  # no joint states around this instant: no chain velocity
                    self.counters['velocity_updates_without_joints'] = \
                        self.counters.get('velocity_updates_without_joints', 0) + 1
                    if have_att[b]:
                        filt.update('attitude', z_a[b], H_a[b], R_a)  # type: ignore[index]
                    continue
            if filt.update('velocity', z_v[b], H_v[b], R_v):
                self._gated_run = 0
            else:
                self._gated_run += 1
                self._cascade = self._gated_run >= cfg.cascade_updates
            if have_att[b]:
                filt.update('attitude', z_a[b], H_a[b],  # type: ignore[index]
                            R_a if R_ab is None else R_ab[b])
        if blk.n_gaps:  # motion during a gap is lost: widen the navigation uncertainty
            widen_for_gaps(filt.P, lay, blk.n_gaps)
        self._feedback()
        h = self._half_span
        self._prev = (t[m - h:m].copy(), w[m - h:m].copy(), f[m - h:m].copy())
        self._t_last_ns = int(t[m - 1])
        self.counters['imu_processed'] += m
        self.counters['chunks'] += B
        self._record_history()

    def _latency_attitude_covariance(self, blk: Block, R_a: FloatArray) -> FloatArray | None:
        """``R`` of each chunk end's encoder attitude with the share of the joint-stamp
        latency's uncertainty: a stamp off by ``dt`` reads the fixture ``omega dt`` away
        (``omega`` its rate in ENU, from the navigated attitude and the gyros), so
        ``R + sigma_s^2 omega omega^T`` with ``sigma_s`` the coarse start's sigma of the latency
        it applied (filter units). None when that sigma is zero or unknown. With 10 Hz joint
        states and bursts of both streams lost the coarse start measured -7.7 +- 5.5 ms
        (truth 0): at 0.2 rad/s a 1.5 mrad attitude error against a 0.1 mrad noise, every
        velocity update gated from then on, and a diverged run; with the true latency it
        passed (bench_corners ``cmems_j10_drops_im@srt2``). A bound, not a model: the error
        of a constant latency has one sign through a turn, and each update takes it as
        independent (a latency state would model it). With it, in quadrature, the error the
        joint clock leaves in stamps taken on receipt
        (:attr:`~..stamp_clock.StampClock.timing_sigma_ns`: 0.1-0.3 ms for a minute after it
        decided on 40 s of 14 Hz joint states with 36 ms of delays; the tactical grid run
        ``tactical-s0.2-large-slow_joints-random@three_axis-0`` gated 118 updates there and
        failed its self-check)."""
        st = self.start
        sd = 0.0 if st is None else float(st.joint_latency_sigma_s)
        sd = math.hypot(sd if math.isfinite(sd) else 0.0,  # (a group's mean stamp: sqrt k less)
                        1e-9 * self._guard.joint_clock.timing_sigma_ns
                        / math.sqrt(self._joints.group))
        if not sd > 0.0:
            return None
        w_enu = np.einsum('bij,bj->bi', blk.R_enu_imu_end, blk.omega_ib_end_rad_s)
        w_enu = w_enu - self.fixture.site.omega_ie_enu  # the fixture's own rate
        return R_a[None] + (sd / MEAS_SCALE) ** 2 * w_enu[:, :, None] * w_enu[:, None, :]

    def _propagate(self, t: NDArray[np.int64], w: FloatArray, f: FloatArray, B: int,
                   n: int, ahead_repeated: bool = False) -> Block:
        """:func:`.propagation.propagate_block` of ``B`` chunks of ``n`` samples (plus the
        look-ahead) from the navigator's state with the current estimate."""
        assert self._nav is not None
        tau = self._theta_a[em.accel_cols('time_offset')][0]
        # the sampling kernels, estimated or assumed (the declared type's: priors.prior_point)
        kernel = (float(self._theta_g[em.gyro_cols('gyro_sample_kernel')][0]),
                  float(self._theta_a[em.accel_cols('accel_sample_kernel')][0]))
        return propagate_block(self._nav, self._errors, tau, self._prev, t, w, f,
                               self._nominal_dt, B, n, self.layout,
                               self.fixture.site.omega_ie_enu, self.fixture.concurrent,
                               self._process_noise.white[1] / math.sqrt(self._nominal_dt),
                               ahead_repeated, self.config.imu_sample_type == 'point',
                               self._rho, kernel)

    def _record_history(self, force: bool = False) -> None:
        """Offer the current values and sigmas (SI) to :attr:`history` (decimated there)."""
        filt = self._filter
        if filt is None or self._t_last_ns is None:
            return
        lay = self.layout
        sd = np.sqrt(np.clip(np.diag(filt.P)[6:], 0.0, None)) * lay.scale[6:]
        self.history.record(self._t_last_ns, lay.state_labels, self._state_values(), sd,
                            filt.counters, force)

    def _encoder_rate_imu(self, t_ns: NDArray[np.int64], R_enu_imu: FloatArray,
                          w_gyro: FloatArray) -> FloatArray:
        """The inertial rate at the chunk ends for the lever arm's velocity on a turntable:
        the gyros' and the encoders' (earth rate + ``sum_j u_j qd_j`` in ENU, into the IMU
        frame by the navigated attitude), weighted by their noise (:meth:`_rate_weight`).

        The gyros' rate there is the mean of the two samples either side of the instant; the
        same two samples' noise is the boundary term of the size effect's ``omega_dot``
        regressor over the chunk. Times the lever arm, that shared noise biased the size
        effect: with a MEMS gyro (1.8e-3 rad/s for the two samples at 100 Hz) and a 34 mm lever
        arm, by ~2 mm (2 sigma; 36 sigma with 10x less accelerometer noise, as the bias stays).
        The encoders' rate shares no noise with the IMU, but a spline's derivative through
        20 urad of encoder noise has ~2e-3 rad/s: more than a tactical gyro's (the encoders'
        alone left a tactical unit's size effect 4.6 sigma off)."""
        self._rate_calls += 1
        if self._rate_calls % RATE_WEIGHT_EVERY == 1 or self._rate_a is None:
            self._rate_a = self._rate_weight()  # the encoders' noise changes slowly
        a = self._rate_a
        if not a:  # the gyros alone: no encoder rates to evaluate
            return w_gyro
        covered, q_e, qd_e = self._joints.motion_at(
            t_ns, self.still_tolerance_rad, CHAIN_STILL_HALF_WINDOW_S)
        if q_e is None or qd_e is None:
            return w_gyro
        axes = self.fixture.angular_axes_enu(self._with_offsets(q_e))  # (B, n, 3)
        w_enu = np.einsum('bjk,bj->bk', axes, qd_e) + self.fixture.site.omega_ie_enu
        w_enc = np.einsum('bji,bj->bi', R_enu_imu, w_enu)  # R^T w_enu
        return np.where(covered[:, None], a * w_enc + (1.0 - a) * w_gyro, w_gyro)

    def _rate_weight(self) -> float | None:
        """The encoders' weight in :meth:`_encoder_rate_imu`, ``s_g^2 / (s_g^2 + s_e^2)``
        per IMU axis: ``s_g^2 = N^2 / (2 dt)``, the gyros' two-sample mean (white-noise
        density ``N``); ``s_e^2 = sum_j (1.57 s_j / dt_j)^2 / 3``, the spline's rate through
        each joint's encoder noise ``s_j`` (:func:`.buffers.encoder_noise_rad` of its latest
        samples: motion and quantization included, a move's own acceleration negligible at
        the joint rate) over the joints' median sample spacing ``dt_j``. None (the gyros alone,
        and asked again at the next block) without enough joint samples."""
        jb = self._joints
        if len(jb) < ENCODER_NOISE_MIN or self._nominal_dt <= 0:
            return None
        jt = np.array(jb.t_ns[-ENCODER_NOISE_SAMPLES:], np.int64)
        jq = np.array(jb.q_rad[-ENCODER_NOISE_SAMPLES:], float)
        dt_j = float(np.median(np.diff(jt))) * 1e-9
        s_j = encoder_noise_rad(jq)
        s_e2 = float(np.sum((SPLINE_RATE_NOISE * s_j / max(dt_j, 1e-6)) ** 2)) / 3.0
        s_g2 = self._process_noise.white[0] ** 2 / (2.0 * self._nominal_dt)
        if s_g2 <= 0.0:
            return 0.0
        return s_g2 / (s_g2 + s_e2)

    def _chain_motion(self, t_ns: NDArray[np.int64]) -> tuple[
            NDArray[np.bool_], FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
            FloatArray]:
        """A general chain (issue 15) at the chunk ends ``t_ns``: (covered, q (with the
        estimated zero offsets), qd, anchor velocity (B, 3), its covariance (B, 3, 3) and the
        encoder attitude's (B, 3, 3) from the arm's errors and the encoder noise,
        :func:`.measurements.chain_velocity_covariance`, and the anchor velocity's derivative
        by the zero-offset states (B, 3, k)). With the offsets as states their share is not
        in the covariances (the link errors' and the encoder noise's are)."""
        cfg = self.config
        B = len(t_ns)
        n = self.fixture.n_joints
        k = self.layout.n_joint_offsets
        zeros = np.zeros((B, 3))
        if not len(self._joints):
            return (np.zeros(B, bool), np.zeros((B, n)), np.zeros((B, n)), zeros,
                    np.zeros((B, 3, 3)), np.zeros((B, 3, 3)), np.zeros((B, 3, k)))
        covered, q, qd = self._joints.motion_at(t_ns, self.still_tolerance_rad,
                                                CHAIN_STILL_HALF_WINDOW_S)
        if q is None or qd is None:
            return (covered, np.zeros((B, n)), np.zeros((B, n)), zeros, np.zeros((B, 3, 3)),
                    np.zeros((B, 3, 3)), np.zeros((B, 3, k)))
        q = self._with_offsets(q)
        if self._chain_fixtures is None:
            self._chain_fixtures = link_error_chains(self.fixture)
        jt = self._joints.t_ns
        dt_j = (jt[-1] - jt[0]) * 1e-9 / max(len(jt) - 1, 1) if len(jt) > 1 else 0.01
        qd_sigma = 1.5 * cfg.chain_encoder_sigma_rad / max(dt_j, 1e-4)
        v_anchor = self.fixture.anchor_velocity_enu_m_s(q, qd)
        sigma_q = 0.0 if k else cfg.chain_joint_offset_sigma_rad  # states: not noise
        C_v = chain_velocity_covariance(self._chain_fixtures, q, qd, sigma_q,
                                        cfg.chain_link_sigma_m, qd_sigma,
                                        cfg.chain_error_correlation)
        C_a = chain_attitude_covariance(self.fixture, q, sigma_q, cfg.chain_error_correlation)
        D = (self.fixture.anchor_velocity_jacobian_q(q, qd)[:, :, list(self._offset_joints)]
             if k else np.zeros((B, 3, 0)))
        return covered, q, qd, v_anchor, C_v, C_a, D

    def _with_offsets(self, q: FloatArray) -> FloatArray:
        """Encoder angles ``q`` (..., n) plus the estimated joint zero offsets: where the
        chain's kinematics are evaluated (the joint is at ``q + o``, :mod:`.measurements`)."""
        if not self._offset_joints or not self.layout.n_joint_offsets:
            return q
        q = np.array(q, dtype=float)
        q[..., list(self._offset_joints)] += self._joint_offsets[:len(self._offset_joints)]
        return q

    def _tilted(self, R_enu_imu: FloatArray) -> FloatArray:
        """``R_enu_imu`` (..., 3, 3) of the fixture on its base turned further by the tilt
        states' estimate (none: unchanged)."""
        v = self._tilt_rotvec()
        return rotvec_to_matrix(v) @ R_enu_imu if np.any(v) else R_enu_imu

    def _encoder_attitude(self, t_ns: NDArray[np.int64], R_enu_imu: FloatArray
                          ) -> tuple[FloatArray | None, FloatArray | None, NDArray[np.bool_]]:
        """Encoder attitude measurements at the chunk ends ``t_ns`` (filter units), and which
        chunk ends have one (joint states around them); none without encoder aiding."""
        have = np.zeros(len(t_ns), bool)
        if not (self.attitude_aiding and len(self._joints)):
            return None, None, have
        have, q_end = self._joints.positions_at(t_ns)
        self.counters['attitude_updates_without_joints'] += int((~have).sum())
        if q_end is None:
            return None, None, have
        lay = self.layout
        q_end = self._with_offsets(q_end)
        axes = None
        if lay.n_joint_offsets:
            axes = np.concatenate([
                self.fixture.angular_axes_enu(q_end)[:, list(self._offset_joints)],
                np.broadcast_to(self._tilt_axes, (len(q_end),) + self._tilt_axes.shape)],
                axis=1)
        z, H = to_filter_units(*encoder_attitude(R_enu_imu,
                                                 self._tilted(self.fixture.R_enu_imu(q_end)),
                                                 self._mount, lay, axes), lay.scale)
        return z, H, have

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
        if lay.n_joint_offsets:
            self._joint_offsets = self._joint_offsets - x[lay.slices[em.CHAIN_GROUP]]
        self._filter.x = np.zeros(lay.n)
        self._errors = self._make_errors()

    # ------------------------------------------------------------------ the start
    def _configure(self) -> None:
        """Priors, encoder aiding and the state layout from the config, grade and start."""
        cfg = self.config
        st = self.start
        # the table's base as it stands (not levelled: coarse.fit_joint_zeros), for every use
        # of the fixture from here on (encoder attitude, windows, bridges, self-check)
        self.fixture = self._nominal_fixture if st is None \
            else self._nominal_fixture.with_base_tilt(st.base_tilt_rad)
        aiding = cfg.attitude_aiding or (
            st is not None and cfg.aiding_gyro_noise_rad_s_rt_hz > 0
            and st.gyro_noise_rad_s_rt_hz > cfg.aiding_gyro_noise_rad_s_rt_hz)
        self.attitude_aiding = bool(aiding)
        self._prior = prior_sigmas(self.grade, cfg, st, self.fixture.concurrent)
        groups = cfg.estimated_groups
        if self.attitude_aiding and 'mounting' not in groups:
            groups = groups + ('mounting',)
        self.dropped_groups = tuple(g for g in groups if not np.all(self._prior[g] > 0.0))
        # a general chain's joint zero offsets (issue 15): states with their prior sigma
        self._offset_joints = (em.joint_offset_joints(self.fixture, self.attitude_aiding)
                               if cfg.estimate_joint_offset
                               and cfg.chain_joint_offset_sigma_rad > 0 else ())
        # the base tilt's residual about east and north after the coarse start, as states
        # after the joint offsets (a turntable with encoder aiding, the one measurement a
        # tilt enters): a left rotation about a fixed ENU axis, as a joint offset is one about
        # its axis. The coarse fit's model is the windows' (no size effect, no G): a consumer
        # MEMS unit's tilt came out 0.13 mrad (6 of its sigmas) off, accel_bias 5.2 sigma off
        tilt_sd = (np.full(2, np.inf) if st is None
                   else np.asarray(st.base_tilt_sigma_rad, float))
        tilt_on = [c for c in range(2) if math.isfinite(tilt_sd[c])] \
            if self.attitude_aiding and self.fixture.concurrent \
            and cfg.estimate_joint_offset else []
        self._tilt_axes = np.eye(3)[tilt_on]
        self._prior[em.CHAIN_GROUP] = np.concatenate([
            np.full(len(self._offset_joints), cfg.chain_joint_offset_sigma_rad),
            np.clip(TILT_PRIOR_SIGMAS * tilt_sd[tilt_on], TILT_PRIOR_FLOOR_RAD,
                    BASE_TILT_PRIOR_RAD)])
        self.layout = em.StateLayout.build(
            tuple(g for g in groups if g not in self.dropped_groups),
            len(self._offset_joints) + len(tilt_on))
        self._prior_shift = None if self._initial is None else prior_shift(
            self._initial, tuple(self.layout.labels()[6:]), self._prior_mean())

    def _reset_filter_side(self) -> None:
        """Start point, compensation, noise, joint latency: what the coarse start sets."""
        self._theta_g, self._theta_a, self._rho, self._mount = self._start_point()
        self._joint_offsets = self._start_offsets()
        self._errors = self._make_errors()
        self._process_noise.white = white_noise_densities(self.start, self.grade,
                                                          self.config.noise_source)
        self._point_prev = None
        self._gap_widening: list[tuple[int, int, FloatArray, FloatArray]] = []
        # a gap in motion waiting for the joint states beyond it (_bridge_motion):
        # (navigator time, time after the bridge, stamp after the gap, its gyro, accel,
        # the last sample before the gap: stamp, gyro, accel)
        self._pending_bridge: tuple[int, int, int, FloatArray, FloatArray,
                                    tuple[int, FloatArray, FloatArray] | None] | None = None
        self._encoder_scatter_rad = 0.0  # joint-angle scatter at rest (the alignment's)
        self._latency_ns = 0 if self.start is None else int(round(
            self.start.joint_latency_s * 1e9))
        # a table's encoder zeros the coarse start measured: the joints are at q + this
        z0 = None if self.start is None else self.start.joint_zero_rad
        self._joint_zero = (np.asarray(z0, float) if z0 is not None and len(z0)
                            else np.zeros(self.fixture.n_joints))
        self._settle_until_ns: int | None = None
        self._unsettled = False  # feedback after every update at the next alignment
        self._gated_run = 0
        self._cascade = False

    def _finish_bootstrap(self, final: bool, t_cut_ns: int | None = None) -> bool:
        """Measure the coarse start from the held data (up to ``t_cut_ns``); when it is
        determined (or at the end of the data), configure the filter around it and replay the
        held input. Returns whether the bootstrap ended."""
        assert self._boot is not None
        self._revise_held_stamps()
        jc = self._guard.joint_clock
        self._boot.joint_timing_sigma_s = 1e-9 * jc.timing_sigma_ns if jc.scattered else 0.0
        ready, st = self._boot.measure(self.fixture, final, t_cut_ns)
        if not ready:
            return False
        why = implausible(st) if st is not None else None
        if why is not None:  # refused before anything changes: every later push refuses too
            raise InputError(why)
        held, self._boot = self._boot.items, None
        if st is not None:
            st = dataclasses.replace(st, stamp_revisions=self._revised)
        self.start = st
        self._configure()
        self._reset_filter_side()
        if st is not None:
            _LOG.info('coarse start: %s', st.summary())
            check_grade_hint(self.grade, st, self.config.noise_source)
        for item in held:
            if item[0] == 'imu':
                self._accept_imu(*item[1:])
            elif len(item[1]):
                self._record_joints(item[1], item[2])
        return True

    def _revise_held_stamps(self) -> None:
        """The held stamps a clock gave out as given while it learnt (stamps taken on
        receipt), on the sender's clock now that it knows it (the coarse start and the
        filter see the same instants as for the rest of the record)."""
        assert self._boot is not None
        g = self._guard
        clocks = (g.imu_clock, g.joint_clock)
        if not any(c.revision_pending for c in clocks):
            return
        change = self._boot.revise_stamps(
            g.imu_clock.revise if g.imu_clock.revision_pending else None,
            g.joint_clock.revise if g.joint_clock.revision_pending else None, g.gap_indices)
        g.flagged['gap'] += change
        self._revised = tuple(c.revisions() if c.revision_pending else r  # type: ignore[assignment]
                              for c, r in zip(clocks, self._revised))
        for c in clocks:
            c.revision_pending = False
        self._sync_input_counters()

    def _try_initialise(self) -> bool:
        """Coarse alignment on the first stationary window (levelling + fixture heading)."""
        t, w, f = self._imu.take()
        if len(t) < 3 or len(self._joints) < 2:
            return False
        cfg = self.config
        jt, jq = self._joints.arrays()
        win_ns = int(cfg.init_window_s * 1e9)
        start_j, stop_j = still_run(jt, jq, win_ns, cfg.stationary_joint_tolerance_rad,
                                    STILL_NOISE_SIGMAS)
        t_start = jt[start_j]
        k0 = int(np.searchsorted(t, t_start))
        if k0 > 0:  # nothing before the still run can be used
            self.counters['imu_dropped_before_alignment'] += k0
            self._imu.keep_from(k0)
            t, w, f = self._imu.take()
        if stop_j is None:  # still waiting: keep only the current still run (bounded memory)
            self._joints.keep_from(start_j)
            return False
        if self._still_tol is None:  # rest as the encoders show it, from here on
            self._still_tol = window_tolerance_rad(jq[start_j:stop_j + 1],
                                                   cfg.stationary_joint_tolerance_rad)
        if len(t) < 3 or t[-1] < t_start + win_ns:
            return False
        k1 = int(np.searchsorted(t, t_start + win_ns, side='right'))
        j1 = min(stop_j + 1, int(np.searchsorted(jt, t_start + win_ns, side='right')))
        q_mean = jq[start_j:j1].mean(axis=0)  # the window only: same for any push pattern
        if j1 - start_j > 8:  # encoder noise (for the motion bridges; a creep within the
            # still tolerance cancels in the second differences)
            self._encoder_scatter_rad = float(np.max(encoder_noise_rad(jq[start_j:j1])))
        try:
            al = align(t[:k1], w[:k1], f[:k1], self._with_offsets(q_mean), self._errors,
                       self._mount, self.fixture, cfg.update_rate_hz)
        except sm.ImplausibleErrors as exc:
            # a re-alignment at sensor errors no unit has (the compensation of the window
            # does not converge): a divergence, as in a block, not a traceback
            self._declare_divergence(f'implausible sensor errors at a re-alignment ({exc})')
            return False
        if al is None:
            return False
        self._nominal_dt = al.nominal_dt_s
        self._n = al.samples_per_chunk
        self._half_span = min(omega_dot_half_span(self._nominal_dt), self._n)
        if cfg.noise_source == 'data' and self.start is None:
            self._process_noise.white = white_noise_from_window(
                al.gyro_rad_s, al.accel_m_s2, al.nominal_dt_s,
                self.config.imu_sample_type == 'point')
        if self._unsettled:  # after a gate cascade or a restart: the start is poor
            self._settle_until_ns = int(t[0]) + int(cfg.settle_s * 1e9)
            self._unsettled = False
        self._nav = Strapdown(self.fixture.site, al.R_enu_imu)
        self._start_filter()
        self._level_M = (level_coupling(self.layout, al.R_enu_imu, self._errors, al.gyro_rad_s,
                                        al.accel_m_s2, al.nominal_dt_s,
                                        self.fixture.site.omega_ie_enu)
                         if cfg.level_coupling else None)
        self._running = True
        self._t0_ns = int(t[0])
        self._prev = None
        return True

    def assumed_noise(self) -> tuple[float, float, float, float]:
        """What the reported covariance assumed (for the self-check): white-noise densities of
        gyros and accelerometers (x ``noise_scale``) and the adapted bias random-walk PSDs."""
        pn = self._process_noise
        k = pn.noise_scale
        return (k * pn.white[0], k * pn.white[1], pn.scale * pn.bias_q[0],
                pn.scale * pn.bias_q[1])

    def bias_walk_summary(self) -> dict[str, Any]:
        """The biases' random walk the reported covariance assumed and where it came from
        (``estimator.bias_walk`` of the calibration file): per group the density (square
        root of the PSD), its source (:func:`.noise.bias_walk_sources` of the first filter,
        or ``raised by the run's data`` where the stationary windows or the innovations made
        it larger since), and for the gyros the Gauss-Markov instability over 100 s that it
        covers (:func:`.noise.instability_covered`): a unit less stable than that, with no
        grade to say so and no plan that shows it, gets optimistic gyro-bias sigmas."""
        _, _, q_g, q_a = self.assumed_noise()
        q0 = self._process_noise.initial
        # the grade and the coarse start are those of the first filter (ProcessNoise.initial)
        src = (['none', 'none'] if q0 is None else list(bias_walk_sources(
            self.grade, self.start, self.config.aiding_gyro_noise_rad_s_rt_hz)))
        q0 = q0 or (0.0, 0.0)
        for i, q in enumerate((q_g, q_a)):
            if q > q0[i] * (1.0 + 1e-9):
                src[i] = "raised by the run's data"
        out: dict[str, Any] = {
            'gyro_bias_random_walk_rad_s2_rt_hz': math.sqrt(q_g),
            'accel_bias_random_walk_m_s3_rt_hz': math.sqrt(q_a),
            'gyro_source': src[0], 'accel_source': src[1],
            'gyro_instability_covered_rad_s': instability_covered(q_g)}
        st = self.start
        if st is not None and st.gyro_walk_profile:
            # the replay's profile (replay.profile_gyro_walk): walk / white noise -> NLL rise
            out['gyro_walk_to_noise_per_s'] = float(st.gyro_walk_to_noise_per_s
                                                    or MEMS_BIAS_WALK[0])
            out['gyro_walk_likelihood_bound_per_s'] = float(st.gyro_walk_bound_per_s)
            # (a pass that diverged or lost updates is infinitely unlikely: left out)
            out['gyro_walk_profile'] = [[float(f), float(d)] for f, d in st.gyro_walk_profile
                                        if math.isfinite(d)]
        return out

    def bias_walk_growth(self) -> tuple[float, float, float, float]:
        """The largest bias walk this run's stationary windows showed against the one it
        started with: ``(q_gyro, q_accel, ratio_gyro, ratio_accel)``
        (:meth:`.noise.ProcessNoise.grown`)."""
        return self._process_noise.grown()

    def innovation_nll(self) -> tuple[float, int]:
        """The whole run's innovations' negative log-likelihood over every filter of the run
        (:class:`~.ekf.GateCounters` ``nll_sum``) and how many updates it sums: the measure
        :func:`.replay.profile_gyro_walk` compares bias walks by."""
        return (float(sum(c.nll_sum for c in self._run_counters)),
                int(sum(c.nll_updates for c in self._run_counters)))

    def nis_totals(self) -> dict[str, tuple[int, int, float]]:
        """Whole-run gate counts per measurement kind over every filter of the run:
        ``{kind: (accepted, rejected, sum of the accepted updates' NIS)}``."""
        out: dict[str, list[Any]] = {}
        for c in self._run_counters:
            for k in set(c.accepted) | set(c.rejected):
                t = out.setdefault(k, [0, 0, 0.0])
                t[0] += int(c.accepted.get(k, 0))
                t[1] += int(c.rejected.get(k, 0))
                t[2] += float(c.nis_sum.get(k, 0.0))
        return {k: (int(v[0]), int(v[1]), float(v[2])) for k, v in sorted(out.items())}

    def raise_bias_walk(self, q_gyro: float, q_accel: float) -> bool:
        """The biases' random walk the run's data show (PSDs, (rad/s)^2/s and (m/s^2)^2/s;
        :meth:`~.run_ledger.RunLedger.bias_walk`): used from now on where it exceeds the
        assumed one by 1.5x (item 5: no grade declares it). Returns whether Q changed."""
        changed = self._process_noise.raise_walk((q_gyro, q_accel))
        if changed:
            self.counters['bias_walk_raised'] += 1
            _LOG.info('bias random walk raised to the stationary windows\' drift: gyro %.3g '
                      'deg/h/sqrt(h), accel %.3g ug/sqrt(s)',
                      math.degrees(math.sqrt(q_gyro)) * 3600 * 60,
                      math.sqrt(q_accel) / 9.80665e-6)
        return changed

    def covariance_scale(self) -> float:
        """Factor on the reported covariance: the largest whole-run NIS per degree of freedom
        of the measurement kinds, at least 1 (the Birge ratio).

        When the innovations are larger than the filter predicts, its noise model is too
        optimistic somewhere; if every noise were off by the same factor ``c`` the gains would
        be unchanged and the true covariance ``c P``, with NIS ``c`` per dof. So the reported
        sigmas are scaled by ``sqrt(c)`` rather than trusted, and the self-check refuses only
        a ratio too large for this to be a noise level (``SelfCheckConfig.max_nis_ratio``).
        Kinds with fewer than :data:`MIN_NIS_UPDATES` accepted updates are not used."""
        c = 1.0
        for acc, _, total in self.nis_totals().values():
            if acc >= MIN_NIS_UPDATES:
                c = max(c, total / (MEASUREMENT_DOF * acc))
        return c if math.isfinite(c) else 1.0

    def _start_filter(self) -> None:
        """A new filter: P0 from the prior, Q from the noise and the biases' random walk."""
        cfg = self.config
        self._filter = ErrorStateFilter(self.layout,
                                        initial_covariance(self.layout, self._prior, cfg),
                                        cfg.gate_probability, cfg.gate_action == 'deweight')
        if self._prior_shift is not None:  # the calibration part comes back at a re-alignment
            self._filter.sens = np.concatenate([np.zeros(6), self._shift_scaled()])
        self._process_noise.start(self.layout, bias_random_walk(
            self.grade, self.start, cfg.aiding_gyro_noise_rad_s_rt_hz))
        if not self._run_counters:
            self.first_filter_dropped = int(self.counters.get('imu_dropped_before_alignment', 0))
        self._run_counters.append(self._filter.counters)

    def _restore_calibration_covariance(self) -> None:
        """After a re-initialisation: the calibration block of P is the one before the gap."""
        if self._kept_cal_P is not None and self._filter is not None:
            self._filter.P[6:, 6:] = self._kept_cal_P
            self._kept_cal_P = None
        if self._kept_sens is not None and self._filter is not None \
                and self._filter.sens is not None:
            self._filter.sens[6:] = self._kept_sens
            self._kept_sens = None

    # ------------------------------------------------------------------ health and faults
    def _check_divergence(self) -> None:
        """Windowed NIS, positive definiteness, physical ranges; snapshot when healthy."""
        if self._filter is None or self._diverged is not None:
            return
        cfg = self.guard_config
        filt = self._filter
        lay = self.layout
        vals = self._state_values()
        v = self._nav.v_enu_m_s if self._nav is not None else np.zeros(3)
        reason = numerical_fault(filt.P, filt.x, vals, v, cfg.max_velocity_m_s)
        if reason is None:  # from the prior mean (the coarse start)
            reason = state_out_of_range(vals, self._prior_mean_cached(),
                                        prior_vector(self._prior, lay.groups),
                                        lay, cfg.state_range_sigmas)
        if reason is None:
            self._nis.push(filt.counters)
            reason = self._nis.reason(cfg.max_rejected_fraction, cfg.max_mean_nis_per_dof)
        if reason is not None:
            self._declare_divergence(reason)
        else:
            self._good.append(self.estimate_state())
            self._good_sens.append(None if filt.sens is None else filt.sens[6:].copy())
            self._adapt_bias_noise()

    def _adapt_bias_noise(self) -> None:
        """Item 5: double the biases' random walk when the innovations over the NIS window
        say they drift more than Q allows (:meth:`.noise.ProcessNoise.adapt`)."""
        if self._filter is None:
            return
        if self._process_noise.adapt(self._nis.span(), self.guard_config.nis_window):
            self.counters['bias_noise_adaptations'] += 1
            self._nis.clear()  # judge the new Q on fresh updates

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

    def _declare_divergence(self, reason: str) -> None:
        """Restart (up to ``max_restarts``); then latch ERROR, roll the estimate back to the
        last good snapshot and stop the filter."""
        if self.restarts < self.config.max_restarts:
            self._restart(reason)
            return
        self._diverged = reason
        self.counters['divergences'] += 1
        st = self._good[0] if self._good else None
        sens = self._good_sens[0] if self._good_sens else None
        self._last_good_state = st
        lay = self.layout
        if st is not None:
            self._theta_g, self._theta_a = st.theta_gyro.copy(), st.theta_accel.copy()
            self._rho, self._mount = st.lever_arm_imu_m.copy(), st.mounting_rotvec_rad.copy()
            working = st.values
            if self._prior_shift is not None and st.values.size:
                # the snapshot holds reported (prior-corrected) values; the navigator's working
                # point is the uncorrected one that estimate_state() corrects again (the joint
                # offsets too: taken from the reported values, they were corrected twice)
                working = st.values + self._prior_correction(sens)
                self._theta_g, self._theta_a, self._rho, self._mount = with_values(
                    lay, working, self._theta_g, self._theta_a, self._rho, self._mount)
            self._joint_offsets = self._offsets_of(working)
        else:  # nothing good yet: back to the starting point
            self._theta_g, self._theta_a, self._rho, self._mount = self._start_point()
            self._joint_offsets = self._start_offsets()
        self._errors = self._make_errors()
        if self._filter is not None:
            self._filter.P = rollback_covariance(lay, None if st is None else st.covariance,
                                                 prior_vector(self._prior, lay.groups))
            self._filter.x = np.zeros(lay.n)
            if self._filter.sens is not None:  # as it was at the snapshot (else: the start's)
                self._filter.sens = np.concatenate([
                    np.zeros(6), self._shift_scaled() if sens is None else sens])
        else:
            # declared while re-aligning (no filter): the next filter takes the snapshot's
            # covariance and sensitivity, as the working point above is the snapshot's
            self._kept_cal_P = rollback_covariance(
                lay, None if st is None else st.covariance,
                prior_vector(self._prior, lay.groups))[6:, 6:]
            self._kept_sens = None if sens is None else sens.copy()
        self._imu.drop_all()
        _LOG.error('calibration filter diverged (%s): estimate rolled back to the last good '
                   'block', reason)

    def _restart(self, reason: str) -> None:
        """A diverged filter restarts from the coarse start with its prior covariance
        inflated (x2 per restart) and re-aligns at the next stationary window (issue 11)."""
        self.restarts += 1
        self.counters['restarts'] = self.restarts
        self._unsettled = True
        _LOG.warning('calibration filter diverged (%s): restart %d of %d from the start point '
                     'with inflated covariance', reason, self.restarts, self.config.max_restarts)
        self._theta_g, self._theta_a, self._rho, self._mount = self._start_point()
        self._joint_offsets = self._start_offsets()
        self._errors = self._make_errors()
        self._drop_navigation()
        lay = self.layout
        self._kept_cal_P = restart_covariance(prior_vector(self._prior, lay.groups), lay,
                                              self.restarts)
        self._kept_sens = None  # from the start point again: the shift's whole sensitivity
        self._good.clear()
        self._good_sens.clear()
        self._gated_run = 0
        self._cascade = False

    def _fill_gap(self, t_before_ns: int, t_after_ns: int, w_after: FloatArray,
                  f_after: FloatArray) -> bool:
        """A short gap (at most ``guard_config.interpolate_gap_s``) while the filter runs: a
        driver dropped a few samples. Fill the lost nominal periods with samples interpolated
        linearly between the last sample before the gap and the one after it (CONTRACT 1: the
        latter is the mean over its own nominal period), and widen the navigation covariance
        by what the interpolation can miss (:func:`.health.interpolated_gap_variance`), so
        that the turn lost in the gap costs a little attitude accuracy instead of the
        navigation (re-initialised, the rest of the turn was lost until the next stationary
        window: with 2 % of a MEMS unit's samples dropped in bursts, the size effect came out
        9 sigma off). Off by default (``interpolate_gap_s`` 0): on a navigation-grade unit
        with 1.7 % of its samples dropped, the fills' errors, each within the widening, still
        set off the bias-noise adaptation twice and left an accelerometer bias 4.6 sigma off
        (true samples in the same fills: clean). Returns whether it filled the gap."""
        cfg = self.guard_config
        last = self._imu.last_sample
        period_ns = int(round(self._nominal_dt * 1e9))
        gap_ns = t_after_ns - t_before_ns
        if (not self._running or self._filter is None or last is None or period_ns <= 0
                or gap_ns > cfg.interpolate_gap_s * 1e9):
            return False
        k = int(round(gap_ns / period_ns)) - 1  # lost periods before the one after the gap
        if k < 1:
            return False
        t_fill = t_after_ns - period_ns * np.arange(k, 0, -1, dtype=np.int64)
        t_fill = t_fill[t_fill > t_before_ns]
        if not len(t_fill):
            return False
        w0, f0 = last
        a = ((t_fill - t_before_ns) / gap_ns)[:, None]
        self._imu.append(t_fill, w0 + a * (w_after - w0), f0 + a * (f_after - f0))
        n_g, n_a, _, _ = self.assumed_noise()
        var_att, var_vel = interpolated_gap_variance(w0, f0, w_after, f_after, gap_ns * 1e-9,
                                                     self._nominal_dt, n_g, n_a)
        # no update at a chunk end inside the filled stretch (its error is still growing);
        # widened in the chunk that holds the gap's end, after its predict, before its updates
        self._gap_widening.append((int(t_fill[0]), t_after_ns, var_att, var_vel))
        self.counters['gaps_interpolated'] += 1
        self.counters['imu_interpolated'] += len(t_fill)
        return True

    def _on_gap(self, t_before_ns: int, t_after_ns: int, long: bool = True,
                w_after: FloatArray | None = None, f_after: FloatArray | None = None) -> None:
        """A gap longer than ``guard_config.max_gap_s`` between two accepted samples, or a
        shorter one (any, with ``bridge_motion``; else one during which the joints moved or
        whose joint data is not there yet).

        The data before the gap is processed first (a partial chunk at its end is dropped and
        counted in ``imu_dropped_at_gap``, or propagated without an update before a motion
        bridge). Policy ``'bridge'`` (only when the joints did not
        move across the gap: the motion during the gap is lost, CONTRACT 1): inflate the
        navigation covariance by ``bridge_*_sigma`` and the bias covariance by the bias
        random walk over the gap; the interval itself is handled like any gap by the block
        code (one nominal period, coning/sculling memory reset). Otherwise, or with policy
        ``'reinitialise'``: drop the navigator and the filter, keep the calibration states
        and their covariance block, and re-align at the next stationary window.

        A gap shorter than ``max_gap_s`` (``guard_config.bridge_motion``): the
        navigation is carried across it with the rotation the encoders measured
        (:meth:`_bridge_motion`, once joint states beyond the gap are there). Re-initialising
        lost the rest of every turn until the next stationary window: with 0.2-2 % of the
        samples dropped in bursts, more than half of some runs, which then refused.
        """
        if not self._running or self._filter is None:
            return
        cfg = self.guard_config
        period_ns = int(round(self._nominal_dt * 1e9))
        can_bridge = (cfg.bridge_motion and not long and w_after is not None
                      and f_after is not None and period_ns > 0)
        pb = self._pending_bridge
        if pb is not None and not self._joints_beyond(pb[1]) and can_bridge \
                and t_after_ns - pb[0] <= cfg.max_gap_s * 1e9:
            # another gap before the joint states of the pending bridge came (a 2 kHz IMU
            # with jittered stamps): one bridge over both (at most max_gap_s), the samples
            # between them dropped
            assert w_after is not None and f_after is not None
            self.counters['imu_dropped_at_gap'] += self._imu.drop_all()
            self._pending_bridge = (pb[0], t_after_ns - period_ns, t_after_ns,
                                    w_after.copy(), f_after.copy(), pb[5])
            return
        self._process(final=True)
        self._check_divergence()
        if self._diverged is not None or self._filter is None or not self._running:
            # a pending bridge fell back to re-initialising: what came before this gap goes
            self.counters['imu_dropped_at_gap'] += self._imu.drop_all()
            return
        still = cfg.gap_policy == 'bridge' and self._joints.still_between(
            t_before_ns, t_after_ns, self.still_tolerance_rad)
        if not still and can_bridge:
            try:
                self._propagate_rest()  # to the gap: the bridge starts there
            except sm.ImplausibleErrors as exc:
                self._declare_divergence(f'implausible sensor errors at the working point '
                                         f'({exc})')
                return
        left = self._imu.drop_all()
        if left:
            self.counters['imu_dropped_at_gap'] += left
        if still:
            q1_s = self._process_noise.q1_s
            assert q1_s is not None
            bridge_gap(self._filter.P, self.layout, q1_s, (t_after_ns - t_before_ns) * 1e-9, cfg)
            self.counters['gaps_bridged'] += 1
            return
        if (can_bridge and w_after is not None and f_after is not None
                and self._t_last_ns is not None and t_after_ns - period_ns > self._t_last_ns):
            # the navigator is at the last processed chunk end; the sample after the gap
            # integrates over its own nominal period
            self._pending_bridge = (self._t_last_ns, t_after_ns - period_ns, t_after_ns,
                                    w_after.copy(), f_after.copy(),
                                    self._before_gap(t_before_ns))
            self._prev = None
            return
        self._reinitialise_at(t_after_ns)

    def _propagate_rest(self) -> None:
        """Propagate the buffered samples after the last whole chunk (fewer than a chunk and
        its look-ahead) without a measurement update: the navigator and ``P`` reach the last
        sample before a gap (each motion bridge otherwise lost half a chunk: 43 % of a
        1 kHz recording with jittered stamps). The look-ahead of the rate differences
        repeats the last sample."""
        t, w, f = self._imu.take()
        m = len(t)
        if not m or self._nav is None or self._filter is None:
            return
        h = self._half_span
        q1_s = self._process_noise.q1_s
        assert q1_s is not None
        step = int(round(self._nominal_dt * 1e9))
        t = np.concatenate([t, t[-1] + step * np.arange(1, h + 1, dtype=np.int64)])
        w = np.vstack([w, np.repeat(w[-1:], h, axis=0)])
        f = np.vstack([f, np.repeat(f[-1:], h, axis=0)])
        blk = self._propagate(t, w, f, 1, m, ahead_repeated=True)
        self._filter.predict_rows(blk.rows_s[0], blk.chunk_noise_s(np.diag(q1_s), 0))
        if blk.n_gaps:
            widen_for_gaps(self._filter.P, self.layout, blk.n_gaps)
        self._t_last_ns = int(t[m - 1])
        self.counters['imu_processed'] += m
        self._imu.drop_all()

    def _before_gap(self, t_before_ns: int) -> tuple[int, FloatArray, FloatArray] | None:
        """The last sample before a gap, ``(stamp, gyro, accel)``, if the buffer has it."""
        last = self._imu.last_sample
        if last is None or self._imu.last_stamp_ns != t_before_ns:
            return None
        return t_before_ns, last[0].copy(), last[1].copy()

    def _joints_beyond(self, t_ns: int) -> bool:
        """Whether joint states reach far enough beyond ``t_ns`` for everything a bridge
        reads there (:data:`BRIDGE_JOINTS_AHEAD` samples of the spline's error estimate, a
        chain's still-joint window), so that a bridge is the same whether the joint states
        came long before or just in time."""
        jt = self._joints.t_ns
        if len(jt) < 2:
            return False
        spacing = (jt[-1] - jt[0]) / (len(jt) - 1)
        lead = 0 if self.fixture.concurrent else int(CHAIN_STILL_HALF_WINDOW_S * 1e9)
        return bool(jt[-1] >= t_ns + max(BRIDGE_JOINTS_AHEAD * spacing, lead))

    def _bridge_motion(self, final: bool, end: bool = False) -> bool:
        """Carry the navigation across the pending gap in motion (:meth:`_on_gap`) with the
        fixture rotation the encoders measured between the navigator's last instant ``t0`` and
        the start ``t1`` of the sample after the gap; the velocity from the fixture
        kinematics at ``t1`` (:func:`.measurements.zero_velocity`'s model with the first
        sample after the gap); ``P`` by :func:`.health.bridge_motion_covariance`. The encoder
        angle error at either end: the larger of ``bridge_encoder_sigma_rad`` and the
        encoder noise at rest, plus what the spline can miss there
        (:meth:`.buffers.JointBuffer.spline_error_at`). Waits (returns False) until joint
        states beyond ``t1`` are there (at the ``end`` of the data: what is there); re-initialises
        when they do not come, or when the joint record does not cover both ends. Returns
        whether the filter runs on.
        """
        assert self._pending_bridge is not None
        t0, t1, t_after, w1, f1, before = self._pending_bridge
        at_end = end and bool(self._joints.t_ns) and self._joints.t_ns[-1] >= t1
        if not self._joints_beyond(t1) and not at_end:  # joint states beyond t1 not there yet
            t_imu = self._imu.last_stamp_ns
            waited = 0 if t_imu is None else t_imu - t_after
            if not final and waited < self.config.max_pending_s * 1e9:
                return False
            self._reinitialise_at(t_after)
            return False
        self._pending_bridge = None
        covered, q = self._joints.positions_at(np.array([t0, t1], np.int64), holes=True)
        chain = None if self.fixture.concurrent else self._chain_motion(
            np.array([t1], np.int64))
        if q is None or not covered.all() or (chain is not None and not chain[0][0]):
            self._reinitialise_at(t_after)
            return False
        assert self._nav is not None and self._filter is not None
        spline2 = float(np.sum(self._joints.spline_error_at(np.array([t0, t1], np.int64)) ** 2))
        enc = max(self.guard_config.bridge_encoder_sigma_rad, self._encoder_scatter_rad)
        var_att = 2 * q.shape[1] * enc ** 2 + spline2  # both ends, every joint
        if np.any(self._joints.bracket_spacing_ns(np.array([t0, t1], np.int64))
                  > self.guard_config.max_gap_s * 1e9):
            self._reinitialise_at(t_after)  # a hole in the joint record longer than a gap
            return False
        offs = self.layout.slices.get(em.CHAIN_GROUP)  # the offsets as states, if they are
        if not self.fixture.concurrent:
            # a joint's zero offset turns the axes after it: its error times their travel
            # (the offset's current sigma where it is a state, else its prior)
            travel = np.abs(q[1] - q[0])
            later = np.cumsum(travel[::-1])[::-1] - travel
            sig = np.full(len(travel), self.config.chain_joint_offset_sigma_rad)
            if offs is not None:
                sig[list(self._offset_joints)] = np.sqrt(np.clip(
                    np.diag(self._filter.P)[offs], 0.0, None)) * self.layout.scale[offs]
            var_att += float(np.sum((sig * later) ** 2))
        fx = self.fixture
        q = self._with_offsets(q)
        dF = fx.R_enu_imu(q[1]) @ fx.R_enu_imu(q[0]).T
        R1 = dF @ self._nav.R_enu_imu
        rho_m = float(np.linalg.norm(self._rho))
        R0 = self._nav.R_enu_imu
        om = fx.site.omega_ie_enu
        zero = np.zeros((1, 3))
        w_c1 = sm.compensate(self._errors, w1[None], f1[None], zero)[0][0]
        var_vel = np.full(3, self.config.velocity_sigma_m_s ** 2)
        w_c0 = w_c1.copy()
        if before is not None and t_after > before[0]:
            # each end's rate: the sample next to it, moved half a period along the slope
            # between the two samples (half of that step as its sigma)
            w_b = sm.compensate(self._errors, before[1][None], before[2][None], zero)[0][0]
            step = (w_c1 - w_b) / ((t_after - before[0]) * 1e-9) * (0.5 * self._nominal_dt)
            w_c1, w_c0 = w_c1 - step, w_b + step
            var_vel += (0.5 * float(np.linalg.norm(step)) * rho_m) ** 2
        n_g = self.assumed_noise()[0]
        # the rate of one sample carries its white noise into omega x rho
        var_vel += (n_g / np.sqrt(self._nominal_dt) * rho_m) ** 2
        w_eb = w_c1 - R1.T @ om
        Ru = R1 @ np.cross(w_eb, self._rho)
        v1 = Ru.copy()  # the fixture's velocity at t1 (zero_velocity's model)
        # how far the navigated velocity was from the same model just before the gap: what
        # the model misses besides psi and the lever arm (calibration errors of the rate,
        # 0.1-0.6 mm/s on a navigation unit early in a run; without it 9 of 181 bridges were
        # followed by a gated update, with it none; carrying the navigated velocity across
        # by the model's change instead: 33)
        m0 = R0 @ np.cross(w_c0 - R0.T @ om, self._rho)
        if chain is not None:  # a chain's model adds the anchor's velocity
            chain0 = self._chain_motion(np.array([t0], np.int64))
            if chain0[0][0]:
                m0 = m0 + chain0[3][0]
        var_vel += (self._nav.v_enu_m_s - m0) ** 2
        if chain is not None:
            v1 = v1 + chain[3][0]
            var_vel = var_vel + np.diag(chain[4][0])
            if offs is not None:  # the offsets' share, no longer in chain[4]
                D = chain[6][0] * self.layout.scale[offs]  # m/s per filter unit
                var_vel = var_vel + np.einsum('ij,jk,ik->i', D, self._filter.P[offs, offs], D)
        q1_s = self._process_noise.q1_s
        assert q1_s is not None
        if self._filter.sens is not None:
            self._filter.sens = self._bridged_sens(self._filter.sens, q, dF, Ru, R1, w_eb,
                                                   chain)
        self._filter.P = bridge_motion_covariance(self._filter.P, self.layout, dF, Ru, R1, w_eb,
                                                  var_att, var_vel, q1_s, (t1 - t0) * 1e-9)
        self._nav.set_state(R1, v1, self._nav.p_enu_m)
        self._nav.reset_memory()
        self._t_last_ns = t1
        self.counters['gaps_bridged_in_motion'] += 1
        return True

    def _bridged_sens(self, sens: FloatArray, q: FloatArray, dF: FloatArray, Ru: FloatArray,
                      R1: FloatArray, w_eb: FloatArray, chain: Any) -> FloatArray:
        """The prior sensitivity (scaled) across a bridge in motion: the derivative of the
        bridge's own map (:meth:`_bridge_motion`), which sets the attitude to ``dF R0`` and the
        velocity to the fixture's. The attitude part is rotated by ``dF`` and moves with the
        joint-offset states through ``dF = R(q1) R(q0)^T`` itself, ``q`` (2, n) the angles
        with the offsets: column ``j`` is ``u_j(q1) - dF u_j(q0)``, ``u`` the joint axes in
        ENU (``d R(q) / d q_j = [u_j x] R(q)``); the velocity part is the model's:
        ``-[(R u) x] psi1 + R [omega_eb x] rho`` and, on a chain, the anchor velocity's offset
        term. Without it the bridges (32-43 of them in a run with 1 % of the IMU samples lost)
        left the correction up to 0.36 sigma off a finite difference of the whole pipeline
        (0.04 with it)."""
        lay = self.layout
        s = lay.scale
        v = sens * s  # SI
        psi = dF @ v[0:3]
        offs = lay.slices.get(em.CHAIN_GROUP)
        n_off = len(self._offset_joints) if offs is not None and lay.n_joint_offsets else 0
        if n_off:
            u = self.fixture.angular_axes_enu(q)[:, list(self._offset_joints)]  # (2, n_off, 3)
            psi = psi + (u[1] - u[0] @ dF.T).T @ v[offs][:n_off]
        vel = -skew(Ru) @ psi
        if 'lever_arm' in lay.slices:
            vel = vel + R1 @ skew(w_eb) @ v[lay.slices['lever_arm']]
        if chain is not None and offs is not None:
            vel = vel + chain[6][0] @ v[offs]
        out = v.copy()
        out[0:3], out[3:6] = psi, vel
        return out / s

    def _reinitialise_at(self, t_after_ns: int) -> None:
        """Drop the navigation (calibration kept), re-align after ``t_after_ns``."""
        self._drop_navigation()
        self._joints.drop_before(t_after_ns)
        self.counters['gaps_reinitialised'] += 1

    def _drop_navigation(self) -> None:
        """Drop the navigator and the filter; keep the calibration states and their
        covariance block (``_kept_cal_P``, put back by
        :meth:`_restore_calibration_covariance` at the next coarse alignment). Shared by
        :meth:`_on_gap` (policy 'reinitialise'), :meth:`reset_navigation`, re-alignments and
        restarts."""
        if self._filter is not None:  # else a block kept earlier is still waiting: keep it
            self._kept_cal_P = self._filter.P[6:, 6:].copy()
            if self._filter.sens is not None:
                self._kept_sens = self._filter.sens[6:].copy()
        self._running = False
        self._nav = None
        self._filter = None
        self._prev = None
        self._pending_bridge = None
        self._gap_widening = []
        self._nis.clear()  # cumulative counts of the dropped filter: a new window

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

    # ------------------------------------------------------------------ working point, prior
    def _start_point(self) -> WorkingPoint:
        """``(theta_gyro, theta_accel, lever arm, mounting)`` the filter starts from: the
        starting estimate's, else the prior mean (fresh arrays)."""
        init = self._initial
        if init is None:
            return prior_point(self.fixture, self.start, self.layout,
                               sample_kernel_mean(self.config))
        return (init.theta_gyro.copy(), init.theta_accel.copy(), init.lever_arm_imu_m.copy(),
                init.mounting_rotvec_rad.copy())

    def _start_offsets(self) -> FloatArray:
        """The joint zero offsets the filter starts from: the starting estimate's, else
        zero (the prior mean; :meth:`_start_point` for the other states)."""
        if self._initial is None:
            return np.zeros(self.layout.n_joint_offsets)
        return self._offsets_of(np.asarray(self._initial.values, float))

    def _offsets_of(self, values: FloatArray) -> FloatArray:
        """The joint zero offsets in calibration-state ``values`` (empty without them)."""
        sl = self.layout.slices.get(em.CHAIN_GROUP)
        if sl is None:
            return np.zeros(0)
        return np.array(values[sl.start - 6:sl.stop - 6], dtype=float)

    def _prior_mean(self) -> FloatArray:
        """Where pass 1 starts (:func:`.priors.prior_point`), as calibration-state values."""
        return values_of(self.layout, *prior_point(self.fixture, self.start, self.layout,
                                                   sample_kernel_mean(self.config)))

    def start_values(self) -> FloatArray:
        """Where this pass started, as calibration-state values (SI): the previous pass's
        estimate, else the prior mean (the coarse start)."""
        if self._initial is not None:
            return np.asarray(self._initial.values, float)
        return self._prior_mean_cached()

    def _prior_mean_cached(self) -> FloatArray:
        """:meth:`_prior_mean`, computed again only when the fixture, the start or the layout
        is another object (the divergence check reads it after every block: the nominal
        lever arm's forward kinematics were 6 % of a replay)."""
        key = (self.fixture, self.start, self.layout)
        c = self._prior_mean_cache
        if c is None or any(a is not b for a, b in zip(c[0], key)):
            c = self._prior_mean_cache = (key, self._prior_mean())
            c[1].flags.writeable = False
        return c[1]

    def _shift_scaled(self) -> FloatArray:
        """:attr:`_prior_shift` in the filter's scaled units."""
        assert self._prior_shift is not None
        return self._prior_shift / self.layout.scale[6:]

    def _prior_correction(self, sens: FloatArray | None = None) -> FloatArray:
        """What re-centring the prior on the starting estimate added to the estimate (SI):
        the filter's sensitivity to its initial mean along the shift (``sens``: a snapshot's
        calibration part, scaled; else the running filter's, the one kept over a
        re-alignment, or before any filter the whole shift). For constant states it is
        ``P P0^-1 (start - prior mean)`` (:mod:`.priors`); a bias whose
        random walk makes its posterior wider than its prior forgets the prior, which
        ``P P0^-1`` does not know (a consumer unit's gyro bias moved 5.4 sigma off by a second
        pass, its sigma 1.18x its prior's)."""
        if sens is None:
            f = self._filter
            sens = f.sens[6:] if f is not None and f.sens is not None else self._kept_sens
        if sens is None:
            sens = self._shift_scaled()
        return sens * self.layout.scale[6:]

    def _make_errors(self) -> Any:
        return em.errors_from_theta(self._theta_g, self._theta_a, sm.SensorErrors)

    def _state_values(self) -> FloatArray:
        return values_of(self.layout, self._theta_g, self._theta_a, self._rho, self._mount,
                         self._joint_offsets)

    def _frame(self) -> str:
        """The frame of the calibration: the configured one, else that of the data."""
        return self.guard_config.frame_id or self.frame_id or 'imu_link'

    def _last_good_result(self) -> Any:
        """CalibrationResult of the last good snapshot (cached), or None."""
        st = self._last_good_state if self._diverged is not None else (
            self._good[-1] if self._good else None)
        if st is None:
            return None
        if self._last_good_cache is None or self._last_good_cache[0] != id(st):
            self._last_good_cache = (id(st), calibration_result(
                st, self.layout, self._prior, self._frame(),
                lambda sd: {'estimator': snapshot_extra(st, self.layout)}))
        return self._last_good_cache[1]

    @property
    def _jt(self) -> list[int]:
        """The joint buffer's stamps [ns] (read by tests)."""
        return self._joints.t_ns

    @property
    def _jq(self) -> list[FloatArray]:
        """The joint buffer's unwrapped positions [rad] (read by tests)."""
        return self._joints.q_rad
