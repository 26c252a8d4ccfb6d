"""``turntable_sim`` node: a simulated turntable with an IMU on it, over real topics.

Publishes ``joint_states`` and ``imu/data_raw`` from :func:`imu_calib_ros.core.simulator.simulate`
and ``/clock`` (``rosgraph_msgs/Clock``), so a graph with ``use_sim_time`` runs at ``speed``
times real time. Two ways to move:

- ``plan:=NAME``: run a motion plan (``config/plans``), then hold the last position;
- no plan: follow ``trajectory_msgs/JointTrajectory`` commands on ``joint_trajectory``
  (remap it to ``/joint_trajectory_controller/joint_trajectory`` to stand in for a
  ros2_control joint trajectory controller). The commanded points are joined by quintic
  polynomials through the given positions, velocities and accelerations (zero when absent),
  i.e. rest-to-rest quintic moves like the plans' moves. A new command replaces the rest of
  the current one from its ``header.stamp`` (zero: now), as the controller does.

The motion is simulated in chunks (a whole plan, a trajectory, or ``hold_chunk_s`` of holding
still), each starting at the last published IMU stamp from the state reached there, with the
same true sensor errors and mounting; only the slow noise states (bias instability) restart
per chunk. ``truth_file`` receives the true calibration (CONTRACT 4 layout, sigma 0).
"""
from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from trajectory_msgs.msg import JointTrajectory

from msg_adapters.convert import imu_msg_from_sample, joint_state_msg_from_sample

from ..core.errors import ConfigError, PlanError
from ..core.types import FloatArray, ImuBatch, JointBatch
from .common import (Endpoint, NodeInterface, declare_config, reliable_qos, run_node,
                     time_msg_from_ns)
from .fixture_source import UrdfFixtureFields, load_node_fixture

NODE_NAME = 'turntable_sim'


@dataclass(frozen=True)
class TurntableSimConfig(UrdfFixtureFields):  # + the URDF parameters
    """Parameters of the turntable simulator node (``config/turntable_sim.yaml``)."""

    fixture: str = field(default='three_axis', metadata={
        'doc': 'fixture file (CONTRACT 2 YAML or a .urdf), shipped fixture name (three_axis, '
               'savage_2axis, arm6.urdf), or robot_description (the URDF on that topic)'})
    imu_grade: str = field(default='nav_grade', metadata={
        'doc': 'IMU grade (config/imus name or path): noise and error magnitudes'})
    plan: str = field(default='', metadata={
        'doc': 'motion plan (config/plans name or path); empty = follow JointTrajectory'})
    seed: int = field(default=0, metadata={'doc': 'random seed (true errors, noise)',
                                           'min': 0})
    # the arm's own errors, as imu-calib simulate --joint-offset-sigma-rad / --link-sigma-m
    joint_offset_sigma_rad: float = field(default=0.0, metadata={
        'doc': 'simulate an uncalibrated chain: each revolute joint\'s zero off by N(0, this) '
               '[rad] (e.g. 1e-3); the joint states are the encoder readings; 0 = none',
        'min': 0.0, 'max': 1.0})
    link_sigma_m: float = field(default=0.0, metadata={
        'doc': 'simulate an uncalibrated chain: each joint origin (link lengths, offsets) off '
               'by N(0, this) per coordinate [m] (e.g. 2e-3; not on a turntable, whose axes '
               'meet in one point); 0 = none', 'min': 0.0, 'max': 1.0})
    imu_rate_hz: float = field(default=200.0, metadata={
        'doc': 'IMU sample rate [Hz]', 'min': 1.0, 'max': 10000.0})
    joint_rate_hz: float = field(default=100.0, metadata={
        'doc': 'joint_states rate [Hz]', 'min': 1.0, 'max': 10000.0})
    frame_id: str = field(default='imu_link', metadata={'doc': 'IMU header.frame_id'})
    speed: float = field(default=1.0, metadata={
        'doc': 'simulated seconds per wall-clock second', 'min': 0.01, 'max': 1000.0})
    publish_clock: bool = field(default=True, metadata={'doc': 'publish /clock'})
    clock_rate_hz: float = field(default=200.0, metadata={
        'doc': 'wall-clock rate of publishing ticks (and /clock) [Hz]', 'min': 1.0,
        'max': 2000.0})
    start_stamp_s: float = field(default=1000.0, metadata={
        'doc': 'simulated time of the start [s] (/clock and stamps)', 'min': 0.0})
    truth_file: str = field(default='', metadata={
        'doc': 'write the true calibration here (CONTRACT 4 layout); empty = do not'})
    wait_for_subscribers: int = field(default=0, metadata={
        'doc': 'wait until this many subscribers listen on imu/data_raw before starting',
        'min': 0})
    wait_timeout_s: float = field(default=30.0, metadata={
        'doc': 'give up waiting for subscribers after this [s wall] and start', 'min': 0.0})
    hold_chunk_s: float = field(default=1.0, metadata={
        'doc': 'length of simulated hold chunks between motions [s]', 'min': 0.05,
        'max': 60.0})
    exit_when_done: bool = field(default=False, metadata={
        'doc': 'exit (status 0) after the plan plus exit_after_s of holding'})
    exit_after_s: float = field(default=1.0, metadata={
        'doc': 'simulated seconds of holding after the plan before exiting', 'min': 0.0})
    noise: bool = field(default=True, metadata={'doc': 'add sensor noise'})
    queue_depth: int = field(default=100, metadata={
        'doc': 'publisher queue depth (sensor-data QoS)', 'min': 1, 'max': 100000})


