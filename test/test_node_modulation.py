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

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 200)))  # conftest's
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402
from ros_helpers import stop_node  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402

from imu_calib_ros.core.fixture import load_fixture  # noqa: E402
from imu_calib_ros.core.imu_grade import load_grade  # noqa: E402
from imu_calib_ros.core.methods import modulation as mod  # noqa: E402
from imu_calib_ros.core.plans import build_profile, plan_from_dict  # noqa: E402
from imu_calib_ros.core.simulator import SimConfig, simulate  # noqa: E402
from msg_adapters.convert import (imu_msg_from_sample,  # noqa: E402
                                  imu_sample_from_msg,
                                  joint_state_msg_from_sample)
from imu_calib_ros.nodes.common import reliable_qos  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize('mode', ['continuous', 'four'])
def test_node_output_equals_offline_causal(mode: str) -> None:
    _node_equals_offline(mode, ['fixture:=three_axis'])


def test_node_takes_the_urdf_from_robot_description() -> None:
    """``fixture:=robot_description`` (issue 15, the calibration node's loader): the shipped
    table as URDF (config/fixtures/three_axis.urdf) on the topic, latched as
    robot_state_publisher publishes it; the node says what it built and its output equals
    the offline demodulation with the YAML fixture, sample for sample."""
    log = _node_equals_offline('continuous', [
        'fixture:=robot_description', 'base_link:=base_link', 'imu_link:=imu_link'],
        urdf=(ROOT / 'config' / 'fixtures' / 'three_axis.urdf').read_text())
    assert 'fixture from URDF <robot_description>: chain base_link -> imu_link, 3 joints ' \
        '[outer (continuous), middle (continuous), inner (continuous)]' in log, log[-2000:]


def test_node_refuses_urdf_parameters_with_a_yaml_fixture(tmp_path: Path) -> None:
    """The URDF parameters are the calibration node's (one owner): with a YAML fixture they
    are refused, one line, exit 2; an unknown link of a URDF file too."""
    for params, words in ((['fixture:=three_axis', 'imu_link:=imu_link'],
                           'imu_link applies to a URDF fixture only'),
                          (['fixture:=three_axis.urdf', 'imu_link:=tool9'],
                           "imu_link: no link 'tool9'")):
        cmd = [sys.executable, '-m', 'imu_calib_ros.nodes.modulation', '--ros-args']
        for p in params:
            cmd += ['-p', p]
        out = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=60)
        err = [ln for ln in (out.stdout + out.stderr).splitlines()
               if ln.startswith('modulation: error:')]
        assert out.returncode == 2 and len(err) == 1 and words in err[0], out


