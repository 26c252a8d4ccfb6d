"""``calibration`` node: live turntable calibration with estimates and a corrected IMU stream.

Topics (relative names, remappable):

- subscribes ``imu/data_raw`` (``sensor_msgs/Imu``) and ``joint_states``
  (``sensor_msgs/JointState``) with sensor-data QoS (best effort, keep last
  ``queue_depth``);
- publishes ``imu/data_corrected`` (``sensor_msgs/Imu``, same stamp and frame) for every
  accepted raw sample, compensated in the subscription callback by
  :class:`~imu_calib_ros.core.stream_compensation.StreamCompensation` (the compensator
  node's code) with the last *good* estimate snapshot; covariances from its sigmas plus the
  sensor noise,
  ``orientation_covariance[0] = -1`` (REP-145);
- publishes, at ``estimate_rate_hz`` and transient-local (late subscribers get the latest),
  ``~/estimates`` (``diagnostic_msgs/DiagnosticArray``: every CONTRACT 4 value and its sigma
  as key/values) and one ``geometry_msgs/Vector3Stamped`` per vector group, ``~/<group>``
  and ``~/<group>_sigma`` (see :data:`VECTOR_GROUPS`);
- publishes ``/diagnostics``: input rates, rejected samples by reason (node and estimator),
  the estimator's health (NIS, covariance), level OK/WARN/ERROR/STALE.

Services (``std_srvs/Trigger``): ``~/save_calibration`` writes the CONTRACT 4 file
(``output_file``) atomically with :meth:`CalibrationResult.save`; ``~/reset`` restarts the
estimator. Parameters: :class:`CalibrationNodeConfig`, the estimator's under ``estimator.``
(the :class:`EstimatorConfig` the CLI uses). ``use_sim_time`` works: timers, staleness and
diagnostics follow ``/clock``; a backward jump of ``/clock`` (a looping bag) restarts the
estimator's navigation (rclpy jump callback); the estimator itself only sees message stamps.

Threads: the raw IMU is served by its own thread
(:class:`~imu_calib_ros.nodes.input_thread.InputThread`: serialised bytes in, then
:class:`~imu_calib_ros.core.imu_stream.ImuStream`, the compensator's code: checked, put back
in stamp order within ``reorder_window_s`` (:mod:`imu_calib_ros.core.reorder`, issue 17),
compensated; published as bytes, tens of microseconds), which queues the sample; the rest
spins in a SingleThreadedExecutor, where a 20 Hz timer hands the queue, as an ``ImuBatch``
and ``JointBatch`` arrays, to an :class:`~imu_calib_ros.core.estimator.runner.EstimatorRunner`
(a child process by default, or a thread), whose bounded queue drops and counts under
overload. Faults (issue 6): see
docs/NODES.md.
"""
from __future__ import annotations

import collections
import dataclasses
import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Vector3Stamped
from rclpy.clock import JumpThreshold
from rclpy.duration import Duration
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState
from std_srvs.srv import Trigger

from msg_adapters.convert import imu_fields_from_cdr, joint_sample_from_msg, time_msg_from_ns

from ..core.diagnostics import StampGapCounter, frame_mismatch, health_values, input_account
from ..core.errors import ImuCalibError
from ..core.estimator.config import EstimatorConfig
from ..core.estimator.runner import EstimatorRunner, Snapshot
from ..core.estimator.selfcheck import saved_extra
from ..core.imu_stream import ImuStream, Step
from ..core.input_guard import rejection_counts
from ..core.stream_compensation import StreamCompensation
from ..core.types import ImuBatch, JointBatch, JointSample
from .common import (Endpoint, NodeInterface, declare_config, finite, latched_qos,
                     publish_corrected, quiet_publisher, reliable_qos, run_node, sensor_qos)
from .fixture_source import (RobotDescriptionWatcher, describe_fixture,
                             UrdfFixtureFields, load_node_fixture_and_urdf)
from .input_thread import InputThread

NODE_NAME = 'calibration'

#: Vector groups published as Vector3Stamped: topic name -> (SensorErrors field, index list)
#: Indices are flat into the field (row-major for matrices); SI units of the field.
VECTOR_GROUPS: dict[str, tuple[str, tuple[int, int, int]]] = {
    'gyro_bias': ('gyro_bias_rad_s', (0, 1, 2)),
    'gyro_scale': ('gyro_scale_misalignment', (0, 4, 8)),
    'gyro_misalignment': ('gyro_scale_misalignment', (5, 2, 1)),  # (yz, xz, xy)
    'gyro_asymmetry': ('gyro_scale_asymmetry', (0, 1, 2)),
    'gyro_g_sensitivity_x': ('gyro_g_sensitivity_rad_s_per_m_s2', (0, 1, 2)),
    'gyro_g_sensitivity_y': ('gyro_g_sensitivity_rad_s_per_m_s2', (3, 4, 5)),
    'gyro_g_sensitivity_z': ('gyro_g_sensitivity_rad_s_per_m_s2', (6, 7, 8)),
    'accel_bias': ('accel_bias_m_s2', (0, 1, 2)),
    'accel_scale': ('accel_scale_misalignment', (0, 4, 8)),
    'accel_misalignment_upper': ('accel_scale_misalignment', (5, 2, 1)),  # (yz, xz, xy)
    'accel_misalignment_lower': ('accel_scale_misalignment', (7, 6, 3)),  # (zy, zx, yx)
    'accel_asymmetry': ('accel_scale_asymmetry', (0, 1, 2)),
    'accel_quadratic': ('accel_quadratic_per_m_s2', (0, 1, 2)),
    'size_effect_x': ('size_effect_m', (0, 1, 2)),  # r_x = (0, r_xy, r_xz)
    'size_effect_y': ('size_effect_m', (3, 4, 5)),  # r_y = (r_yx, 0, r_yz)
    'size_effect_z': ('size_effect_m', (6, 7, 8)),  # r_z = (r_zx, r_zy, 0)
}


