"""``modulation`` node: live rotation demodulation (MEMS paper; METHODS.md section 3).

Subscribes ``imu/data_raw`` (sensor-data QoS) and ``joint_states``; publishes
``imu/data_body``: the IMU stream in the platform-base frame b with the modulated X/Y biases
removed and the platform rate taken out of the gyro. ``mode:=continuous`` (default) outputs
every sample (causal de-rotation, full IMU rate); ``one | two | four`` the paper's
control-point variants (1, 2 or 4 outputs per revolution). All arithmetic is
:class:`~imu_calib_ros.core.methods.modulation.StreamingDemodulator` (equal to the offline
``imu-calib modulate`` with causal bias); output starts after the first full revolution.

Run: ``modulation --ros-args -p fixture:=three_axis -p joint:=inner [-p mode:=four]``. The
fixture is any the calibration node takes (a CONTRACT 2 YAML, a ``.urdf`` with ``base_link``
and ``imu_link``, or ``robot_description``: the URDF on that topic), loaded by the same
:func:`~imu_calib_ros.nodes.fixture_source.load_node_fixture`.
Spun by :func:`~imu_calib_ros.nodes.common.run_node` with a SingleThreadedExecutor: under
rclpy's experimental EventsExecutor (this Jazzy build) the node matched its topics but no
callback ever ran and SIGINT was ignored (found with a faulthandler stack dump: the
process sat in the C++ spin at ~50 % CPU), hence no output and no counters log. The IMU
subscription is best effort (sensor-data QoS) unless overridden with
``-p qos_overrides./imu/data_raw.subscription.reliability:=reliable`` (lossless with a
reliable publisher: a best-effort reader loses the samples sent while discovery is still
completing, seen as ~100 of 700 missing at the start of a burst).
"""
from __future__ import annotations

import sys
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Imu, JointState

from msg_adapters.convert import imu_msg_from_sample, imu_sample_from_msg, joint_sample_from_msg

from ..core.errors import ConfigError
from ..core.methods.modulation import MODES, StreamingDemodulator
from ..core.reorder import ReorderBuffer
from .common import (Endpoint, NodeInterface, declare_config, finite, log_at_exit,
                     quiet_publisher, reliable_qos, run_node, sensor_qos)
from .fixture_source import UrdfFixtureFields, load_node_fixture

NODE_NAME = 'modulation'


@dataclass(frozen=True)
class ModulationConfig(UrdfFixtureFields):  # + the URDF parameters
    """Parameters of the modulation node."""

    fixture: str = field(default='', metadata={
        'doc': 'fixture file (CONTRACT 2 YAML or a .urdf), shipped fixture name, or '
               'robot_description (the URDF on that topic): the modulation joint axis',
        'required': True})
    joint: str = field(default='', metadata={
        'doc': 'modulation joint name; empty = the innermost joint'})
    mode: str = field(default='continuous', metadata={
        'doc': 'continuous (full rate) or one | two | four (control points per revolution)'})
    frame_id: str = field(default='', metadata={
        'doc': 'output header.frame_id; empty = input frame + "_body"'})
    queue_depth: int = field(default=100, metadata={
        'doc': 'subscriber queue depth', 'min': 1, 'max': 100000})
    max_pending: int = field(default=2000, metadata={
        'doc': 'IMU samples held while waiting for joint states', 'min': 1, 'max': 1000000})
    reorder_window_s: float = field(default=0.005, metadata={
        'doc': 'longest wait [s] of a raw IMU sample to put the stream back in header-stamp'
               ' order (transport jitter); a later one counts as out_of_order; 0 = no wait',
        'min': 0.0, 'max': 1.0})
    min_coverage: float = field(default=0.75, metadata={
        'doc': 'withhold (count, not publish) an output whose revolution window the samples '
               'present cover less than this fraction of (lost samples); the bias fitted '
               'over a window with smaller holes is exact for a constant body vector',
        'min': 0.0, 'max': 1.0})
    diagnostics_rate_hz: float = field(default=1.0, metadata={
        'doc': 'rate of /diagnostics [Hz]', 'min': 0.01, 'max': 100.0})
    stale_timeout_s: float = field(default=2.0, metadata={
        'doc': 'no raw IMU for this long [s, wall clock] = STALE', 'min': 0.01})