def _node_equals_offline(mode: str, fixture_params: list[str], urdf: str = '') -> str:
    """Run the node with ``fixture_params`` on a simulated spin of the three-axis table's
    inner axis; assert its output equals the offline demodulation; its log. ``urdf``:
    published on ``robot_description`` (transient local) before the node starts."""
    fx = load_fixture('three_axis')
    plan = plan_from_dict({'name': 'm', 'steps': [
        {'dwell': {'duration_s': 0.5}},
        # 11 s: ~4.4 revolutions, so the four-point mode has > 10 outputs after the first
        {'spin': {'imu_axis': 'z', 'rate_deg_s': 150, 'duration_s': 11, 'ramp_s': 0.5}},
        {'dwell': {'duration_s': 0.5}}]})
    sim = simulate(fx, build_profile(plan, fx), load_grade('mems_mti1'),
                   SimConfig(imu_rate_hz=100, joint_rate_hz=50, seed=2,
                             wrap_joint_positions=True))
    ref = mod.demodulate(sim.imu, sim.joints, fx, mod.DemodulationOptions(
        mode, joint='inner', causal=mode == 'continuous'))
    rclpy.init(args=[])
    node = rclpy.create_node(f'test_modulation_{os.getpid()}')
    if urdf:
        from std_msgs.msg import String

        from imu_calib_ros.nodes.common import latched_qos
        desc = node.create_publisher(String, 'robot_description', latched_qos())
        desc.publish(String(data=urdf))
    params = [x for p in fixture_params for x in ('-p', p)]
    proc = subprocess.Popen(
        [sys.executable, '-m', 'imu_calib_ros.nodes.modulation', '--ros-args', *params,
         '-p', 'joint:=inner', '-p', f'mode:={mode}', '-p',
         'queue_depth:=5000', '-p', 'qos_overrides./imu/data_raw.subscription.reliability:='
         'reliable'], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
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
    return log


def test_node_under_sample_loss_is_right_or_withholds_and_says_so() -> None:
    """Issue 16 item 3 over DDS. The inner axis (horizontal: gravity turns in the sensor
    frame) spins at 150 deg/s; bursts of raw samples (5-20) are never sent, and one stretch
    of 1 s (150 deg, 42 % of a revolution). Every output the node publishes is within
    0.01 m/s^2 of the offline result on the loss-free data (before: up to 2.5 m/s^2 off, no
    warning); the outputs whose revolution lost more than 25 % are withheld and counted;
    ``/diagnostics`` (the node published none before) counts each lost sample and says WARN
    while it happens."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    fx = load_fixture('three_axis')
    plan = plan_from_dict({'name': 'm', 'steps': [
        {'dwell': {'duration_s': 0.5}},
        {'spin': {'joint': 'inner', 'rate_deg_s': 150, 'duration_s': 16, 'ramp_s': 0.5}},
        {'dwell': {'duration_s': 0.5}}]})
    sim = simulate(fx, build_profile(plan, fx), load_grade('mems_mti1'),
                   SimConfig(imu_rate_hz=100, joint_rate_hz=50, seed=4))
    full = mod.demodulate(sim.imu, sim.joints, fx,
                          mod.DemodulationOptions(joint='inner', causal=True))
    n = len(sim.imu)
    rng = np.random.default_rng(5)
    skip = np.zeros(n, bool)
    for s in rng.choice(np.arange(300, n - 300), 12, replace=False):
        skip[s:s + rng.integers(5, 21)] = True
    skip[900:1000] = True  # 1 s
    proc = subprocess.Popen(
        [sys.executable, '-m', 'imu_calib_ros.nodes.modulation', '--ros-args', '-p',
         'fixture:=three_axis', '-p', 'joint:=inner', '-p', 'queue_depth:=5000', '-p',
         'diagnostics_rate_hz:=4.0', '-p', 'stale_timeout_s:=30.0', '-p',
         'qos_overrides./imu/data_raw.subscription.reliability:=reliable'],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    rclpy.init(args=[])
    node = rclpy.create_node(f'test_modulation_loss_{os.getpid()}')
    got: dict[int, object] = {}
    diags: list[DiagnosticArray] = []
    try:
        pub_i = node.create_publisher(Imu, 'imu/data_raw', reliable_qos(5000))
        pub_j = node.create_publisher(JointState, 'joint_states', reliable_qos(5000))
        node.create_subscription(Imu, 'imu/data_body',
                                 lambda m: got.__setitem__(imu_sample_from_msg(m).stamp_ns,
                                                           imu_sample_from_msg(m)),
                                 reliable_qos(5000))
        node.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 100)
        deadline = time.monotonic() + 30.0
        while (pub_i.get_subscription_count() == 0 or pub_j.get_subscription_count() == 0
               or node.count_publishers('imu/data_body') == 0):
            assert time.monotonic() < deadline, 'node did not come up: ' + str(proc.poll())
            rclpy.spin_once(node, timeout_sec=0.1)
        events = sorted([(s.stamp_ns, 0, s) for s in sim.joints]
                        + [(s.stamp_ns, 1, s) for i, s in enumerate(sim.imu) if not skip[i]],
                        key=lambda e: (e[0], e[1]))
        for k, (_, kind, s) in enumerate(events):
            if kind == 0:
                pub_j.publish(joint_state_msg_from_sample(s, JointState))
            else:
                pub_i.publish(imu_msg_from_sample(s, Imu))
            if k % 20 == 0:
                rclpy.spin_once(node, timeout_sec=0.0)
                time.sleep(0.02)  # ~2.5x real time: the diagnostics see the losses happen
        deadline = time.monotonic() + 15.0
        last = int(sim.imu.stamps_ns[~skip][-1])

        def counted() -> dict[str, str]:
            st = [s for d in diags for s in d.status if 'demodulation' in s.name]
            return {kv.key: kv.value for kv in st[-1].values} if st else {}
        while (last not in got or int(counted().get('imu_in', 0)) < int((~skip).sum())) \
                and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        values = counted()
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    log = stop_node(proc, wait_s=10.0)
    idx = {int(t): i for i, t in enumerate(full.stamps_ns)}
    t0 = int(sim.imu.stamps_ns[0])
    steady = [t for t in got if t0 + 4_000_000_000 < t < t0 + 16_500_000_000]
    assert len(steady) > 700, (len(got), log[-2000:])
    err = max(float(np.max(np.abs(np.asarray(got[t].accel_m_s2) - full.accel_m_s2[idx[t]])))
              for t in steady)
    # noise of the fit over a revolution with its holes: 3 x 120 ug/sqrt(Hz) / sqrt(2.4 s)
    # x 3 = 7e-3 m/s^2; the plain mean was off by up to 2.5 m/s^2
    print(f'largest accel error {err:.4f} m/s^2 over {len(steady)} outputs; {values}')
    assert err < 0.01, err
    assert int(values['lost_imu']) == int(skip.sum()), (values, int(skip.sum()))
    withheld = int(values['withheld_low_coverage'])
    # the 1 s hole (150 deg) leaves < 75 % of a revolution for ~1 revolution of outputs
    assert 50 < withheld < 400, values
    assert int(values['fitted_after_loss']) > 200, values
    # every sample in is out, withheld, or before the first revolution
    assert int(values['published']) + withheld + int(values['warming_up']) >= \
        int(values['imu_in']) - 5, values
    levels = [s.level for d in diags for s in d.status if 'demodulation' in s.name]
    assert DiagnosticStatus.WARN in levels, levels
    assert 'Traceback' not in log, log[-2000:]