class QuinticProfile:
    """Joint motion through knots joined by quintic polynomials (duck-types ``JointProfile``).

    Between knots ``k`` and ``k+1`` each joint follows the unique quintic matching position,
    velocity and acceleration at both ends (continuous acceleration at every knot), the
    profile of rest-to-rest moves when the inner velocities and accelerations are zero.

    Parameters
    ----------
    joint_names:
        Names of the ``n`` joints, fixture order.
    t_s:
        ``(K,)`` increasing knot times from 0.
    q_rad, qd_rad_s, qdd_rad_s2:
        ``(K, n)`` positions, velocities, accelerations at the knots.
    """

    def __init__(self, joint_names: tuple[str, ...], t_s: FloatArray, q_rad: FloatArray,
                 qd_rad_s: FloatArray, qdd_rad_s2: FloatArray, label: str = 'trajectory'):
        self.joint_names = tuple(joint_names)
        self.plan_name = label
        self.t_s = np.asarray(t_s, float)
        if self.t_s.ndim != 1 or self.t_s.size < 2 or np.any(np.diff(self.t_s) <= 0):
            raise PlanError('trajectory: knot times must increase strictly')
        self.duration_s = float(self.t_s[-1])
        self.breakpoints_s = self.t_s.copy()
        q = np.asarray(q_rad, float)
        qd = np.asarray(qd_rad_s, float)
        qdd = np.asarray(qdd_rad_s2, float)
        h = np.diff(self.t_s)[:, None]
        # Quintic Hermite coefficients in the normalised time s = (t - t_k) / h
        # (hand-written: scipy's BPoly.from_derivatives builds the same but is slower to
        # evaluate per chunk and hides the closed form).
        p0, v0, a0 = q[:-1], qd[:-1] * h, qdd[:-1] * h * h
        p1, v1, a1 = q[1:], qd[1:] * h, qdd[1:] * h * h
        c3 = 10 * (p1 - p0) - 6 * v0 - 4 * v1 - 1.5 * a0 + 0.5 * a1
        c4 = -15 * (p1 - p0) + 8 * v0 + 7 * v1 + 1.5 * a0 - a1
        c5 = 6 * (p1 - p0) - 3 * v0 - 3 * v1 - 0.5 * a0 + 0.5 * a1
        self._c = np.stack([p0, v0, 0.5 * a0, c3, c4, c5], axis=0)  # (6, K-1, n)
        self._h = h[:, 0]
        self.segments = [_segment(float(self.t_s[k]), float(self.t_s[k + 1]),
                                  'dwell' if np.allclose(q[k], q[k + 1]) else 'move', label)
                         for k in range(self.t_s.size - 1)]

    @property
    def q_start(self) -> FloatArray:
        """Joint angles at t = 0."""
        return self._c[0, 0].copy()

    @classmethod
    def hold(cls, joint_names: tuple[str, ...], q_rad: FloatArray,
             duration_s: float) -> 'QuinticProfile':
        """Hold still at ``q_rad`` for ``duration_s``."""
        q = np.asarray(q_rad, float)[None, :].repeat(2, axis=0)
        z = np.zeros_like(q)
        return cls(joint_names, np.array([0.0, duration_s]), q, z, z, label='hold')

    def evaluate(self, t_s: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(q, qd, qdd)``, each ``(N, n)``, at times ``t_s`` (clamped to the profile)."""
        t = np.clip(np.atleast_1d(np.asarray(t_s, float)), 0.0, self.duration_s)
        k = np.clip(np.searchsorted(self.t_s, t, side='right') - 1, 0, self._h.size - 1)
        h = self._h[k][:, None]
        s = ((t - self.t_s[k]) / self._h[k])[:, None]
        c = self._c[:, k, :]  # (6, N, n)
        q = c[0] + s * (c[1] + s * (c[2] + s * (c[3] + s * (c[4] + s * c[5]))))
        dq = c[1] + s * (2 * c[2] + s * (3 * c[3] + s * (4 * c[4] + s * 5 * c[5])))
        ddq = 2 * c[2] + s * (6 * c[3] + s * (12 * c[4] + s * 20 * c[5]))
        return q, dq / h, ddq / (h * h)


def _chain_errors_line(chain: dict[str, Any]) -> str:
    """One line: the arm errors drawn (zero offsets [mrad], largest origin error [mm])."""
    offs = ', '.join(f'{n} {v * 1e3:+.3f}' for n, v in chain['joint_zero_offsets_rad'].items())
    link = max((float(np.linalg.norm(v)) for v in chain['joint_origin_errors_m'].values()),
               default=0.0)
    return (f'simulating the chain with errors (joint_offset_sigma_rad '
            f'{chain["joint_offset_sigma_rad"]:g}, link_sigma_m {chain["link_sigma_m"]:g}): '
            f'joint zero offsets [mrad] {offs}; largest joint-origin error {link * 1e3:.3f} mm')


def _segment(t0: float, t1: float, kind: str, label: str) -> Any:
    try:
        from ..core.plans import Segment
        return Segment(t0_s=t0, t1_s=t1, kind=kind, label=label, meta={})
    except (ImportError, TypeError):  # plans not importable: a plain record with the fields
        return {'t0_s': t0, 't1_s': t1, 'kind': kind, 'label': label, 'meta': {}}


@dataclass
class _Chunk:
    """One simulated stretch: its samples and the profile they came from."""

    start_ns: int
    profile: Any
    imu: ImuBatch
    joints: JointBatch

    @property
    def end_ns(self) -> int:
        return int(self.imu.stamps_ns[-1]) if len(self.imu) else self.start_ns

    def state_at(self, stamp_ns: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        q, qd, qdd = self.profile.evaluate(np.array([(stamp_ns - self.start_ns) * 1e-9]))
        return q[0], qd[0], qdd[0]


class TurntableSimNode(Node):
    """Publishes simulated joint states, raw IMU and /clock at ``speed`` x real time."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config: TurntableSimConfig = declare_config(self, TurntableSimConfig)
        cfg = self.config
        from ..core.imu_grade import load_grade
        self.fixture = load_node_fixture(self, cfg)
        self.grade = load_grade(cfg.imu_grade)
        self.joint_names: tuple[str, ...] = tuple(self.fixture.joint_names)
        self._truth_errors: Any = None
        self._true_fixture: Any = None
        self._chunk_index = 0
        self._chunks: list[_Chunk] = []
        self._imu_pub = self.create_publisher(Imu, 'imu/data_raw',
                                             reliable_qos(cfg.queue_depth))
        self._joint_pub = self.create_publisher(JointState, 'joint_states',
                                                reliable_qos(cfg.queue_depth))
        self._clock_pub = (self.create_publisher(Clock, '/clock', 10) if cfg.publish_clock
                           else None)
        self._traj_sub = self.create_subscription(JointTrajectory, 'joint_trajectory',
                                                  self._on_trajectory, reliable_qos())
        self.now_ns = int(round(cfg.start_stamp_s * 1e9))
        self._last_imu_ns = self.now_ns
        self._last_joint_ns = self.now_ns - 1
        self.plan_end_ns: int | None = None
        start_q = np.zeros(len(self.joint_names))
        if cfg.plan:
            self._start_plan()
        else:
            self._append(QuinticProfile.hold(self.joint_names, start_q, cfg.hold_chunk_s),
                         self.now_ns)
        self.imu_published = 0
        self.joint_published = 0
        self._started = False
        self._wall_wait_start = time.monotonic()
        self._wall_t0 = 0.0
        self._sim_t0_ns = self.now_ns
        self._timer = self.create_timer(1.0 / cfg.clock_rate_hz, self._on_tick)

    # ------------------------------------------------------------------ simulation chunks
    def _sim_config(self, start_ns: int) -> Any:
        from ..core.simulator import SimConfig
        cfg = self.config
        kwargs: dict[str, Any] = dict(imu_rate_hz=cfg.imu_rate_hz,
                                      joint_rate_hz=cfg.joint_rate_hz,
                                      seed=cfg.seed + 7919 * self._chunk_index,
                                      noise=cfg.noise, start_stamp_ns=start_ns,
                                      joint_offset_sigma_rad=cfg.joint_offset_sigma_rad,
                                      link_sigma_m=cfg.link_sigma_m)
        if self._true_fixture is not None:  # later chunks: the first chunk's true mounting
            # and chain (arm errors), drawn once
            kwargs.update(mounting_rpy_sigma_rad=0.0, mounting_xyz_sigma_m=0.0,
                          joint_offset_sigma_rad=0.0, link_sigma_m=0.0)
        names = {f.name for f in dataclasses.fields(SimConfig)}
        return SimConfig(**{k: v for k, v in kwargs.items() if k in names})

    def _append(self, profile: Any, start_ns: int) -> _Chunk:
        from ..core.simulator import simulate
        fixture = self._true_fixture if self._true_fixture is not None else self.fixture
        result = simulate(fixture, profile, self.grade, self._sim_config(start_ns),
                          errors=self._truth_errors)
        self._chunk_index += 1
        if self._truth_errors is None:
            self._truth_errors = result.truth.errors
            self._true_fixture = result.true_fixture
            chain = result.truth.extra.get('chain_errors')
            if chain:
                self.get_logger().info(_chain_errors_line(chain))
            if self.config.truth_file:
                truth = result.truth
                if not self.config.plan:  # the first chunk is a hold, not the run: no
                    # end-of-run bias (the drift restarts with every chunk)
                    truth = dataclasses.replace(truth, extra={
                        k: v for k, v in truth.extra.items() if k != 'bias_at_end'})
                truth.save(self.config.truth_file)
                self.get_logger().info(f'true calibration written to {self.config.truth_file}')
        chunk = _Chunk(start_ns, profile, result.imu, result.joints)
        self._chunks.append(chunk)
        return chunk

    def _start_plan(self) -> None:
        from ..core.plans import build_profile, load_plan
        plan = load_plan(self.config.plan)
        profile = build_profile(plan, self.fixture)
        chunk = self._append(profile, self.now_ns)
        self.plan_end_ns = chunk.end_ns
        self.get_logger().info(f'plan "{self.config.plan}": {profile.duration_s:.1f} s '
                               f'simulated, {len(chunk.imu)} IMU samples')

    def _state_at(self, stamp_ns: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        for chunk in reversed(self._chunks):
            if chunk.start_ns <= stamp_ns:
                return chunk.state_at(stamp_ns)
        return self._chunks[-1].state_at(stamp_ns)

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        """Follow a trajectory from ``header.stamp`` (zero: from now), as a ros2_control
        joint trajectory controller does.

        A stamp in the past by less than the first point's ``time_from_start`` (transport
        latency; the driver stamps the time it measures the plan from) starts the trajectory
        at the stamp, from the state at the stamp; the samples already published up to now
        stay as they were (the start of a trajectory leaves the table's state with zero
        velocity only if its first point is that state, as the driver's lead-in is). Further
        in the past: from now, with a warning. In the future: the current motion goes on
        until then (holding its end state if it ends first), and the trajectory starts from
        the state there.
        """
        cut = self._last_imu_ns
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        start = stamp if stamp > 0 else cut
        if msg.points:
            t1 = msg.points[0].time_from_start
            first_ns = t1.sec * 10**9 + t1.nanosec
            if start > cut + int(60e9):
                self.get_logger().warn(f'trajectory stamped {(start - cut) * 1e-9:.0f} s ahead '
                                       'of the simulated time (a wall-clock stamp? set '
                                       'use_sim_time on the sender): starting it now')
                start = cut
            elif start < cut - first_ns:
                self.get_logger().warn(f'trajectory stamped {(cut - start) * 1e-9:.3f} s in the '
                                       'past: starting it now')
                start = cut
        # the simulated chunk starts on the IMU sample grid (uniform stamps, CONTRACT 1) at
        # or before the stamp; the profile holds its start state for the difference
        period_ns = int(round(1e9 / self.config.imu_rate_hz))
        chunk_ns = cut + ((start - cut) // period_ns) * period_ns
        try:
            profile = self._profile_from_trajectory(msg, chunk_ns, (start - chunk_ns) * 1e-9)
        except (PlanError, ConfigError) as exc:
            self.get_logger().error(f'trajectory refused: {exc}')
            return
        # the motion so far runs on until the new start (the controller's behaviour); if it
        # ends before a future stamp, the table holds its end state until then
        self._chunks = [c for c in self._chunks if c.start_ns < chunk_ns]
        last = self._chunks[-1] if self._chunks else None
        if last is not None and last.end_ns < chunk_ns:
            q, _, _ = last.state_at(last.end_ns)
            self._append(QuinticProfile.hold(self.joint_names, q,
                                             (chunk_ns - last.end_ns) * 1e-9), last.end_ns)
        self._append(profile, chunk_ns)
        self.get_logger().info(f'following trajectory of {len(msg.points)} points, '
                               f'{profile.duration_s:.2f} s, from {start * 1e-9:.3f} s')

    def _profile_from_trajectory(self, msg: JointTrajectory, start_ns: int,
                                 delay_s: float = 0.0) -> QuinticProfile:
        unknown = [n for n in msg.joint_names if n not in self.joint_names]
        if unknown:
            raise PlanError(f'unknown joints {unknown} (fixture joints: '
                            f'{list(self.joint_names)})')
        if not msg.points:
            raise PlanError('no points')
        q0, qd0, qdd0 = self._state_at(start_ns)
        idx = [self.joint_names.index(n) for n in msg.joint_names]
        t = [0.0]
        qs, qds, qdds = [q0], [qd0], [qdd0]
        for i, p in enumerate(msg.points):
            tk = delay_s + p.time_from_start.sec + p.time_from_start.nanosec * 1e-9
            if len(p.positions) != len(idx):
                raise PlanError(f'point {i}: {len(p.positions)} positions for '
                                f'{len(idx)} joints')
            q = qs[-1].copy()
            q[idx] = np.asarray(p.positions, float)
            qd = np.zeros_like(q)
            qdd = np.zeros_like(q)
            if len(p.velocities):
                qd[idx] = np.asarray(p.velocities, float)
            if len(p.accelerations):
                qdd[idx] = np.asarray(p.accelerations, float)
            if tk <= t[-1] + 1e-9:
                if i == 0 and tk <= 1e-9:  # a point at time 0 restates the start
                    continue
                raise PlanError(f'point {i}: time_from_start {tk} s does not increase')
            t.append(tk)
            qs.append(q)
            qds.append(qd)
            qdds.append(qdd)
        if len(t) < 2:
            raise PlanError('no point after time 0')
        return QuinticProfile(self.joint_names, np.array(t), np.array(qs), np.array(qds),
                              np.array(qdds))

    # ------------------------------------------------------------------ publishing
    def _waiting(self) -> bool:
        cfg = self.config
        if self._started:
            return False
        waited = time.monotonic() - self._wall_wait_start
        if (self._imu_pub.get_subscription_count() < cfg.wait_for_subscribers
                and waited < cfg.wait_timeout_s):
            if self._clock_pub is not None:
                self._clock_pub.publish(Clock(clock=time_msg_from_ns(self.now_ns)))
            return True
        if cfg.wait_for_subscribers and waited < 0.5:  # let the matching settle both ways
            return True
        self._started = True
        self._wall_t0 = time.monotonic()
        self._sim_t0_ns = self.now_ns
        self.get_logger().info(f'starting at {self.now_ns * 1e-9:.3f} s sim time, speed '
                               f'{cfg.speed}x, {self._imu_pub.get_subscription_count()} '
                               'IMU subscribers')
        return False

    def _on_tick(self) -> None:
        if self._waiting():
            return
        cfg = self.config
        target_ns = self._sim_t0_ns + int((time.monotonic() - self._wall_t0) * cfg.speed * 1e9)
        # keep simulated data ahead of the clock: hold at the last state when it runs out
        while self._chunks[-1].end_ns < target_ns + int(0.2 * 1e9 * max(cfg.speed, 1.0)):
            last = self._chunks[-1]
            q, _, _ = last.state_at(last.end_ns)
            self._append(QuinticProfile.hold(self.joint_names, q, cfg.hold_chunk_s),
                         last.end_ns)
        self._publish_until(target_ns)
        self.now_ns = target_ns
        if self._clock_pub is not None:
            self._clock_pub.publish(Clock(clock=time_msg_from_ns(target_ns)))
        # drop chunks that are entirely published
        while len(self._chunks) > 1 and self._chunks[1].start_ns <= self._last_imu_ns \
                and self._chunks[0].end_ns <= self._last_imu_ns:
            self._chunks.pop(0)
        if (cfg.exit_when_done and self.plan_end_ns is not None
                and target_ns >= self.plan_end_ns + int(cfg.exit_after_s * 1e9)):
            self.get_logger().info(f'plan done: {self.imu_published} IMU and '
                                   f'{self.joint_published} joint samples published')
            raise SystemExit(0)

    def _publish_until(self, target_ns: int) -> None:
        """Publish every sample with a stamp in (last published, target], in stamp order."""
        frame_id = self.config.frame_id
        for chunk in list(self._chunks):
            if chunk.start_ns > target_ns:
                break
            nxt = [c.start_ns for c in self._chunks if c.start_ns > chunk.start_ns]
            upto = min([target_ns, *nxt])  # a later chunk supersedes this one from its start
            imu, joints = chunk.imu, chunk.joints
            i0 = int(np.searchsorted(imu.stamps_ns, self._last_imu_ns, side='right'))
            i1 = int(np.searchsorted(imu.stamps_ns, upto, side='right'))
            j0 = int(np.searchsorted(joints.stamps_ns, self._last_joint_ns, side='right'))
            j1 = int(np.searchsorted(joints.stamps_ns, upto, side='right'))
            i, j = i0, j0
            while i < i1 or j < j1:
                if j >= j1 or (i < i1 and imu.stamps_ns[i] <= joints.stamps_ns[j]):
                    s = imu.sample(i)
                    self._imu_pub.publish(imu_msg_from_sample(s, Imu, frame_id=frame_id))
                    self._last_imu_ns = s.stamp_ns
                    self.imu_published += 1
                    i += 1
                else:
                    sj = joints.sample(j)
                    self._joint_pub.publish(joint_state_msg_from_sample(sj, JointState))
                    self._last_joint_ns = sj.stamp_ns
                    self.joint_published += 1
                    j += 1


INTERFACE = NodeInterface(
    name=NODE_NAME, config=TurntableSimConfig, params_file='config/turntable_sim.yaml',
    summary='A simulated turntable with an IMU on it: runs a motion plan, or follows '
            'JointTrajectory commands like a ros2_control joint trajectory controller, and '
            'publishes the exact simulated IMU and joint states with /clock. Moves no hardware.',
    subscribes=(Endpoint('joint_trajectory', 'trajectory_msgs/msg/JointTrajectory',
                         'commands, when no plan is given'),
                Endpoint('robot_description', 'std_msgs/msg/String',
                         'with fixture:=robot_description only: the URDF, once at start '
                         '(reliable, transient local)')),
    publishes=(
        Endpoint('imu/data_raw', 'sensor_msgs/msg/Imu', 'simulated raw IMU (CONTRACT 1)'),
        Endpoint('joint_states', 'sensor_msgs/msg/JointState', 'simulated encoders'),
        Endpoint('/clock', 'rosgraph_msgs/msg/Clock', 'simulated time (publish_clock)')))


def main(args: list[str] | None = None) -> int:
    """Console script ``turntable_sim``."""
    return run_node(TurntableSimNode, args, INTERFACE)


if __name__ == '__main__':
    sys.exit(main())
