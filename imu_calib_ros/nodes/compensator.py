"""``compensator`` node: republish a raw IMU corrected with a calibration file (no estimator).

The robot-side deployment after a calibration: subscribes ``imu/data_raw`` (sensor-data
QoS), publishes ``imu/data_corrected`` with the same stamp and frame, values from
:class:`~imu_calib_ros.core.stream_compensation.StreamCompensation` in the IMU input thread
(:class:`~imu_calib_ros.nodes.input_thread.InputThread`, the code the calibration node uses),
covariances from the calibration's sigmas plus the sensor noise, and
``orientation_covariance[0] = -1`` (REP-145). A raw sample in another frame than the
calibration's, or with a non-finite value, is dropped, counted and reported.

Run: ``compensator --ros-args -p calibration_file:=calib.yaml [-p imu_grade:=NAME]``.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import Imu

from msg_adapters.convert import imu_cdr, imu_fields_from_cdr

from ..core.calibration import CalibrationResult
from ..core.errors import ConfigError, ImuCalibError
from ..core.reorder import ReorderBuffer
from ..core.stream_compensation import StreamCompensation
from .common import (Endpoint, NodeInterface, declare_config, diag9, finite3, quiet_publisher,
                     reliable_qos, run_node, sensor_qos)
from .input_thread import InputThread

NODE_NAME = 'compensator'


@dataclass(frozen=True)
class CompensatorConfig:
    """Parameters of the compensator node (``config/compensator.yaml``)."""

    calibration_file: str = field(default='', metadata={
        'doc': 'calibration file (CONTRACT 4) to apply', 'required': True})
    frame_id: str = field(default='', metadata={
        'doc': 'expected IMU frame; empty = the calibration file\'s frame_id'})
    imu_grade: str = field(default='', metadata={
        'doc': 'IMU grade (name in config/imus or path) giving the noise densities; '
               'empty = use gyro_noise_rad_s_rt_hz / accel_noise_m_s2_rt_hz'})
    gyro_noise_rad_s_rt_hz: float = field(default=0.0, metadata={
        'doc': 'gyro white noise (ARW) [rad/s/sqrt(Hz)] when imu_grade is empty', 'min': 0.0})
    accel_noise_m_s2_rt_hz: float = field(default=0.0, metadata={
        'doc': 'accelerometer white noise (VRW) [m/s^2/sqrt(Hz)] when imu_grade is empty',
        'min': 0.0})
    imu_rate_hz: float = field(default=0.0, metadata={
        'doc': 'nominal IMU rate [Hz] (gap threshold 1.5 periods, noise of the mean); 0 = '
               'detect from the data (median of the first 20 stamp intervals)',
        'min': 0.0, 'max': 100000.0})
    reorder_window_s: float = field(default=0.005, metadata={
        'doc': 'longest wait [s] of a raw IMU sample to put the stream back in header-stamp'
               ' order (transport jitter); a sample later than that is dropped as'
               ' out_of_order (reorder.late); 0 = no wait', 'min': 0.0, 'max': 1.0})
    queue_depth: int = field(default=500, metadata={
        'doc': 'queue depth of the raw input (sensor-data QoS, best effort) and of the '
               'corrected output (reliable, keep last)', 'min': 1,
        'max': 100000})
    diagnostics_rate_hz: float = field(default=1.0, metadata={
        'doc': 'rate of /diagnostics [Hz]; 0 = off', 'min': 0.0, 'max': 100.0})


def noise_densities(grade_name: str, gyro: float, accel: float) -> tuple[float, float]:
    """White-noise densities from an IMU grade file, or the given values if no grade."""
    if not grade_name:
        return gyro, accel
    from ..core.imu_grade import load_grade
    grade = load_grade(grade_name)
    return grade.gyro_noise_rad_s_rt_hz, grade.accel_noise_m_s2_rt_hz


class CompensatorNode(Node):
    """Applies a fixed calibration to every raw IMU sample."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config: CompensatorConfig = declare_config(self, CompensatorConfig)
        cfg = self.config
        self.calibration = CalibrationResult.load(cfg.calibration_file)
        if cfg.frame_id and cfg.frame_id != self.calibration.frame_id:
            raise ConfigError(f'calibration is for frame "{self.calibration.frame_id}", '
                              f'but frame_id parameter is "{cfg.frame_id}"',
                              cfg.calibration_file, 'imu_calibration.frame_id')
        gyro_n, accel_n = noise_densities(cfg.imu_grade, cfg.gyro_noise_rad_s_rt_hz,
                                          cfg.accel_noise_m_s2_rt_hz)
        self.compensation = StreamCompensation(
            self.calibration, gyro_n, accel_n,
            1.0 / cfg.imu_rate_hz if cfg.imu_rate_hz > 0 else 0.0)
        self._rate_known = False
        self.rejected: dict[str, int] = {'frame_id': 0, 'non_finite': 0, 'out_of_order': 0,
                                         'compensation_non_finite': 0, 'bad_message': 0}
        self.published = 0
        self._last_stamp_ns: int | None = None
        self._reorder: ReorderBuffer[tuple[str, Any, Any]] = ReorderBuffer(cfg.reorder_window_s)
        self._pub = self.create_publisher(Imu, 'imu/data_corrected',
                                          reliable_qos(cfg.queue_depth))
        self._sub = InputThread(self, Imu, 'imu/data_raw', self._on_imu,
                                sensor_qos(cfg.queue_depth), raw=True, idle=self._release_held)
        if cfg.diagnostics_rate_hz > 0:
            self._diag_pub = quiet_publisher(self, DiagnosticArray, '/diagnostics', 10)
            self.create_timer(1.0 / cfg.diagnostics_rate_hz, self._on_diag_timer)
        self.get_logger().info(f'applying {cfg.calibration_file} (frame '
                               f'"{self.calibration.frame_id}")')

    def _reject(self, reason: str, detail: str) -> None:
        self.rejected[reason] += 1
        self.get_logger().warn(f'dropped raw IMU sample: {detail}', throttle_duration_sec=5.0)

    def _on_imu(self, data: bytes) -> None:
        """One raw IMU message (serialised bytes; runs in the IMU input thread), checked, then
        held by the reorder window until it is in stamp order (:meth:`_on_ordered_imu`)."""
        try:
            ns, frame, gyro, accel = imu_fields_from_cdr(data)
        except ImuCalibError:
            return self._reject('bad_message', 'not a CDR sensor_msgs/Imu')
        if frame != self.calibration.frame_id:
            return self._reject('frame_id', f'frame "{frame}" is not the calibration\'s '
                                            f'"{self.calibration.frame_id}"')
        if not finite3(gyro, accel):
            return self._reject('non_finite', 'non-finite value')
        for ns, (frame, gyro, accel) in self._reorder.push(ns, (frame, gyro, accel),
                                                           time.monotonic_ns()):
            self._on_ordered_imu(ns, frame, gyro, accel)

    def _release_held(self) -> float | None:
        """IMU input thread, after each burst: the samples whose reorder wait is over (the
        stream paused); returns the seconds until the next one is due."""
        for ns, (frame, gyro, accel) in self._reorder.release(time.monotonic_ns()):
            self._on_ordered_imu(ns, frame, gyro, accel)
        due = self._reorder.due_ns()
        return None if due is None else (due - time.monotonic_ns()) * 1e-9

    def _on_ordered_imu(self, ns: int, frame: str, gyro: Any, accel: Any) -> None:
        """A raw IMU sample in stamp order, or too late for the window (dropped here)."""
        if self._last_stamp_ns is not None and ns <= self._last_stamp_ns:
            return self._reject('out_of_order', 'stamp not after the previous one')
        self._last_stamp_ns = ns
        omega, f, gvar, avar = self.compensation(ns, gyro, accel)
        if not finite3(omega, f, gvar, avar):  # never a NaN out of a publisher
            return self._reject('compensation_non_finite', 'compensation not finite')
        self._pub.publish(imu_cdr(ns, frame, omega, f, diag9(gvar), diag9(avar)))
        self.published += 1
        if not self._rate_known and self.compensation.measured_period_s is not None:
            self._rate_known = True
            if self.compensation.rate_mismatch:
                self.get_logger().warn(self.compensation.rate_mismatch)

    def _on_diag_timer(self) -> None:
        status = DiagnosticStatus(name=f'{self.get_name()}: IMU compensation',
                                  hardware_id=self.calibration.frame_id)
        bad = sum(self.rejected.values())
        comp = self.compensation
        status.level = DiagnosticStatus.OK if bad == 0 and not comp.rate_mismatch \
            else DiagnosticStatus.WARN
        status.message = comp.rate_mismatch or ('OK' if bad == 0 else f'{bad} samples dropped')
        status.values = [KeyValue(key='published', value=str(self.published)),
                         KeyValue(key='received', value=str(self._sub.messages))] + [
            KeyValue(key=f'rejected.{k}', value=str(v)) for k, v in self.rejected.items()] + [
            KeyValue(key=f'reorder.{k}', value=str(v))
            for k, v in self._reorder.stats.as_dict().items()]
        if comp.measured_period_s is not None:
            status.values.append(KeyValue(key='imu_rate_measured_hz',
                                          value=f'{1.0 / comp.measured_period_s:.6g}'))
        if comp.rate_mismatch:
            status.values.append(KeyValue(key='imu_rate_warning', value=comp.rate_mismatch))
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(arr)

    def destroy_node(self) -> None:
        """Stop the input thread first: a thread still waiting in rcl when the node and
        the context go away aborted the process (SIGABRT, exit 134) on SIGINT/SIGTERM."""
        self._sub.stop()
        super().destroy_node()


INTERFACE = NodeInterface(
    name=NODE_NAME, config=CompensatorConfig, params_file='config/compensator.yaml',
    summary='Robot-side deployment of a calibration: every raw IMU sample is corrected with '
            'a calibration file (CONTRACT 4) and republished, with covariances from its sigmas '
            'and the sensor noise. No estimator.',
    subscribes=(Endpoint('imu/data_raw', 'sensor_msgs/msg/Imu',
                         'raw IMU, interval means (CONTRACT 1); sensor-data QoS'),),
    publishes=(
        Endpoint('imu/data_corrected', 'sensor_msgs/msg/Imu',
                 'compensated, same stamp and frame, orientation_covariance[0] = -1'),
        Endpoint('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
                 'published and dropped samples by reason, measured IMU rate')))


def main(args: list[str] | None = None) -> int:
    """Console script ``compensator``."""
    return run_node(CompensatorNode, args, INTERFACE)


if __name__ == '__main__':
    sys.exit(main())
