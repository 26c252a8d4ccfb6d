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

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import Imu

from msg_adapters.convert import imu_fields_from_cdr

from ..core.calibration import CalibrationResult
from ..core.errors import ConfigError, ImuCalibError
from ..core.imu_stream import ImuStream, Step
from ..core.stream_compensation import StreamCompensation
from .common import (Endpoint, NodeInterface, declare_config, publish_corrected,
                     quiet_publisher, reliable_qos, run_node, sensor_qos)
from .input_thread import InputThread

NODE_NAME = 'compensator'

#: the log line's detail of a dropped raw sample, by reason (ImuStream's)
_DETAIL = {'bad_message': 'not a CDR sensor_msgs/Imu', 'non_finite': 'non-finite value',
           'out_of_order': 'stamp not after the previous one',
           'compensation_non_finite': 'compensation not finite'}


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
        # the calibration node's per-sample code; only the calibration's frame is accepted
        self.stream = ImuStream(self.compensation, self.calibration.frame_id,
                                cfg.reorder_window_s)
        self.published = 0
        self._pub = self.create_publisher(Imu, 'imu/data_corrected',
                                          reliable_qos(cfg.queue_depth))
        self._sub = InputThread(self, Imu, 'imu/data_raw', self._on_imu,
                                sensor_qos(cfg.queue_depth), raw=True, idle=self._release_held)
        if cfg.diagnostics_rate_hz > 0:
            self._diag_pub = quiet_publisher(self, DiagnosticArray, '/diagnostics', 10)
            self.create_timer(1.0 / cfg.diagnostics_rate_hz, self._on_diag_timer)
        self.get_logger().info(f'applying {cfg.calibration_file} (frame '
                               f'"{self.calibration.frame_id}")')

    @property
    def rejected(self) -> dict[str, int]:
        """Dropped raw samples by reason."""
        r = self.stream.rejected
        return {k: r[k] for k in ('frame_id', 'non_finite', 'out_of_order',
                                  'compensation_non_finite', 'bad_message')}

    def _reject(self, detail: str) -> None:
        self.get_logger().warn(f'dropped raw IMU sample: {detail}', throttle_duration_sec=5.0)

    def _on_imu(self, data: bytes) -> None:
        """One raw IMU message (serialised bytes; runs in the IMU input thread): decoded, then
        :class:`ImuStream` (checks, reorder window, compensation); see :meth:`_take`."""
        try:
            ns, frame, gyro, accel = imu_fields_from_cdr(data)
        except ImuCalibError:
            return self._take(self.stream.reject('bad_message'))
        self._take(self.stream.push(ns, frame, gyro, accel, time.monotonic_ns()))

    def _release_held(self) -> float | None:
        """IMU input thread, after each burst: the samples whose reorder wait is over (the
        stream paused); returns the seconds until the next one is due."""
        self._take(self.stream.release(time.monotonic_ns()))
        return self.stream.seconds_to_due(time.monotonic_ns())

    def _take(self, step: Step) -> None:
        """Publish the compensated samples; log the dropped ones (throttled)."""
        for r in step.rejected:
            self._reject(f'frame "{r.frame_id}" is not the calibration\'s '
                         f'"{self.calibration.frame_id}"' if r.reason == 'frame_id' else
                         _DETAIL[r.reason])
        for c in step.accepted:
            if publish_corrected(self._pub, c):  # else counted as compensation_non_finite
                self.published += 1
        if step.rate_known and self.compensation.rate_mismatch:
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
            for k, v in self.stream.reorder.stats.as_dict().items()]
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
