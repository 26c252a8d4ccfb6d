"""``turntable_driver`` node: drive a real turntable through a motion plan.

Publishes the plan (the same ``config/plans`` files the simulator runs) as one
``trajectory_msgs/JointTrajectory`` on ``joint_trajectory`` (remap it to the table's
controller, e.g. ``/joint_trajectory_controller/joint_trajectory`` of a ros2_control joint
trajectory controller). The points carry position, velocity and acceleration sampled from the
plan's analytic profile at every breakpoint and every ``point_period_s`` in between, so a
quintic interpolation through them (the controller's, or ``turntable_sim``'s) reproduces the
plan's moves exactly and its oscillations to O(h^6); a second point 1 ms before each
breakpoint carries acceleration steps (an oscillation's start).

The profile starts where the table is: the driver waits for one ``joint_states`` message (up to
``wait_timeout_s``; else it starts from zero angles). It then follows ``joint_states`` until
the plan's end plus ``settle_s`` (node clock: ``use_sim_time`` works), logs the largest
tracking error, and exits with status 0 (1 if the error exceeded ``max_tracking_error_deg``
or no joint states came).

Run: ``turntable_driver --ros-args -p plan:=savage_srt -p fixture:=my_table.yaml
-r joint_trajectory:=/joint_trajectory_controller/joint_trajectory``.

A robot arm is driven the same way (issue 15): ``fixture`` a ``.urdf`` (with ``base_link``,
``imu_link``) or ``robot_description``; the trajectory carries the chain's joint names, and a
plan that would leave a URDF position or velocity limit from where the arm is is refused
before anything is sent (``core.plans.build_profile`` names the joint and the limit; exit
status 2).
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from builtin_interfaces.msg import Duration
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from msg_adapters.convert import joint_sample_from_msg, time_msg_from_ns

from ..core.errors import ImuCalibError, PlanError
from ..core.types import FloatArray
from .common import (Endpoint, NodeInterface, declare_config, reliable_qos, run_node,
                     sensor_qos)
from .fixture_source import UrdfFixtureFields, load_node_fixture

NODE_NAME = 'turntable_driver'


@dataclass(frozen=True)
class TurntableDriverConfig(UrdfFixtureFields):  # + the URDF parameters
    """Parameters of the turntable driver node."""

    fixture: str = field(default='', metadata={
        'doc': 'fixture file (CONTRACT 2 YAML or a .urdf) of the table or arm to drive, a '
               'shipped fixture name, or robot_description (the URDF on that topic): joint '
               'names, axes and limits',
        'required': "another table's joint names and axes would move this one"})
    plan: str = field(default='', metadata={
        'doc': 'motion plan (config/plans name, e.g. savage_srt, or path)',
        'required': 'this node moves hardware'})
    point_period_s: float = field(default=0.05, metadata={
        'doc': 'largest time between trajectory points [s]', 'min': 0.001, 'max': 10.0})
    lead_in_s: float = field(default=0.5, metadata={
        'doc': 'time before the first point [s] (the controller starts from rest)',
        'min': 0.0})
    wait_for_subscribers: int = field(default=1, metadata={
        'doc': 'wait for this many trajectory subscribers (the controller)', 'min': 0})
    wait_timeout_s: float = field(default=10.0, metadata={
        'doc': 'longest wait for subscribers and the first joint state [s wall]', 'min': 0.0})
    settle_s: float = field(default=1.0, metadata={
        'doc': 'time after the plan before checking and exiting [s]', 'min': 0.0})
    max_tracking_error_deg: float = field(default=1.0, metadata={
        'doc': 'exit status 1 if a joint state deviates more from the plan [deg]', 'min': 0.0})


#: Time of the extra point before each breakpoint [s].
BREAKPOINT_LEAD_S = 1e-3


def trajectory_from_profile(profile: Any, point_period_s: float,
                            lead_in_s: float = 0.0) -> JointTrajectory:
    """A JointTrajectory through ``profile``: breakpoints plus a grid of ``point_period_s``.

    Point ``k`` has ``time_from_start = lead_in_s + t_k`` and the profile's ``q, qd, qdd`` at
    ``t_k`` (rad, rad/s, rad/s^2). ``header.stamp`` is zero (start on receipt); the node
    stamps it with the time it measures the plan from.
    """
    t_end = float(profile.duration_s)
    n_grid = max(int(math.ceil(t_end / point_period_s)), 1)
    bp = np.asarray(profile.breakpoints_s, float)
    # a point just before each breakpoint too: the acceleration may step there (an
    # oscillation starts at -A w^2), which one C2 point cannot carry for both sides; across
    # the 1 ms between the two the quintic's error is ~ step x (1 ms)^2 / 60 (1e-7 rad),
    # where the grid alone left 2e-4 rad (A = 30 deg, T = 2 s, 0.05 s points)
    pre = bp[1:-1] - BREAKPOINT_LEAD_S
    must = np.union1d(bp, pre[pre > 0.0])
    grid = np.linspace(0.0, t_end, n_grid + 1)
    # grid points next to a breakpoint give way to it (never the breakpoint to them)
    near = np.abs(grid[:, None] - must[None, :]).min(axis=1) <= 0.5 * BREAKPOINT_LEAD_S
    t = np.union1d(must, grid[~near])
    keep = np.concatenate([[True], np.diff(t) > 0.5 * BREAKPOINT_LEAD_S])  # near-duplicates
    t = t[keep]
    if t[-1] < t_end:
        t = np.append(t, t_end)
    q, qd, qdd = profile.evaluate(t)
    msg = JointTrajectory()
    msg.joint_names = list(profile.joint_names)
    for k, tk in enumerate(t):
        ts = float(tk) + lead_in_s
        if ts <= 0.0:
            continue  # the start state is where the table is; not a point to reach
        msg.points.append(JointTrajectoryPoint(
            positions=q[k].tolist(), velocities=qd[k].tolist(), accelerations=qdd[k].tolist(),
            time_from_start=duration_from_seconds(ts)))
    return msg


def duration_from_seconds(t_s: float) -> Duration:
    """``builtin_interfaces/Duration`` of ``t_s`` >= 0 seconds, rounded to the nanosecond.

    Rounded once in integer nanoseconds, so a fraction that rounds up to a whole second
    carries into ``sec`` (2.9999999999 s -> 3 s 0 ns, not 2 s 0 ns).
    """
    sec, nanosec = divmod(int(round(t_s * 1e9)), 10**9)
    return Duration(sec=sec, nanosec=nanosec)


class TurntableDriverNode(Node):
    """Sends a plan as a JointTrajectory and watches the table follow it."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config: TurntableDriverConfig = declare_config(self, TurntableDriverConfig)
        from ..core.plans import load_plan
        self.fixture = load_node_fixture(self, self.config)
        self.plan = load_plan(self.config.plan)
        self._pub = self.create_publisher(JointTrajectory, 'joint_trajectory', reliable_qos())
        self.create_subscription(JointState, 'joint_states', self._on_joints, sensor_qos(50))
        self._q_now: FloatArray | None = None
        self._profile: Any = None
        self._t0_ns: int | None = None
        self.max_error_rad = 0.0
        self.states_seen = 0
        self.states_checked = 0  # joint states inside the plan's time window
        self.done = False
        self._wall_start = time.monotonic()
        self.status = 0
        self.create_timer(0.05, self._on_timer)

    def _on_joints(self, msg: JointState) -> None:
        sample = joint_sample_from_msg(msg)
        names = self.fixture.joint_names
        if not all(n in sample.names for n in names):
            return
        q = np.array([sample.positions_rad[sample.names.index(n)] for n in names])
        self._q_now = q
        if self._profile is None or self._t0_ns is None:
            return
        self.states_seen += 1
        t = (sample.stamp_ns - self._t0_ns) * 1e-9 - self.config.lead_in_s
        if 0.0 <= t <= self._profile.duration_s:
            self.states_checked += 1
            q_plan, _, _ = self._profile.evaluate(np.array([t]))
            err = np.angle(np.exp(1j * (q - q_plan[0])))  # wrapped or continuous both work
            self.max_error_rad = max(self.max_error_rad, float(np.max(np.abs(err))))

    def _on_timer(self) -> None:
        cfg = self.config
        if self._profile is None:
            waited = time.monotonic() - self._wall_start
            ready = (self._pub.get_subscription_count() >= cfg.wait_for_subscribers
                     and self._q_now is not None)
            if not ready and waited < cfg.wait_timeout_s:
                return
            self._start()
            return
        assert self._t0_ns is not None  # set with the profile
        now_ns = self.get_clock().now().nanoseconds
        end_ns = self._t0_ns + int((cfg.lead_in_s + self._profile.duration_s + cfg.settle_s)
                                   * 1e9)
        if now_ns >= end_ns:
            err_deg = math.degrees(self.max_error_rad)
            ok = self.states_checked > 0 and err_deg <= cfg.max_tracking_error_deg
            self.done = True
            self.get_logger().info(f'plan done: {self.states_seen} joint states, largest '
                                   f'tracking error {err_deg:.4f} deg')
            if self.states_seen and not self.states_checked:
                self.get_logger().error(
                    'no joint state was stamped inside the plan\'s time window: the table '
                    'and this node are on different clocks (set use_sim_time:=true when the '
                    'table publishes /clock)')
            elif not ok:
                self.get_logger().error('the table did not follow the plan (no joint states '
                                        'or tracking error above max_tracking_error_deg)')
            raise SystemExit(0 if ok else 1)

    def on_shutdown(self) -> None:
        """SIGINT/SIGTERM before the plan ended: exit status 1 (the plan did not run)."""
        if not self.done:
            raise ImuCalibError('interrupted before the plan ended')

    def _start(self) -> None:
        from ..core.plans import build_profile
        q0 = self._q_now if self._q_now is not None else np.zeros(self.fixture.n_joints)
        if self._q_now is None:
            self.get_logger().warn('no joint_states received: assuming the table is at zero')
        try:  # on a URDF chain: refused naming the joint and the limit (nothing is sent)
            self._profile = build_profile(self.plan, self.fixture, q_start_rad=q0)
        except PlanError as exc:
            self.done = True  # nothing moved: not "interrupted"
            raise PlanError(f'plan refused, nothing sent to {self._pub.topic_name}: {exc}') \
                from None
        msg = trajectory_from_profile(self._profile, self.config.point_period_s,
                                      self.config.lead_in_s)
        self._t0_ns = self.get_clock().now().nanoseconds
        # the controller starts the trajectory at this stamp (ros2_control semantics), the
        # time the tracking check measures from: transport latency does not shift them apart
        msg.header.stamp = time_msg_from_ns(self._t0_ns)
        self._pub.publish(msg)
        self.get_logger().info(f'plan "{self.plan.name}": {len(msg.points)} points, '
                               f'{self._profile.duration_s:.1f} s, sent to '
                               f'{self._pub.topic_name}')