#: Live blocks are the offline ones (the estimator's default, 50 updates = 5 s): the node
#: and ``imu-calib replay`` run the same computation and give the same numbers (issue 16 item
#: 10: with 1 s blocks live they differed by up to 0.72 sigma on another simulator's data;
#: test_live_offline.py). Estimates are then up to one block behind the data.
LIVE_BLOCK_CHUNKS = EstimatorConfig().block_chunks


@dataclass(frozen=True)
class CalibrationNodeConfig(UrdfFixtureFields):  # + the URDF parameters
    """Parameters of the calibration node (``config/calibration_node.yaml``)."""

    fixture: str = field(default='', metadata={
        'doc': 'fixture file (CONTRACT 2 YAML or a .urdf) of the table or arm in use, a shipped'
               ' fixture name (three_axis, savage_2axis, arm6.urdf), or robot_description: the'
               ' URDF from the robot_description topic (issue 15)',
        'required': "a calibration against another table's kinematics is silently wrong"})
    imu_grade: str = field(default='', metadata={
        'doc': 'optional IMU grade hint (config/imus name or path): prior floors; empty = '
               'none, everything measured from the data (issue 11)'})
    frame_id: str = field(default='', metadata={
        'doc': 'IMU frame to accept; empty = the first sample\'s frame'})
    imu_rate_hz: float = field(default=0.0, metadata={
        'doc': 'nominal IMU rate [Hz] (gaps, noise of the mean, missing samples); 0 = detect'
               ' from the data (median of the first 20 stamp intervals)',
        'min': 0.0, 'max': 100000.0})
    reorder_window_s: float = field(default=0.005, metadata={
        'doc': 'longest wait [s] of a raw IMU sample to put the stream back in header-stamp'
               ' order (transport jitter); a sample later than that is rejected as'
               ' out_of_order (reorder.late); 0 = no wait', 'min': 0.0, 'max': 1.0})
    output_file: str = field(default='imu_calibration.yaml', metadata={
        'doc': 'where ~/save_calibration writes the calibration (CONTRACT 4)'})
    save_on_shutdown: bool = field(default=False, metadata={
        'doc': 'on SIGINT/SIGTERM, save the latest good estimate to output_file'})
    force_save: bool = field(default=False, metadata={
        'doc': 'save (service, shutdown) even when the run fails its self-check, marked as '
               'failing under provenance.self_check; false: refuse (issue 17)'})
    estimate_rate_hz: float = field(default=1.0, metadata={
        'doc': 'rate of ~/estimates and the per-group Vector3Stamped [Hz]', 'min': 0.01,
        'max': 100.0})
    diagnostics_rate_hz: float = field(default=1.0, metadata={
        'doc': 'rate of /diagnostics [Hz]', 'min': 0.01, 'max': 100.0})
    filter_rate_hz: float = field(default=20.0, metadata={
        'doc': 'rate at which queued samples are handed to the estimator [Hz]', 'min': 1.0,
        'max': 1000.0})
    estimator_mode: Literal['process', 'thread'] = field(default='process', metadata={
        'doc': 'run the estimator in a child process (no GIL contention) or a thread'})
    estimator_queue_batches: int = field(default=50, metadata={
        'doc': 'bound of the estimator input queue [batches of 1/filter_rate_hz]; when full,'
               ' batches are dropped and counted', 'min': 1, 'max': 10000})
    stale_timeout_s: float = field(default=2.0, metadata={
        'doc': 'no raw IMU for this long [s, node clock] = STALE', 'min': 0.01})
    joint_timeout_s: float = field(default=5.0, metadata={
        'doc': 'IMU data for this long [s of stamps] without joint states of the fixture'
               ' joints = ERROR', 'min': 0.1})
    stopped_after_s: float = field(default=10.0, metadata={
        'doc': 'the estimator counts as stopped (ERROR; a save is refused unless force_save)'
               ' when its filter has not run for this long [s of IMU stamps] after it ran'
               ' (a gap re-initialised the navigation and no stationary window came)',
        'min': 0.1})
    warn_rejected_fraction: float = field(default=0.01, metadata={
        'doc': 'WARN when more than this fraction of the inputs was rejected', 'min': 0.0,
        'max': 1.0})
    log_throttle_s: float = field(default=5.0, metadata={
        'doc': 'at most one log line per rejection reason per this period [s]', 'min': 0.0})
    queue_depth: int = field(default=1000, metadata={
        'doc': 'queue depth of the raw input (sensor-data QoS, best effort) and of the '
               'corrected output (reliable, keep last)', 'min': 1,
        'max': 100000})
    estimator: EstimatorConfig = field(default_factory=lambda: EstimatorConfig(
        block_chunks=LIVE_BLOCK_CHUNKS), metadata={
        'doc': 'the streaming estimator (same keys as config/estimator.yaml; the same 5 s '
               'blocks as imu-calib replay)'})


