"""Node configuration without DDS: YAML files match the dataclasses, parameters, profiles."""
from __future__ import annotations

import dataclasses
import math
from typing import Any
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter

from imu_calib_ros.core.errors import ConfigError
from imu_calib_ros.nodes.calibration import CalibrationNodeConfig
from imu_calib_ros.nodes.common import declare_config, load_params_file
from imu_calib_ros.nodes.compensator import CompensatorConfig
from imu_calib_ros.nodes.turntable_sim import QuinticProfile, TurntableSimConfig

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize('cls,name,node', [
    (CalibrationNodeConfig, 'calibration_node.yaml', 'calibration'),
    (CompensatorConfig, 'compensator.yaml', 'compensator'),
    (TurntableSimConfig, 'turntable_sim.yaml', 'turntable_sim')])
def test_config_yaml_matches_dataclass(cls: type, name: str, node: str) -> None:
    """The shipped params files hold exactly the dataclass defaults (and load strictly)."""
    assert load_params_file(ROOT / 'config' / name, cls, node) == cls()


def test_declared_defaults_are_the_dataclass_defaults_without_a_params_file() -> None:
    """A nested field's own default is what a node started without --params-file runs; the
    node's estimator blocks are the offline ones (issue 16 item 10: one computation)."""
    from imu_calib_ros.core.estimator import EstimatorConfig
    from imu_calib_ros.nodes.calibration import LIVE_BLOCK_CHUNKS
    assert EstimatorConfig().block_chunks == LIVE_BLOCK_CHUNKS
    rclpy.init(args=['x', '--ros-args', '-p', 'fixture:=three_axis'])  # required
    try:
        node = Node('calibration_defaults')
        cfg = declare_config(node, CalibrationNodeConfig)
        assert cfg.estimator.block_chunks == LIVE_BLOCK_CHUNKS
        assert cfg == dataclasses.replace(CalibrationNodeConfig(), fixture='three_axis')
    finally:
        rclpy.try_shutdown()


def test_parameters_declared_from_dataclass_with_descriptors() -> None:
    rclpy.init(args=['x', '--ros-args', '--params-file',
                     str(ROOT / 'config' / 'calibration_node.yaml'),
                     '-p', 'estimator.noise_scale:=2.5', '-p', 'imu_rate_hz:=1000.0',
                     '-p', 'fixture:=three_axis'])
    try:
        node = Node('calibration')
        cfg = declare_config(node, CalibrationNodeConfig)
        assert cfg.imu_rate_hz == 1000.0 and cfg.estimator.noise_scale == 2.5
        assert dataclasses.replace(cfg, imu_rate_hz=0.0, fixture='', estimator=dataclasses.replace(
            cfg.estimator, noise_scale=1.0)) == CalibrationNodeConfig()
        d = node.describe_parameter('estimator.gate_probability')
        assert d.description and d.floating_point_range[0].to_value == 1.0
        bad = Node('bad', parameter_overrides=[Parameter('imu_rate_hz', value=-3.0)])
        with pytest.raises(ConfigError, match='imu_rate_hz'):
            declare_config(bad, CalibrationNodeConfig)
        bad2 = Node('bad2', parameter_overrides=[
            Parameter('estimator.noise_source', value='foo')])
        with pytest.raises(ConfigError, match='estimator.noise_source'):
            declare_config(bad2, CalibrationNodeConfig)
    finally:
        rclpy.try_shutdown()


def test_quintic_profile_through_plan_points_reproduces_the_plan() -> None:
    """The driver's trajectory points, joined by the sim's quintics, give the plan back."""
    from imu_calib_ros.core.config import resolve_config_file
    from imu_calib_ros.core.fixture import Fixture
    from imu_calib_ros.core.plans import build_profile, load_plan
    from imu_calib_ros.nodes.turntable_driver import trajectory_from_profile
    fx = Fixture.from_yaml(resolve_config_file('three_axis', 'fixtures'))
    profile = build_profile(load_plan('demo_short'), fx)
    msg = trajectory_from_profile(profile, 0.05, 0.0)
    t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points])
    q0, v0, a0 = profile.evaluate(np.array([0.0]))
    qp = QuinticProfile(profile.joint_names, np.r_[0.0, t],
                        np.vstack([q0, [p.positions for p in msg.points]]),
                        np.vstack([v0, [p.velocities for p in msg.points]]),
                        np.vstack([a0, [p.accelerations for p in msg.points]]))
    tt = np.linspace(0.0, profile.duration_s, 50001)
    for got, want in zip(qp.evaluate(tt), profile.evaluate(tt)):
        # quintic pieces exactly (points at every breakpoint); cosines to O(h^6) ~ 1e-9
        np.testing.assert_allclose(got, want, atol=1e-7)
    hold = QuinticProfile.hold(profile.joint_names, np.array([0.1, 0.2, 0.3]), 2.0)
    q, qd, qdd = hold.evaluate(np.array([0.0, 1.0, 2.0]))
    np.testing.assert_array_equal(q, np.tile([0.1, 0.2, 0.3], (3, 1)))
    assert not qd.any() and not qdd.any()


