"""bag_player over real DDS: a simulated bag comes out on the topics with its recorded stamps,
values bit for bit, and /clock follows the recorded time (what `ros2 bag play --clock` does)."""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 200)))  # conftest's
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402

from imu_calib_ros.core.fixture import load_fixture  # noqa: E402
from imu_calib_ros.core.imu_grade import load_grade  # noqa: E402
from imu_calib_ros.core.plans import build_profile, plan_from_dict  # noqa: E402
from imu_calib_ros.core.simulator import SimConfig, simulate  # noqa: E402
from msg_adapters.bag import read_bag, write_bag  # noqa: E402
from msg_adapters.convert import (imu_sample_from_msg,  # noqa: E402
                                  joint_sample_from_msg, stamp_ns_from_time)
from imu_calib_ros.nodes.common import reliable_qos  # noqa: E402


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    fx = load_fixture('three_axis')
    plan = plan_from_dict({'name': 't', 'steps': [
        {'dwell': {'duration_s': 1.0}},
        {'move': {'joint': 'outer', 'by_deg': 90, 'duration_s': 2.0}},
        {'dwell': {'duration_s': 1.0}}]}, source='test')
    sim = simulate(fx, build_profile(plan, fx), load_grade('mems_mti1'),
                   SimConfig(imu_rate_hz=100, joint_rate_hz=50, seed=5))
    path = tmp_path_factory.mktemp('bag') / 'b'
    write_bag(path, sim.imu, sim.joints)
    return path


def test_bag_player_republishes_the_bag_with_clock(bag: Path) -> None:
    imu, joints = read_bag(bag)
    rclpy.init(args=[])
    node = rclpy.create_node(f'test_bag_player_{os.getpid()}')
    got_imu, got_joint, got_clock = [], [], []
    qos = reliable_qos(depth=1000)
    node.create_subscription(Imu, 'imu/data_raw', lambda m: got_imu.append(m), qos)
    node.create_subscription(JointState, 'joint_states', lambda m: got_joint.append(m), qos)
    node.create_subscription(Clock, '/clock', lambda m: got_clock.append(m), qos)
    proc = subprocess.Popen([sys.executable, '-m', 'imu_calib_ros.nodes.bag_player',
                             '--ros-args', '-p', f'bag:={bag}', '-p', 'rate:=4.0',
                             '-p', 'wait_for_subscribers:=1', '-p', 'wait_timeout_s:=30.0'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        end = time.monotonic() + 60
        while time.monotonic() < end and (len(got_imu) < len(imu) or proc.poll() is None):
            rclpy.spin_once(node, timeout_sec=0.05)
        for _ in range(20):
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        if proc.poll() is None:
            proc.kill()
        out = proc.communicate(timeout=10)[0].decode(errors='replace')
        node.destroy_node()
        rclpy.try_shutdown()
    assert proc.returncode == 0, out
    samples = [imu_sample_from_msg(m) for m in got_imu]
    np.testing.assert_array_equal([s.stamp_ns for s in samples], imu.stamps_ns)
    np.testing.assert_array_equal([s.gyro_rad_s for s in samples], imu.gyro_rad_s)
    np.testing.assert_array_equal([s.accel_m_s2 for s in samples], imu.accel_m_s2)
    jsamples = [joint_sample_from_msg(m) for m in got_joint]
    np.testing.assert_array_equal([s.stamp_ns for s in jsamples], joints.stamps_ns)
    np.testing.assert_array_equal([s.positions_rad for s in jsamples], joints.positions_rad)
    clock = np.array([stamp_ns_from_time(m.clock) for m in got_clock])
    assert np.all(np.diff(clock) >= 0)
    assert clock[0] == min(imu.stamps_ns[0], joints.stamps_ns[0])
    assert clock[-1] == max(imu.stamps_ns[-1], joints.stamps_ns[-1])


def test_bag_player_without_bag_says_so() -> None:
    out = subprocess.run([sys.executable, '-m', 'imu_calib_ros.nodes.bag_player'],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert 'bag is required' in out.stderr


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_bag_player_stops_cleanly_mid_play(bag: Path, sig: int) -> None:
    """A signal while playing: exit status 0 and no traceback (publishing on the context the
    signal had just shut down raised RCLError, exit 1)."""
    proc = subprocess.Popen([sys.executable, '-m', 'imu_calib_ros.nodes.bag_player',
                             '--ros-args', '-p', f'bag:={bag}', '-p', 'wait_for_subscribers:=0',
                             '-p', 'rate:=0.5'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    time.sleep(4.0)
    proc.send_signal(sig)
    out = proc.communicate(timeout=30)[0].decode(errors='replace')
    assert proc.returncode == 0, out
    assert 'Traceback' not in out, out