INTERFACE = NodeInterface(
    name=NODE_NAME, config=TurntableDriverConfig,
    summary='Drives a real turntable through a motion plan: sends it as one JointTrajectory '
            '(positions, velocities, accelerations) from where the table is, follows the joint '
            'states, and exits 0 only if the table followed the plan.',
    subscribes=(Endpoint('joint_states', 'sensor_msgs/msg/JointState',
                         'where the table is, and how it follows'),
                Endpoint('robot_description', 'std_msgs/msg/String',
                         'with fixture:=robot_description only: the URDF, once at start '
                         '(reliable, transient local)')),
    publishes=(Endpoint('joint_trajectory', 'trajectory_msgs/msg/JointTrajectory',
                        'the plan; remap to the controller, e.g. '
                        '/joint_trajectory_controller/joint_trajectory'),),
    notes='Exit status: 0 the table followed the plan; 1 tracking error above '
          'max_tracking_error_deg, no joint state in the plan\'s window, or interrupted; '
          '2 bad parameter or file, or a plan refused (on a URDF chain: a step would leave a '
          'joint\'s position or velocity limit; nothing is sent).')


def main(args: list[str] | None = None) -> int:
    """Console script ``turntable_driver``."""
    return run_node(TurntableDriverNode, args, INTERFACE)


if __name__ == '__main__':
    sys.exit(main())