def _trajectory(stamp_ns: int, points: list[tuple[float, float]]) -> Any:
    from builtin_interfaces.msg import Duration, Time
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    m = JointTrajectory(joint_names=['outer'])
    m.header.stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    for t, q in points:
        ns = int(round(t * 1e9))
        m.points.append(JointTrajectoryPoint(
            positions=[q], time_from_start=Duration(sec=ns // 10**9, nanosec=ns % 10**9)))
    return m


@pytest.mark.parametrize('ahead_s', [0.5, 3.0])
def test_sim_follows_trajectories_from_their_stamps_without_jumps(ahead_s: float) -> None:
    """turntable_sim (a real node, no peers needed): trajectory A (90 deg in 2 s) from now;
    mid-move, B stamped ``ahead_s`` in the future (before and after A's end). The joint
    motion stays continuous: A runs on until B's stamp (holding its end if it ends first),
    then B starts from there. Before the fix the table froze at the arrival of B and jumped
    by 36 deg at its stamp."""
    from imu_calib_ros.nodes.turntable_sim import TurntableSimNode
    rclpy.init(args=['x', '--ros-args', '-p', 'imu_rate_hz:=100.0', '-p', 'noise:=false'])
    try:
        node = TurntableSimNode()
        i = node.joint_names.index('outer')
        t0 = node._last_imu_ns
        node._on_trajectory(_trajectory(0, [(0.5, 0.0), (2.5, math.pi / 2)]))
        node._last_imu_ns = cut = t0 + 1_500_000_000  # A published up to mid-move
        q_a = node._state_at(cut)[0][i]
        b_start = cut + int(ahead_s * 1e9)
        node._on_trajectory(_trajectory(b_start, [(0.5, 2.0), (1.5, 2.5)]))
        t = np.arange(cut, b_start + 2_000_000_000, 1_000_000)  # 1 ms steps
        q = np.array([node._state_at(int(x))[0][i] for x in t])
        qd = np.array([node._state_at(int(x))[1][i] for x in t])
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
    assert q[0] == pytest.approx(q_a)
    # no step larger than the largest rate allows over 1 ms (+ rounding)
    assert np.max(np.abs(np.diff(q))) <= np.max(np.abs(qd)) * 1e-3 * 1.01 + 1e-12
    assert q[-1] == pytest.approx(2.5, abs=1e-9)  # B's last point reached
    if ahead_s > 2.0:  # A ended first: held at 90 deg until B's stamp
        k = np.searchsorted(t, b_start) - 1
        assert q[k] == pytest.approx(math.pi / 2, abs=1e-9)


def test_driver_keeps_every_breakpoint_next_to_a_grid_point() -> None:
    """A breakpoint 0.3 ms after a grid point (0.05 s grid) stays a trajectory point, with
    the extra point 1 ms before it; the grid point gives way."""
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.plans import build_profile, plan_from_dict
    from imu_calib_ros.nodes.turntable_driver import trajectory_from_profile
    plan = plan_from_dict({'name': 't', 'steps': [
        {'dwell': {'duration_s': 1.0003}},
        {'move': {'joint': 'outer', 'by_deg': 30.0, 'duration_s': 0.9997}}]}, '<test>')
    profile = build_profile(plan, load_fixture('three_axis'))
    assert profile.duration_s == pytest.approx(2.0)  # grid: 40 x 0.05 s, 1.0 on it
    msg = trajectory_from_profile(profile, 0.05, 0.5)
    times = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9
                      for p in msg.points]) - 0.5
    for b in profile.breakpoints_s:
        assert np.min(np.abs(times - b)) < 1e-9, b
    assert np.min(np.abs(times - (1.0003 - 1e-3))) < 1e-9
    assert np.min(np.abs(times - 1.0)) > 1e-4  # the grid point gave way