def _flat_items(prefix: str, value: Any) -> list[tuple[str, str]]:
    """``(key, text)`` pairs of a nested dict/list (CONTRACT 4 layout) for KeyValue lists."""
    if isinstance(value, dict):
        out = []
        for k, v in value.items():
            out += _flat_items(f'{prefix}.{k}' if prefix else str(k), v)
        return out
    arr = np.asarray(value)
    if arr.dtype.kind in 'fiu' and arr.ndim > 0:
        return [(f'{prefix}[{",".join(map(str, idx))}]', f'{float(arr[idx]):.9g}')
                for idx in np.ndindex(arr.shape)]
    return [(prefix, str(value))]


class CalibrationNode(Node):
    """Live calibration: raw IMU + joint states in; corrected IMU, estimates, diagnostics out."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config: CalibrationNodeConfig = declare_config(self, CalibrationNodeConfig)
        cfg = self.config
        from ..core.estimator import CalibrationEstimator
        from ..core.imu_grade import load_grade
        # a file, a shipped name, or the robot_description topic (waits; one line either way)
        self.fixture, urdf_text = load_node_fixture_and_urdf(self, cfg)
        self.grade = load_grade(cfg.imu_grade) if cfg.imu_grade else None
        self.joint_names = tuple(self.fixture.joint_names)
        prior = CalibrationEstimator(self.fixture, self.grade, cfg.estimator).estimate(
            frame_id=cfg.frame_id or 'imu_link')
        self.compensation = StreamCompensation(
            # without a grade hint the output covariances hold the calibration's uncertainty
            # only, until a grade is given (the estimator's measured noise is not fed back)
            prior, self.grade.gyro_noise_rad_s_rt_hz if self.grade else 0.0,
            self.grade.accel_noise_m_s2_rt_hz if self.grade else 0.0,
            1.0 / cfg.imu_rate_hz if cfg.imu_rate_hz > 0 else 0.0)
        # raw IMU checked, back in stamp order, compensated (the compensator's code too); the
        # first frame is adopted when frame_id is empty
        self.stream = ImuStream(self.compensation, cfg.frame_id, cfg.reorder_window_s,
                                adopt_frame=True)
        self.runner = EstimatorRunner(cfg.estimator_mode,
                                      (self.fixture, cfg.imu_grade, cfg.estimator),
                                      cfg.frame_id or 'imu_link', cfg.estimator_queue_batches)
        self._good_seq = -1
        # fixture:=robot_description: later URDFs on the topic (robot_state_publisher
        # republishes on a change); see _on_robot_description
        self._has_data = False  # the run has accepted IMU data (cleared by ~/reset)
        self._next_chain: Any = None  # a changed chain kept out of this run (~/reset adopts)
        self._description_note = ''  # for /diagnostics: what the last change did
        self._description_warn = ''  # WARN text while the topic's chain is not the run's
        self._watcher = (RobotDescriptionWatcher(self, cfg, urdf_text, lambda: self.fixture,
                                                 self._on_robot_description)
                         if urdf_text is not None else None)
        # filled by the IMU input thread and the joint thread, drained by the filter timer
        self._pending_imu: collections.deque[tuple[int, Any, Any]] = collections.deque()
        self._pending_joints: collections.deque[JointSample] = collections.deque()
        self.counts = {'imu': 0, 'joint': 0, 'published': 0, 'missing_imu': 0,
                       'missing_joint': 0, 'time_jumps_backward': 0}
        self._joint_gaps = StampGapCounter()  # joint states lost upstream, from stamp gaps
        # joint states rejected here (the IMU's: self.stream.rejected; both in self.rejected)
        self._joint_rejected = {'bad_message': 0, 'joint_names': 0, 'non_finite': 0}
        self._logged: dict[str, tuple[int, float]] = {}  # reason -> (count, monotonic time)
        self._frame_mark = (0, 0)  # (imu, rejected frame_id) at the last diagnostics
        self._frame_error = ''
        self._rate_mark: tuple[int, int, Any] = (0, 0, None)
        self._joint_ok = False
        self._last_joint_ns: int | None = None  # stamp of the last good joint state
        self._joint_stamps: dict[str, int] = {}  # the last stamp of each fixture joint
        self._last_rx: Any = None  # rclpy Time of the last raw IMU message
        self._pub = self.create_publisher(Imu, 'imu/data_corrected',
                                          reliable_qos(cfg.queue_depth))
        self._imu_sub = InputThread(self, Imu, 'imu/data_raw', self._on_imu,
                                    sensor_qos(cfg.queue_depth), raw=True,
                                    idle=self._release_held)
        # joint states in their own thread too: through the executor each message cost a
        # wake (~0.3 ms: wait-set rebuild), a quarter of a core at 1 kHz (issue 16 item 8)
        self._joint_sub = InputThread(self, JointState, 'joint_states', self._on_joints,
                                      sensor_qos(cfg.queue_depth), name='joints')
        self._est_pub = quiet_publisher(self, DiagnosticArray, '~/estimates', latched_qos())
        self._vec_pubs = {name: (quiet_publisher(self, Vector3Stamped, f'~/{name}',
                                                 latched_qos()),
                                 quiet_publisher(self, Vector3Stamped, f'~/{name}_sigma',
                                                 latched_qos()))
                          for name in VECTOR_GROUPS}
        self._diag_pub = quiet_publisher(self, DiagnosticArray, '/diagnostics', reliable_qos())
        self.create_timer(1.0 / cfg.filter_rate_hz, self._on_filter_timer)
        self.create_timer(1.0 / cfg.estimate_rate_hz, self._on_estimate_timer)
        self.create_timer(1.0 / cfg.diagnostics_rate_hz, self._on_diag_timer)
        self.create_service(Trigger, '~/save_calibration', self._on_save)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self._jump_handler = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=Duration(nanoseconds=-1),
                          on_clock_change=False), post_callback=self._on_time_jump)
        self.get_logger().info(
            f'calibrating on fixture {cfg.fixture} (joints {", ".join(self.joint_names)}), '
            f'grade {self.grade.name if self.grade else "none (measured)"}, '
            f'estimator in a {cfg.estimator_mode}, output '
            f'{cfg.output_file}')

    # ------------------------------------------------------------------ state views
    @property
    def frame_id(self) -> str:
        """The IMU frame accepted (the configured one, else the first sample's)."""
        return self.stream.frame_id

    @property
    def rejected(self) -> dict[str, int]:
        """What this node rejected, by reason (IMU and joint states)."""
        imu, joint = self.stream.rejected, self._joint_rejected
        return {'frame_id': imu['frame_id'],
                'non_finite': imu['non_finite'] + joint['non_finite'],
                'out_of_order': imu['out_of_order'],
                'bad_message': imu['bad_message'] + joint['bad_message'],
                'joint_names': joint['joint_names'],
                'compensation_non_finite': imu['compensation_non_finite']}

    # ------------------------------------------------------------------ input callbacks
    def _on_imu(self, data: bytes) -> None:
        """One raw IMU message (serialised bytes; runs in the IMU input thread): decoded, then
        :class:`ImuStream` (checks, reorder window, compensation); see :meth:`_take`."""
        self.counts['imu'] += 1
        self._last_rx = self.get_clock().now()
        try:
            ns, frame, gyro, accel = imu_fields_from_cdr(data)
        except ImuCalibError:
            self.stream.reject('bad_message')
            return
        self._take(self.stream.push(ns, frame, gyro, accel, time.monotonic_ns()))

    def _release_held(self) -> float | None:
        """IMU input thread, after each burst: the samples whose reorder wait is over (the
        stream paused); returns the seconds until the next one is due."""
        self._take(self.stream.release(time.monotonic_ns()))
        return self.stream.seconds_to_due(time.monotonic_ns())

    def _take(self, step: Step) -> None:
        """Publish what the stream accepted (compensated), queue it for the estimator."""
        if step.adopted_frame:
            self.runner.set_frame_id(step.adopted_frame)
        if step.accepted:
            self._has_data = True
        for c in step.accepted:
            if publish_corrected(self._pub, c):  # else counted as compensation_non_finite
                self.counts['published'] += 1
            self._pending_imu.append((c.stamp_ns, c.gyro, c.accel))  # cheap to queue
        self.counts['missing_imu'] = self.stream.missing
        if step.rate_known:
            self._on_rate_known()

    def _on_rate_known(self) -> None:
        """Once the IMU period is measured (IMU thread): log the rate; one WARN when a
        configured rate is more than 20 % off."""
        comp = self.compensation
        assert comp.measured_period_s is not None
        if comp.rate_mismatch:
            self.get_logger().warn(comp.rate_mismatch)
        else:
            self.get_logger().info(f'IMU rate {1.0 / comp.measured_period_s:.4g} Hz (from the '
                                   'stamps)')

    def _on_joints(self, msg: JointState) -> None:
        self.counts['joint'] += 1
        try:
            sample = joint_sample_from_msg(msg)
        except ImuCalibError:
            self._joint_rejected['bad_message'] += 1
            return
        if not any(n in sample.names for n in self.joint_names):
            self._joint_names_seen = sample.names
            self._joint_rejected['joint_names'] += 1
            return
        if not finite(sample.positions_rad):
            self._joint_rejected['non_finite'] += 1
            return
        for name in sample.names:  # one axis per message: each fixture joint's own stamp
            if name in self.joint_names:
                self._joint_stamps[name] = sample.stamp_ns
        if len(self._joint_stamps) == len(self.joint_names):  # every joint has come
            self._joint_ok = True
            self._last_joint_ns = min(self._joint_stamps.values())  # an axis that stops
        if self.joint_names[0] in sample.names:  # the merge's instants: the outer's stamps
            self.counts['missing_joint'] += self._joint_gaps.push(sample.stamp_ns)
        self._pending_joints.append(sample)

    def _on_time_jump(self, jump: Any) -> None:
        """``/clock`` went backward (a looping bag): restart navigation, keep calibration."""
        if jump.delta.nanoseconds >= 0:
            return
        self.counts['time_jumps_backward'] += 1
        self._clear_pending()
        self.stream.restart()
        self._last_joint_ns = None
        self._joint_stamps = {}
        self._joint_gaps.reset()
        self.runner.command('reset_navigation')
        self.get_logger().warn(f'time jumped back by {-jump.delta.nanoseconds * 1e-9:.3f} s: '
                               'estimator navigation restarted (calibration kept)')

    # ------------------------------------------------------------------ robot_description
    def _on_robot_description(self, fixture: Any, changes: list[str], error: str) -> None:
        """A URDF on ``robot_description`` other than the last one (executor thread).

        Never two chains in one calibration: a different chain is adopted only while the run
        has no IMU data (a new estimator on it, one INFO line); once data came the run keeps
        its chain, says once (WARN line, ``/diagnostics`` WARN) what changed, and ``~/reset``
        restarts the calibration on the new chain. The same chain (another text: meshes,
        colours, links off the chain) changes nothing; a URDF that cannot be built is
        ignored with a WARN saying why.
        """
        log = self.get_logger()
        if fixture is None:
            self._description_note = (f'update {self._watcher_updates()} ignored (cannot build '
                                      f'the chain: {error}); calibrating on the chain it '
                                      'started with')
            self._description_warn = f'robot_description {self._description_note}'
            log.warn(self._description_warn)
            return
        if not changes:
            was = self._next_chain is not None or self._description_warn
            self._next_chain = None
            self._description_warn = ''
            self._description_note = (f'update {self._watcher_updates()}: the same chain '
                                      '(kinematics unchanged), nothing to do')
            log.info(f'robot_description changed, the chain is the same as the run\'s'
                     f'{" again" if was else ""}: nothing to do')
            return
        what = '; '.join(changes)
        if not self._has_data:
            self._adopt(fixture)
            self._description_note = (f'update {self._watcher_updates()} adopted before any '
                                      f'IMU data: {what}')
            self._description_warn = ''
            log.info(f'robot_description changed before any IMU data: adopted the new chain '
                     f'({what}); {describe_fixture(fixture, self.config)}')
            return
        self._next_chain = fixture
        self._description_note = (f'update {self._watcher_updates()} NOT applied: the '
                                  f'calibration keeps the chain it started with; changed: '
                                  f'{what}; ~/reset restarts it on the new chain')
        self._description_warn = (f'robot_description changed while calibrating: kept the '
                                  f'run\'s chain (a calibration never mixes two); changed: '
                                  f'{what}; ~/reset restarts the calibration on the new chain')
        log.warn(self._description_warn)

    def _watcher_updates(self) -> int:
        return self._watcher.updates if self._watcher is not None else 0

    def _adopt(self, fixture: Any) -> None:
        """Run on ``fixture`` from now: a new estimator on it (the old one and anything queued
        for it dropped)."""
        cfg = self.config
        self._clear_pending()
        self.runner.stop()
        self.fixture = fixture
        self.joint_names = tuple(fixture.joint_names)
        self._joint_ok = False
        self._last_joint_ns = None
        self._joint_stamps = {}
        self._good_seq = -1
        self.runner = EstimatorRunner(cfg.estimator_mode, (fixture, cfg.imu_grade, cfg.estimator),
                                      self.frame_id or cfg.frame_id or 'imu_link',
                                      cfg.estimator_queue_batches)

    # ------------------------------------------------------------------ estimator
    def _hand_over(self) -> None:
        """Queued samples to the estimator (each kind in stamp order, as arrays: one
        :class:`ImuBatch`, a :class:`JointBatch` per joint-name list), newest snapshot to the
        stream."""
        imu = [self._pending_imu.popleft() for _ in range(len(self._pending_imu))]
        joints = [self._pending_joints.popleft() for _ in range(len(self._pending_joints))]
        if imu or joints:
            self.runner.submit(ImuBatch.from_rows(imu, self.frame_id or 'imu_link'),
                               JointBatch.runs(joints))
        self.runner.poll()
        good = self.runner.last_good
        if good is not None and good.seq != self._good_seq:
            self._good_seq = good.seq
            self.compensation.update(good.result)

    def _clear_pending(self) -> None:
        self._pending_imu.clear()
        self._pending_joints.clear()

    def _on_filter_timer(self) -> None:
        self._hand_over()

    def _on_estimate_timer(self) -> None:
        snap = self.runner.latest_estimate
        if snap is None:
            return
        result = snap.result
        diverged = snap.diverged or bool(self.runner.latest and self.runner.latest.diverged)
        if not (finite(result.errors.as_vector()) and finite(result.sigma.as_vector())):
            return  # never a NaN out of a publisher; diagnostics say ERROR
        stamp = time_msg_from_ns(self.stream.last_ns) if self.stream.last_ns else \
            self.get_clock().now().to_msg()
        arr = DiagnosticArray()
        arr.header.stamp = stamp
        level = DiagnosticStatus.ERROR if diverged else DiagnosticStatus.OK
        status = DiagnosticStatus(name=f'{self.get_name()}: calibration estimate',
                                  hardware_id=self.frame_id, level=level,
                                  message='DIVERGED: the corrected stream uses the last good '
                                  'estimate' if diverged else
                                  'one-sigma values under sigma.*, SI units')
        status.values = [KeyValue(key=k, value=v)
                         for k, v in _flat_items('', result.to_dict()['imu_calibration'])]
        arr.status = [status]
        self._est_pub.publish(arr)
        for name, (attr, idx) in VECTOR_GROUPS.items():
            value = np.asarray(getattr(result.errors, attr), float).ravel()
            sigma = np.asarray(getattr(result.sigma, attr), float).ravel()
            for pub, v in zip(self._vec_pubs[name], (value, sigma)):
                msg = Vector3Stamped()
                msg.header.stamp = stamp
                msg.header.frame_id = self.frame_id
                msg.vector.x, msg.vector.y, msg.vector.z = (float(v[i]) for i in idx)
                pub.publish(msg)

    # ------------------------------------------------------------------ diagnostics
    def reasons(self, health: dict[str, Any]) -> dict[str, int]:
        """Rejected input by reason, each sample once (``core.input_guard.rejection_counts``):
        ``node.*`` what this node dropped before the estimator (its input guard never sees
        those), ``guard.*`` the input guard's own counts; non-zero only. Gaps (accepted
        samples), gate rejections (measurement updates) and missing samples are not here."""
        node = dict(self.rejected, estimator_queue_full=self.runner.dropped)
        return rejection_counts(health.get('rejected'), node)

    def _log_reasons(self, reasons: dict[str, int]) -> None:
        """One throttled WARN line per reason whose counter grew."""
        now = time.monotonic()
        for reason, n in reasons.items():
            seen, t = self._logged.get(reason, (0, -math.inf))
            if n > seen and now - t >= self.config.log_throttle_s:
                self._logged[reason] = (n, now)
                self.get_logger().warn(f'rejected input ({reason}): {n - seen} more, {n} in '
                                       'total' + self._hint(reason))

    def _hint(self, reason: str) -> str:
        if reason == 'node.frame_id':
            return (f'; received "{self.stream.rejected_frame}", expected frame_id '
                    f'"{self.frame_id}"')
        if reason == 'node.joint_names':
            seen = getattr(self, '_joint_names_seen', ())
            return f'; expected joints {list(self.joint_names)}, got {list(seen)}'
        return ''

    def _on_diag_timer(self) -> None:
        self._hand_over()
        self.runner.refresh_health()  # shown at the next period
        now = self.get_clock().now()
        snap = self.runner.latest
        health = dict(snap.health) if snap is not None else {}
        imu_n, joint_n = self.counts['imu'], self.counts['joint']
        last_imu, last_joint, last_t = self._rate_mark
        dt = (now - last_t).nanoseconds * 1e-9 if last_t is not None else 0.0
        self._rate_mark = (imu_n, joint_n, now)
        # totals always; the other counters only when not zero
        values = {k: str(v) for k, v in self.counts.items()
                  if v or k in ('imu', 'joint', 'published')}
        comp = self.compensation
        if comp.measured_period_s is not None:
            values['imu_rate_measured_hz'] = f'{1.0 / comp.measured_period_s:.6g}'
        if comp.rate_mismatch:
            values['imu_rate_warning'] = comp.rate_mismatch
        if dt > 0:
            values['imu_rate_hz'] = f'{(imu_n - last_imu) / dt:.1f}'
            values['joint_rate_hz'] = f'{(joint_n - last_joint) / dt:.1f}'
        reasons = self.reasons(health)
        values.update({f'rejected.{k}': str(v) for k, v in reasons.items()})
        values.update({f'reorder.{k}': str(v)
                       for k, v in self.stream.reorder.stats.as_dict().items() if v})
        values.update(health_values(health))
        values['estimator_alive'] = str(self.runner.alive)
        if self._description_note:
            values['robot_description'] = self._description_note
        account = self.account(health, snap)
        values['input'] = account['summary']
        self._check_frames(imu_n)
        level, message = self._level(now, imu_n, joint_n, reasons, snap, account)
        self._log_reasons({**reasons, 'node.missing_imu': self.counts['missing_imu']})
        status = DiagnosticStatus(name=f'{self.get_name()}: IMU calibration', level=level,
                                  message=message, hardware_id=self.frame_id)
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = now.to_msg()
        self._diag_pub.publish(arr)

    def _check_frames(self, imu_n: int) -> None:
        """ERROR while every IMU sample since the last diagnostics was rejected for its
        frame (kept through periods without IMU input)."""
        last_imu, last_frame = self._frame_mark
        frame_n = self.rejected['frame_id']
        self._frame_mark = (imu_n, frame_n)
        if imu_n > last_imu:
            self._frame_error = frame_mismatch(imu_n - last_imu, frame_n - last_frame,
                                               self.stream.rejected_frame, self.frame_id)

    def stopped(self, snap: Snapshot | None) -> str:
        """Why the estimator stopped ('' = it runs): its process died, it diverged, or its
        filter has not run for ``stopped_after_s`` of data after it ran."""
        if not self.runner.alive:
            return 'the estimator process died'
        if snap is None:
            return ''
        if snap.diverged:
            return 'diverged'
        idle = float(snap.health.get('stopped_for_s', 0.0) or 0.0)
        if idle > self.config.stopped_after_s:
            return (f'its filter has not run for {idle:.0f} s of data: the navigation waits '
                    'for a stationary window to re-align')
        return ''

    def account(self, health: dict[str, Any], snap: Snapshot | None) -> dict[str, Any]:
        """What the calibration is built from (``core.diagnostics.input_account``)."""
        rejected = sum(self.rejected[k] for k in ('frame_id', 'non_finite', 'out_of_order',
                                                  'bad_message'))
        return input_account(health, self.counts['imu'], self.counts['missing_imu'],
                             self.runner.dropped, rejected, self.counts['missing_joint'],
                             self.stopped(snap))

    def _level(self, now: Any, imu_n: int, joint_n: int, reasons: dict[str, int],
               snap: Snapshot | None, account: dict[str, Any]) -> tuple[bytes, str]:
        if self._last_rx is None or (now - self._last_rx).nanoseconds * 1e-9 > \
                self.config.stale_timeout_s:
            return DiagnosticStatus.STALE, 'no raw IMU data' + (
                f'; {account["summary"]}' if account['partial'] else '')
        if not self.runner.alive:
            return DiagnosticStatus.ERROR, 'the estimator process died'
        if account['stopped']:
            return DiagnosticStatus.ERROR, f'estimator stopped: {account["summary"]}'
        for sub in (self._imu_sub, self._joint_sub):
            if not sub.alive:
                return DiagnosticStatus.ERROR, f'an input thread stopped {sub.error}'
        if snap is not None and snap.diverged:
            return DiagnosticStatus.ERROR, ('estimator diverged: the corrected stream uses '
                                            'the last good calibration')
        if self._frame_error:
            return DiagnosticStatus.ERROR, self._frame_error
        expected = ', '.join(self.joint_names)
        if not self._joint_ok and self.stream.first_ns is not None and self.stream.last_ns and \
                (self.stream.last_ns - self.stream.first_ns) * 1e-9 > self.config.joint_timeout_s:
            msg = (f'no joint_states with the fixture joints [{expected}] after '
                   f'{self.config.joint_timeout_s:g} s of IMU data')
            if self._joint_stamps:  # one axis per message, and some never came
                never = ', '.join(n for n in self.joint_names if n not in self._joint_stamps)
                msg += f' ({never} never came; {", ".join(self._joint_stamps)} did)'
            self.get_logger().error(msg, throttle_duration_sec=self.config.log_throttle_s)
            return DiagnosticStatus.ERROR, msg
        last_j, last_i = self._last_joint_ns, self.stream.last_ns
        if self._joint_ok and last_j is not None and last_i is not None and \
                (last_i - last_j) * 1e-9 > self.config.joint_timeout_s:
            msg = (f'joint_states stopped: none with the fixture joints [{expected}] for '
                   f'{(last_i - last_j) * 1e-9:.1f} s of IMU data')
            self.get_logger().error(msg, throttle_duration_sec=self.config.log_throttle_s)
            return DiagnosticStatus.ERROR, msg
        if snap is not None and snap.error:
            return DiagnosticStatus.ERROR, snap.error
        if self._description_warn:
            return DiagnosticStatus.WARN, self._description_warn
        if self.compensation.rate_mismatch:
            return DiagnosticStatus.WARN, self.compensation.rate_mismatch
        bad = sum(reasons.values()) + self.counts['missing_imu'] + self.counts['missing_joint']
        total = max(imu_n + joint_n + self.counts['missing_imu'] + self.counts['missing_joint'],
                    1)
        if bad / total > self.config.warn_rejected_fraction:
            return DiagnosticStatus.WARN, (f'{bad} of {total} inputs rejected or lost; '
                                           f'{account["summary"]}')
        if self.runner.dropped or account['navigation_restarts']:
            # the calibration is partial: kept visible (the counts only grow) until ~/reset
            return DiagnosticStatus.WARN, account['summary']
        if snap is not None and str(snap.health.get('status', '')).upper() == 'WARN':
            return DiagnosticStatus.WARN, str(snap.health.get('message', 'estimator warning'))
        return DiagnosticStatus.OK, 'calibrating'

    # ------------------------------------------------------------------ services, shutdown
    def save(self) -> tuple[bool, str]:
        """Everything received so far into the estimator, then write the last good estimate."""
        self._hand_over()
        if not self.runner.request('estimate', 60.0, flush=True):
            if not self.runner.alive:
                return False, ('the estimator process ended unexpectedly (its error is in '
                               'this node\'s log); nothing saved')
            return False, 'the estimator did not answer within 60 s'
        self._hand_over()
        good, latest = self.runner.last_good, self.runner.latest_estimate
        if good is None:
            return False, f'no usable estimate yet{": " + latest.error if latest else ""}'
        health = good.result.extra.get('estimator', {}).get('health', {})
        if not health.get('imu_processed', 0):
            # a file of prior values would look like a calibration: refuse (README: never
            # silently wrong)
            lh = dict(latest.health) if latest is not None and latest.health else {}
            if latest is not None and latest.diverged and lh.get('imu_processed', 0):
                # the filter ran and diverged before its first good snapshot (a loaded
                # machine lost samples): say so, not 'no data'
                return False, ('nothing to save yet: the estimator diverged ('
                               f'{lh.get("divergence_reason") or "see its diagnostics"}) before '
                               'a good estimate and restarts from its coarse start with the '
                               'next data')
            if latest is not None and lh.get('imu_processed', 0) and lh.get('restarts', 0):
                # it ran, diverged and restarted (not latched): not 'no data' either
                return False, ('nothing to save yet: the estimator diverged and restarted '
                               f'from its coarse start ({lh.get("restarts")} restart(s)) '
                               'before a good estimate')
            if latest is not None and latest.error:
                # it refused the data (e.g. the coarse start: the gyros do not follow the
                # fixture's joints): that reason, not 'no data'
                return False, f'nothing to save: {latest.error}'
            return False, ('nothing to save: the estimator has not used any IMU data yet '
                           f'({health.get("imu_samples", 0)} samples received; it starts at a '
                           'stationary window with joint states)')
        account = self.account(dict(self.runner.latest.health) if self.runner.latest else {},
                               self.runner.latest)
        if account['stopped'] and not self.config.force_save:
            return False, (f'not saved: the estimator stopped ({account["stopped"]}); '
                           f'{account["summary"]}; force_save:=true writes it marked')
        extra, why = saved_extra(good.result.extra, latest.selfcheck if latest else None,
                                 self.config.force_save)
        if extra is None:  # issue 17: never a plain file from a run its evidence condemns
            return False, (f'not saved, {why}; {account["summary"]}; force_save:=true writes '
                           'it marked as failing')
        extra['provenance'] = dict(extra.get('provenance', {}) or {}, input=account)
        try:
            dataclasses.replace(good.result, extra=extra).save(self.config.output_file)
        except (ImuCalibError, OSError) as exc:
            return False, f'cannot write {self.config.output_file}: {exc}'
        note = ' (the estimator diverged: last good estimate)' if good is not latest else ''
        failed = '' if extra['provenance']['self_check']['passed'] else \
            ' (FAILED its self-check: written because of force_save)'
        stopped = ' (the estimator STOPPED: written because of force_save)' \
            if account['stopped'] else ''
        return True, f'{self.config.output_file}{note}{failed}{stopped}; {account["summary"]}'

    def _on_save(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        response.success, response.message = self.save()
        log = self.get_logger().info if response.success else self.get_logger().error
        log(f'save_calibration: {response.message}')
        note = self._walk_note() if response.success else None
        if note:
            self.get_logger().warn(f'save_calibration: note: {note}')
        return response

    def _walk_note(self) -> str | None:
        """What ``imu-calib replay`` notes when the saved gyro-bias sigmas rest on the assumed
        MEMS drift alone (``estimator.bias_walk`` of the estimate :meth:`save` wrote), else
        None."""
        from ..core.estimator.noise import assumed_walk_note
        good = self.runner.last_good
        return None if good is None else assumed_walk_note(good.result.extra,
                                                           'the imu_grade parameter')

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        self._clear_pending()
        self.stream.restart()
        adopted = ''
        if self._next_chain is not None:  # the chain robot_description changed to
            fixture, self._next_chain = self._next_chain, None
            self._adopt(fixture)
            adopted = (f'; adopted the chain from the latest robot_description: '
                       f'{describe_fixture(fixture, self.config)}')
            self._description_note = f'update {self._watcher_updates()} adopted at ~/reset'
            self._description_warn = ''
        ok = self.runner.request('reset', 30.0)
        self._has_data = False
        self.stream.reset_counts()
        self._joint_rejected = {k: 0 for k in self._joint_rejected}
        self.stream.last_ns = None
        self._last_joint_ns = None
        self._joint_stamps = {}
        self._joint_gaps.reset()
        self.compensation.reset()
        self._hand_over()
        response.success = ok
        response.message = ('estimator reset' if ok else 'the estimator did not answer') + adopted
        self.get_logger().info(response.message)
        return response

    def on_shutdown(self) -> None:
        """After SIGINT/SIGTERM: save the latest good estimate if ``save_on_shutdown``."""
        if self.config.save_on_shutdown:
            ok, message = self.save()
            print(f'{self.get_name()}: save on shutdown: {message}', file=sys.stderr,
                  flush=True)
            if not ok:
                raise ImuCalibError(message)
            note = self._walk_note()
            if note:
                print(f'{self.get_name()}: note: {note}', file=sys.stderr, flush=True)

    def destroy_node(self) -> None:
        """Stop the input thread and the estimator worker, then the node."""
        self._imu_sub.stop()
        self._joint_sub.stop()
        self.runner.stop()
        super().destroy_node()


INTERFACE = NodeInterface(
    name=NODE_NAME, config=CalibrationNodeConfig, params_file='config/calibration_node.yaml',
    summary='Live turntable calibration of an IMU: a strapdown navigator and an error EKF '
            'estimate the sensor errors of CONTRACT 3 with one-sigma values from the raw IMU '
            'and the table\'s joint states; the raw stream is republished corrected with the '
            'latest good estimate.',
    subscribes=(
        Endpoint('imu/data_raw', 'sensor_msgs/msg/Imu',
                 'raw IMU, interval means (CONTRACT 1); sensor-data QoS'),
        Endpoint('joint_states', 'sensor_msgs/msg/JointState',
                 'positions of the fixture joints; sensor-data QoS'),
        Endpoint('robot_description', 'std_msgs/msg/String',
                 'with fixture:=robot_description only: the URDF at start (reliable, '
                 'transient local, as robot_state_publisher publishes it); a changed chain '
                 'later is adopted only before any IMU data, else kept out of the run (WARN, '
                 '~/reset adopts it)'),
        Endpoint('/clock', 'rosgraph_msgs/msg/Clock', 'with use_sim_time:=true')),
    publishes=(
        Endpoint('imu/data_corrected', 'sensor_msgs/msg/Imu',
                 'every accepted raw sample, compensated, same stamp and frame'),
        Endpoint('~/estimates', 'diagnostic_msgs/msg/DiagnosticArray',
                 'every CONTRACT 4 value and its sigma, transient local'),
        Endpoint('~/<group>, ~/<group>_sigma', 'geometry_msgs/msg/Vector3Stamped',
                 'one pair per vector group (' + ', '.join(VECTOR_GROUPS) + '), transient '
                 'local'),
        Endpoint('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
                 'input rates, rejections by reason, estimator health; OK/WARN/ERROR/STALE')),
    services=(
        Endpoint('~/save_calibration', 'std_srvs/srv/Trigger',
                 'write the last good estimate to output_file (CONTRACT 4, atomic)'),
        Endpoint('~/reset', 'std_srvs/srv/Trigger', 'restart the estimator (on the chain of '
                 'a robot_description change it did not apply)')))


def main(args: list[str] | None = None) -> int:
    """Console script ``calibration``."""
    sys.setswitchinterval(0.0005)  # the IMU thread gets the GIL within 0.5 ms (default 5 ms)
    return run_node(CalibrationNode, args, INTERFACE)


if __name__ == '__main__':
    sys.exit(main())
