"""``calibration`` node: live turntable calibration with estimates and a corrected IMU stream.

Topics (relative names, remappable):

- subscribes ``imu/data_raw`` (``sensor_msgs/Imu``) and ``joint_states``
  (``sensor_msgs/JointState``) with sensor-data QoS (best effort);
- publishes ``imu/data_corrected`` (``sensor_msgs/Imu``, same stamp and frame) for every
  accepted raw sample, compensated with the current estimate by
  :class:`~imu_calib_ros.nodes.common.StreamCompensation` (the compensator node's code),
  covariances from the estimate's sigmas plus the sensor noise,
  ``orientation_covariance[0] = -1`` (REP-145);
- publishes, at ``estimate_rate_hz`` and transient-local (late subscribers get the latest),
  ``~/estimates`` (``diagnostic_msgs/DiagnosticArray``: every CONTRACT 4 value and its sigma
  as key/values) and one ``geometry_msgs/Vector3Stamped`` per vector group, ``~/<group>``
  and ``~/<group>_sigma`` (see :data:`VECTOR_GROUPS`);
- publishes ``/diagnostics``: input rates, rejected samples by reason, the estimator's
  health (NIS, covariance), level OK/WARN/ERROR/STALE.

Services (``std_srvs/Trigger``): ``~/save_calibration`` writes the CONTRACT 4 file
(``output_file``) atomically with :meth:`CalibrationResult.save`; ``~/reset`` restarts the
estimator. Parameters: :class:`CalibrationNodeConfig`, the estimator's under ``estimator.``
(the :class:`EstimatorConfig` the CLI uses). ``use_sim_time`` works: timers, staleness and
diagnostics follow ``/clock``; the estimator itself only sees message stamps.

Threads: the IMU and joint callbacks only check and queue; a
:class:`~imu_calib_ros.nodes.common.CompensationWorker` thread compensates and publishes the
corrected samples, and a timer feeds the queued samples to the estimator in stamp order, so
the corrected stream never waits for the filter. The node spins in a single-threaded
executor: measured on this 2-core machine, rclpy's
MultiThreadedExecutor lost most 800 Hz input to its own overhead, the single-threaded one none.
"""
from __future__ import annotations

import collections
import math
import sys
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Vector3Stamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState
from std_srvs.srv import Trigger

from ..core.errors import ImuCalibError
from ..core.estimator.config import EstimatorConfig
from ..core.types import ImuBatch, ImuSample, JointSample
from ..msg_adapters.convert import (ImuCovariances, imu_msg_from_sample, imu_sample_from_msg,
                                    joint_sample_from_msg)
from .common import (CompensationWorker, StreamCompensation, declare_config, diag9, finite,
                     latched_qos,
                     reliable_qos, run_node, sensor_qos, stamp_msg)

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


