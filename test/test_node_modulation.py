"""The ``modulation`` node over real DDS: its output equals the offline causal demodulation.

Node process started with --ros-args; rclpy publisher/subscriber in this process; random
ROS_DOMAIN_ID and localhost discovery; bounded waits; the child is stopped in ``finally``.
"""
from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

os.environ['ROS_DOMAIN_ID'] = str(random.randint(1, 200))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402
from ros_helpers import stop_node  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402

from imu_calib_ros.core.fixture import load_fixture  # noqa: E402
from imu_calib_ros.core.imu_grade import load_grade  # noqa: E402
from imu_calib_ros.core.methods import modulation as mod  # noqa: E402
from imu_calib_ros.core.plans import build_profile, plan_from_dict  # noqa: E402
from imu_calib_ros.core.simulator import SimConfig, simulate  # noqa: E402
from imu_calib_ros.msg_adapters.convert import (imu_msg_from_sample,  # noqa: E402
                                                imu_sample_from_msg,
                                                joint_state_msg_from_sample)
from imu_calib_ros.nodes.common import reliable_qos  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize('mode', ['continuous', 'four'])
def test_node_output_equals_offline_causal(mode: str) -> None:
    fx = load_fixture('three_axis')
    plan = plan_from_dict({'name': 'm', 'steps': [
        {'dwell': {'duration_s': 0.5}},
        # 11 s: ~4.4 revolutions, so the four-point mode has > 10 outputs after the first
        {'spin': {'imu_axis': 'z', 'rate_deg_s': 150, 'duration_s': 11, 'ramp_s': 0.5}},
        {'dwell': {'duration_s': 0.5}}]})
    sim = simulate(fx, build_profile(plan, fx), load_grade('mems_mti1'),
                   SimConfig(imu_rate_hz=100, joint_rate_hz=50, seed=2,
                             wrap_joint_positions=True))
    kw = {'causal': True} if mode == 'continuous' else {}
    ref = mod.demodulate(sim.imu, sim.joints, fx, mode, joint='inner', **kw)
    proc = subprocess.Popen(
        [sys.executable, '-m', 'imu_calib_ros.nodes.modulation', '--ros-args', '-p',
         'fixture:=three_axis', '-p', 'joint:=inner', '-p', f'mode:={mode}', '-p',
         'queue_depth:=5000', '-p', 'qos_overrides./imu/data_raw.subscription.reliability:='
         'reliable'], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    rclpy.init(args=[])
    node = rclpy.create_node(f'test_modulation_{os.getpid()}')
    got: dict[int, object] = {}
    try:
        pub_i = node.create_publisher(Imu, 'imu/data_raw', reliable_qos(5000))
        pub_j = node.create_publisher(JointState, 'joint_states', reliable_qos(5000))
        node.create_subscription(Imu, 'imu/data_body',
                                 lambda m: got.__setitem__(imu_sample_from_msg(m).stamp_ns,
                                                           imu_sample_from_msg(m)),
                                 reliable_qos(5000))
        deadline = time.monotonic() + 30.0
        while (pub_i.get_subscription_count() == 0 or pub_j.get_subscription_count() == 0
               or node.count_publishers('imu/data_body') == 0):
            assert time.monotonic() < deadline, 'node did not come up: ' + str(proc.poll())
            rclpy.spin_once(node, timeout_sec=0.1)
        events = sorted([(s.stamp_ns, 0, s) for s in sim.joints]
                        + [(s.stamp_ns, 1, s) for s in sim.imu], key=lambda e: (e[0], e[1]))
        for n, (_, kind, s) in enumerate(events):
            if kind == 0:
                pub_j.publish(joint_state_msg_from_sample(s, JointState))
            else:
                pub_i.publish(imu_msg_from_sample(s, Imu))
            if n % 20 == 0:
                rclpy.spin_once(node, timeout_sec=0.0)
                time.sleep(0.005)  # keep the node's queues from overflowing
        deadline = time.monotonic() + 20.0
        last = ref.stamps_ns[-1]  # wait for the whole reference stream (or the deadline)
        while int(last) not in got and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    log = stop_node(proc, wait_s=10.0)
    idx = {int(t): i for i, t in enumerate(ref.stamps_ns)}
    common = [t for t in got if t in idx]
    # output starts after one revolution (2.9 s at 150 deg/s incl. the ramp): the offline
    # stream has outputs from its first samples (its first-revolution bias is non-causal)
    later = [t for t in idx if t >= min(got, default=0)]
    assert len(common) >= 0.95 * len(later) > 10, (len(common), len(later), log[-2000:])
    for t in common:
        s = got[t]
        i = idx[t]
        # identical arithmetic; messages carry float64: agreement to rounding
        np.testing.assert_allclose(s.gyro_rad_s, ref.gyro_rad_s[i], rtol=0, atol=1e-9)
        np.testing.assert_allclose(s.accel_m_s2, ref.accel_m_s2[i], rtol=0, atol=1e-9)
        assert s.frame_id == f'{sim.imu.frame_id}_body'