class ModulationNode(Node):
    """Thin shell: messages in, StreamingDemodulator, messages out."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        cfg: ModulationConfig = declare_config(self, ModulationConfig)
        self.config = cfg
        if cfg.mode != 'continuous' and cfg.mode not in MODES:
            raise ConfigError(f'mode must be continuous, one, two or four, got {cfg.mode!r}',
                              'ROS parameters', 'mode')
        # a file, a shipped name, or the robot_description topic (waits; one line either way)
        fx = load_node_fixture(self, cfg)
        joint = cfg.joint or fx.joint_names[-1]
        if joint not in fx.joint_names:
            raise ConfigError(f'joint {joint!r} is not a fixture joint {list(fx.joint_names)}',
                              'ROS parameters', 'joint')
        self._fixture, self._k = fx, fx.joint_index(joint)
        self._joint = joint
        self.demod: StreamingDemodulator | None = None  # axis needs the other joints' angles
        self.rejected = {'non_finite': 0}
        self._early: deque = deque(maxlen=cfg.max_pending)
        self._reorder: ReorderBuffer[Any] = ReorderBuffer(cfg.reorder_window_s)
        self._pub = self.create_publisher(Imu, 'imu/data_body', reliable_qos(cfg.queue_depth))
        # sensor-data QoS matches any IMU driver; a lost sample shortens the revolution mean
        # (counted as a gap), so with a reliable driver make it lossless with the standard
        # override -p qos_overrides./imu/data_raw.subscription.reliability:=reliable
        self._sub_imu = self.create_subscription(
            Imu, 'imu/data_raw', self._on_imu, sensor_qos(cfg.queue_depth),
            qos_overriding_options=QoSOverridingOptions.with_default_policies())
        self._sub_joints = self.create_subscription(JointState, 'joint_states',
                                                    self._on_joints,
                                                    reliable_qos(cfg.queue_depth))
        if cfg.reorder_window_s > 0:  # what waited its window when the stream pauses
            self.create_timer(0.05, self._release_held)
        self._diag_pub = quiet_publisher(self, DiagnosticArray, '/diagnostics', reliable_qos())
        self.create_timer(1.0 / cfg.diagnostics_rate_hz, self._on_diag_timer)
        self._last_rx: float | None = None  # monotonic time of the last raw IMU message
        self._diag_mark: dict[str, int] = {}  # loss counters at the last diagnostics
        self.get_logger().info(f'demodulating joint {joint!r}, mode {cfg.mode}')

    def _on_joints(self, msg: JointState) -> None:
        s = joint_sample_from_msg(msg)
        if self.demod is None:
            if not all(n in s.names for n in self._fixture.joint_names):
                return
            q = np.array([s.positions_rad[s.names.index(n)] for n in self._fixture.joint_names])
            q[self._k] = 0.0
            axis = self._fixture.joint_axes_imu(q)[self._k]
            self.demod = StreamingDemodulator(axis, self._joint, self.config.mode,
                                              self.config.max_pending,
                                              min_coverage=self.config.min_coverage)
            # IMU samples that came before the first joint state (the two topics are not
            # ordered against each other): feed them first, as offline
            early, self._early = self._early, deque()
            for e in early:
                self._publish(self.demod.push_imu(e))
        self._publish(self.demod.push_joint(s))

    def _on_imu(self, msg: Imu) -> None:
        self._last_rx = time.monotonic()
        s = imu_sample_from_msg(msg)
        if not finite(s.gyro_rad_s, s.accel_m_s2):
            self.rejected['non_finite'] += 1
            self.get_logger().warn('dropped non-finite IMU sample', throttle_duration_sec=5.0)
            return
        for _, ordered in self._reorder.push(s.stamp_ns, s, time.monotonic_ns()):
            self._on_ordered_imu(ordered)

    def _release_held(self) -> None:
        for _, s in self._reorder.release(time.monotonic_ns()):
            self._on_ordered_imu(s)

    def _on_ordered_imu(self, s: Any) -> None:
        """An IMU sample in stamp order (or too late for the reorder window)."""
        if self.demod is not None:
            self._publish(self.demod.push_imu(s))
        else:
            self._early.append(s)

    #: counters whose growth means outputs missing or wrong without it: WARN for that period
    LOSS_KEYS = ('lost_imu', 'withheld_low_coverage', 'dropped_no_joint_states',
                 'out_of_order')

    def _on_diag_timer(self) -> None:
        """``/diagnostics``: every counter (the demodulator's, rejections, reordering); STALE
        without raw IMU for ``stale_timeout_s``, WARN while samples are lost or outputs
        withheld (in the last period), else OK."""
        c = dict(self.demod.counters) if self.demod is not None else {}
        values = {k: str(v) for k, v in c.items()}
        values.update({f'rejected.{k}': str(v) for k, v in self.rejected.items() if v})
        values.update({f'reorder.{k}': str(v) for k, v in self._reorder.stats.as_dict().items()
                       if v})
        new = {k: c.get(k, 0) - self._diag_mark.get(k, 0) for k in self.LOSS_KEYS}
        self._diag_mark = {k: c.get(k, 0) for k in self.LOSS_KEYS}
        if self._last_rx is None or time.monotonic() - self._last_rx > \
                self.config.stale_timeout_s:
            level, message = DiagnosticStatus.STALE, 'no raw IMU data'
        elif any(new.values()):
            level = DiagnosticStatus.WARN
            message = (f'{new["lost_imu"]} raw samples lost, {new["withheld_low_coverage"]} '
                       f'outputs withheld (revolution covered < {self.config.min_coverage:g})'
                       f' in the last period; {c.get("fitted_after_loss", 0)} outputs fitted '
                       'over a window with a loss')
        elif self.demod is None:
            level, message = DiagnosticStatus.OK, 'waiting for joint states'
        else:
            level, message = DiagnosticStatus.OK, 'demodulating'
        status = DiagnosticStatus(name=f'{self.get_name()}: rotation demodulation',
                                  hardware_id=self.config.frame_id or self._joint,
                                  level=level, message=message)
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(arr)

    def destroy_node(self) -> None:
        """Log the counters, then stop."""
        counters = self.demod.counters if self.demod is not None else {}
        log_at_exit(self, f'counters: {counters}, rejected: {self.rejected}, reorder: '
                          f'{self._reorder.stats.as_dict()}')
        super().destroy_node()

    def _publish(self, samples: list) -> None:
        for s in samples:
            fid = self.config.frame_id or f'{s.frame_id}_body'
            self._pub.publish(imu_msg_from_sample(s, Imu, frame_id=fid))


INTERFACE = NodeInterface(
    name=NODE_NAME, config=ModulationConfig,
    summary='Live rotation demodulation: the IMU stream of a unit turning on one joint, in the '
            'platform-base frame with the modulated X/Y biases removed and the platform rate '
            'taken out of the gyro (as imu-calib modulate --causal).',
    subscribes=(
        Endpoint('imu/data_raw', 'sensor_msgs/msg/Imu', 'raw IMU; sensor-data QoS (override: '
                 '-p qos_overrides./imu/data_raw.subscription.reliability:=reliable)'),
        Endpoint('joint_states', 'sensor_msgs/msg/JointState', 'fixture joint positions'),
        Endpoint('robot_description', 'std_msgs/msg/String',
                 'with fixture:=robot_description only: the URDF, once at start (reliable, '
                 'transient local)')),
    publishes=(Endpoint('imu/data_body', 'sensor_msgs/msg/Imu',
                        'body-frame stream (continuous, or 1/2/4 points per revolution); '
                        'outputs over a revolution with too much lost are withheld'),
               Endpoint('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
                        'counters (lost, withheld, fitted after a loss); OK/WARN/STALE')))


def main(args: list[str] | None = None) -> int:
    """Console script ``modulation``."""
    return run_node(ModulationNode, args, INTERFACE)


if __name__ == '__main__':
    sys.exit(main())