@dataclass(frozen=True)
class CalibrationNodeConfig:
    """Parameters of the calibration node (``config/calibration_node.yaml``)."""

    fixture: str = field(default='three_axis', metadata={
        'doc': 'fixture file (CONTRACT 2) or shipped fixture name'})
    imu_grade: str = field(default='nav_grade', metadata={
        'doc': 'IMU grade (config/imus name or path): noise and prior sigmas'})
    frame_id: str = field(default='', metadata={
        'doc': 'IMU frame to accept; empty = the first sample\'s frame'})
    imu_rate_hz: float = field(default=200.0, metadata={
        'doc': 'nominal IMU rate [Hz] (gaps, noise of the mean, rate diagnostics)',
        'min': 1.0, 'max': 100000.0})
    output_file: str = field(default='imu_calibration.yaml', metadata={
        'doc': 'where ~/save_calibration writes the calibration (CONTRACT 4)'})
    estimate_rate_hz: float = field(default=1.0, metadata={
        'doc': 'rate of ~/estimates and the per-group Vector3Stamped [Hz]', 'min': 0.01,
        'max': 100.0})
    diagnostics_rate_hz: float = field(default=1.0, metadata={
        'doc': 'rate of /diagnostics [Hz]', 'min': 0.01, 'max': 100.0})
    filter_rate_hz: float = field(default=20.0, metadata={
        'doc': 'rate at which queued samples are fed to the estimator [Hz]', 'min': 1.0,
        'max': 1000.0})
    stale_timeout_s: float = field(default=2.0, metadata={
        'doc': 'no raw IMU for this long [s, node clock] = STALE', 'min': 0.01})
    warn_rejected_fraction: float = field(default=0.01, metadata={
        'doc': 'WARN when more than this fraction of the inputs was rejected', 'min': 0.0,
        'max': 1.0})
    queue_depth: int = field(default=2000, metadata={
        'doc': 'subscriber queue depth (sensor-data QoS, best effort)', 'min': 1,
        'max': 100000})
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig, metadata={
        'doc': 'the streaming estimator (same keys as config/estimator.yaml)'})


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
        from ..core.config import resolve_config_file
        from ..core.estimator import CalibrationEstimator
        from ..core.fixture import Fixture
        from ..core.imu_grade import load_grade
        self.fixture = Fixture.from_yaml(resolve_config_file(cfg.fixture, 'fixtures'))
        self.grade = load_grade(cfg.imu_grade)
        self.estimator = CalibrationEstimator(self.fixture, self.grade, cfg.estimator)
        self.frame_id = cfg.frame_id
        self.compensation = StreamCompensation(
            self.estimator.estimate(), self.grade.gyro_noise_rad_s_rt_hz,
            self.grade.accel_noise_m_s2_rt_hz, 1.0 / cfg.imu_rate_hz)
        self.worker = CompensationWorker(self.compensation, self._publish_batch)
        # queued for the estimator thread; deque append/popleft are thread-safe
        self._queue: collections.deque[ImuSample | JointSample] = collections.deque()
        self._lock = threading.Lock()  # counters shared between the two callback groups
        self.counts = {'imu': 0, 'joint': 0, 'published': 0}
        self.rejected = {'frame_id': 0, 'non_finite': 0, 'out_of_order': 0, 'bad_message': 0,
                         'estimator_error': 0}
        self._rate_mark = (0, 0, None)  # (imu count, joint count, node time) at last diag
        self._last_imu_ns: int | None = None
        self._last_rx = None  # node clock time of the last raw IMU
        self._last_pushed_ns = 0
        self._result = None
        self._estimator_error = ''
        io = MutuallyExclusiveCallbackGroup()
        work = MutuallyExclusiveCallbackGroup()
        self._pub = self.create_publisher(Imu, 'imu/data_corrected',
                                          reliable_qos(cfg.queue_depth))
        self.create_subscription(Imu, 'imu/data_raw', self._on_imu, sensor_qos(cfg.queue_depth),
                                 callback_group=io)
        self.create_subscription(JointState, 'joint_states', self._on_joints,
                                 sensor_qos(cfg.queue_depth), callback_group=io)
        self._est_pub = self.create_publisher(DiagnosticArray, '~/estimates', latched_qos())
        self._vec_pubs = {name: (self.create_publisher(Vector3Stamped, f'~/{name}',
                                                       latched_qos()),
                                 self.create_publisher(Vector3Stamped, f'~/{name}_sigma',
                                                       latched_qos()))
                          for name in VECTOR_GROUPS}
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', reliable_qos())
        self.create_timer(1.0 / cfg.filter_rate_hz, self._on_filter_timer, callback_group=work)
        self.create_timer(1.0 / cfg.estimate_rate_hz, self._on_estimate_timer,
                          callback_group=work)
        self.create_timer(1.0 / cfg.diagnostics_rate_hz, self._on_diag_timer,
                          callback_group=work)
        self.create_service(Trigger, '~/save_calibration', self._on_save, callback_group=work)
        self.create_service(Trigger, '~/reset', self._on_reset, callback_group=work)
        joints = ', '.join(self.fixture.joint_names)
        self.get_logger().info(f'calibrating on fixture {cfg.fixture} ({joints}), grade '
                               f'{self.grade.name}, output {cfg.output_file}')

    # ------------------------------------------------------------------ input callbacks
    def _reject(self, reason: str, detail: str) -> None:
        with self._lock:
            self.rejected[reason] += 1
        self.get_logger().warn(f'rejected input ({reason}): {detail}',
                               throttle_duration_sec=5.0)

    def _on_imu(self, msg: Imu) -> None:
        sample = imu_sample_from_msg(msg)
        self._last_rx = self.get_clock().now()
        if not self.frame_id:
            self.frame_id = sample.frame_id
        if sample.frame_id != self.frame_id:
            self._reject('frame_id', f'IMU frame "{sample.frame_id}" is not "{self.frame_id}"')
            return
        if not finite(sample.gyro_rad_s, sample.accel_m_s2):
            self._reject('non_finite', f'IMU sample at {sample.stamp_ns} ns')
            return
        if self._last_imu_ns is not None and sample.stamp_ns <= self._last_imu_ns:
            self._reject('out_of_order', f'IMU stamp {sample.stamp_ns} ns not after '
                                         f'{self._last_imu_ns} ns')
            return
        self._last_imu_ns = sample.stamp_ns
        self.worker.put(sample)
        self.counts['imu'] += 1
        self._queue.append(sample)

    def _publish_batch(self, samples: list[ImuSample], omega: Any, f: Any, gvar: Any,
                       avar: Any) -> None:
        ok = np.all(np.isfinite(omega), axis=1) & np.all(np.isfinite(f), axis=1) & \
            np.all(np.isfinite(gvar), axis=1) & np.all(np.isfinite(avar), axis=1)
        for k, s in enumerate(samples):
            if ok[k]:  # never a NaN out of a publisher
                self._pub.publish(imu_msg_from_sample(
                    ImuSample(s.stamp_ns, omega[k], f[k], s.frame_id), Imu,
                    ImuCovariances(diag9(gvar[k]), diag9(avar[k]))))
        self.counts['published'] += int(np.sum(ok))

    def destroy_node(self) -> None:
        """Stop the compensation thread, then the node."""
        self.worker.stop()
        super().destroy_node()

    def _on_joints(self, msg: JointState) -> None:
        try:
            sample = joint_sample_from_msg(msg)
        except ImuCalibError as exc:
            self._reject('bad_message', str(exc))
            return
        if not finite(sample.positions_rad):
            self._reject('non_finite', f'joint state at {sample.stamp_ns} ns')
            return
        self.counts['joint'] += 1
        self._queue.append(sample)

    # ------------------------------------------------------------------ estimator thread
    def _on_filter_timer(self) -> None:
        """Feed queued samples to the estimator in stamp order (IMU runs as batches)."""
        n = len(self._queue)
        if n == 0:
            return
        items = [self._queue.popleft() for _ in range(n)]
        items.sort(key=lambda s: s.stamp_ns)  # stable: joint before IMU at equal stamps kept
        run: list[ImuSample] = []
        try:
            for s in items:
                if isinstance(s, ImuSample):
                    run.append(s)
                    continue
                if run:
                    self.estimator.push_imu_batch(ImuBatch.from_samples(run))
                    run = []
                self.estimator.push_joint(s)
            if run:
                self.estimator.push_imu_batch(ImuBatch.from_samples(run))
            self._last_pushed_ns = items[-1].stamp_ns
        except ImuCalibError as exc:
            with self._lock:
                self.rejected['estimator_error'] += len(run) or 1
            self._estimator_error = str(exc)
            self.get_logger().error(f'estimator refused input: {exc}',
                                    throttle_duration_sec=5.0)

    def _current_estimate(self) -> Any:
        try:
            result = self.estimator.estimate()
        except ImuCalibError as exc:
            self._estimator_error = str(exc)
            return None
        self._result = result
        return result

    def _on_estimate_timer(self) -> None:
        result = self._current_estimate()
        if result is None:
            return
        if not (finite(result.errors.as_vector()) and finite(result.sigma.as_vector())):
            self._estimator_error = 'estimate is not finite'
            return
        self.compensation.update(result)
        stamp = stamp_msg(self._last_pushed_ns) if self._last_pushed_ns else \
            self.get_clock().now().to_msg()
        arr = DiagnosticArray()
        arr.header.stamp = stamp
        status = DiagnosticStatus(name=f'{self.get_name()}: calibration estimate',
                                  hardware_id=self.frame_id, level=DiagnosticStatus.OK,
                                  message='one-sigma values under sigma.*, SI units')
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

    def _on_diag_timer(self) -> None:
        now = self.get_clock().now()
        with self._lock:
            rejected = dict(self.rejected)
        imu_n, joint_n = self.counts['imu'], self.counts['joint']
        last_imu, last_joint, last_t = self._rate_mark
        dt = (now - last_t).nanoseconds * 1e-9 if last_t is not None else 0.0
        imu_rate = (imu_n - last_imu) / dt if dt > 0 else math.nan
        joint_rate = (joint_n - last_joint) / dt if dt > 0 else math.nan
        self._rate_mark = (imu_n, joint_n, now)
        try:
            health = dict(self.estimator.health())
        except Exception as exc:  # noqa: BLE001 - report, never crash the diagnostics
            health = {'health_error': str(exc)}
        values = {'imu_rate_hz': f'{imu_rate:.1f}', 'joint_rate_hz': f'{joint_rate:.1f}',
                  'imu_received': str(imu_n), 'joint_received': str(joint_n),
                  'corrected_published': str(self.counts['published']),
                  'queued': str(len(self._queue))}
        values.update({f'rejected.{k}': str(v) for k, v in rejected.items()})
        values.update(_health_values(health))
        level, message = self._level(now, imu_n, joint_n, rejected, health)
        status = DiagnosticStatus(name=f'{self.get_name()}: IMU calibration', level=level,
                                  message=message, hardware_id=self.frame_id)
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = now.to_msg()
        self._diag_pub.publish(arr)

    def _level(self, now: Any, imu_n: int, joint_n: int, rejected: dict[str, int],
               health: dict[str, Any]) -> tuple[bytes, str]:
        if self._last_rx is None or (now - self._last_rx).nanoseconds * 1e-9 > \
                self.config.stale_timeout_s:
            return DiagnosticStatus.STALE, 'no raw IMU data'
        if self._estimator_error:
            return DiagnosticStatus.ERROR, self._estimator_error
        if str(health.get('status', '')).upper() in ('ERROR', 'DIVERGED'):
            return DiagnosticStatus.ERROR, str(health.get('message', 'estimator error'))
        bad = sum(rejected.values()) + int(_as_number(health.get('rejected_total', 0)))
        total = max(imu_n + joint_n, 1)
        if bad / total > self.config.warn_rejected_fraction:
            return DiagnosticStatus.WARN, f'{bad} of {total} inputs rejected'
        if str(health.get('status', '')).upper() == 'WARN':
            return DiagnosticStatus.WARN, str(health.get('message', 'estimator warning'))
        return DiagnosticStatus.OK, 'calibrating'

    # ------------------------------------------------------------------ services
    def _on_save(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        self._on_filter_timer()  # everything received so far goes into the saved estimate
        result = self._current_estimate()
        if result is None:
            response.success = False
            response.message = f'no estimate yet: {self._estimator_error}'
            return response
        try:
            result.save(self.config.output_file)
        except (ImuCalibError, OSError) as exc:
            response.success = False
            response.message = f'cannot write {self.config.output_file}: {exc}'
            return response
        response.success = True
        response.message = self.config.output_file
        self.get_logger().info(f'calibration saved to {self.config.output_file}')
        return response

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        self._queue.clear()
        self.estimator.reset()
        with self._lock:
            self.rejected = {k: 0 for k in self.rejected}
        self._estimator_error = ''
        self._last_imu_ns = None
        self.worker.reset()
        result = self._current_estimate()
        if result is not None:
            self.compensation.update(result)
        response.success = True
        response.message = 'estimator reset'
        self.get_logger().info('estimator reset')
        return response


def _as_number(x: Any) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return 0.0


def _health_values(health: dict[str, Any], prefix: str = 'estimator.') -> dict[str, str]:
    """Flatten the estimator's health() into diagnostics key/values."""
    out: dict[str, str] = {}
    for k, v in health.items():
        if isinstance(v, dict):
            out.update(_health_values(v, f'{prefix}{k}.'))
        elif isinstance(v, float):
            out[f'{prefix}{k}'] = f'{v:.6g}'
        else:
            out[f'{prefix}{k}'] = str(v)
    return out


def main(args: list[str] | None = None) -> int:
    """Console script ``calibration``."""
    sys.setswitchinterval(0.0005)  # let the compensation thread preempt the filter quickly
    return run_node(CalibrationNode, args)


if __name__ == '__main__':
    sys.exit(main())
