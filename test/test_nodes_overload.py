"""Issue 16 item 8: lost input never gives a silent partial calibration.

Real rclpy over DDS: the calibration node runs as a child process started with --ros-args;
this process publishes a simulated spin (the core simulator) with IMU samples and joint
states left out, as a stream that lost them upstream, and listens to ``/diagnostics``.
Random ROS_DOMAIN_ID per session, localhost discovery, bounded waits.
"""
from __future__ import annotations

import os
import random
import signal
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest
import yaml

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 200)))  # conftest's
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402
from ros_helpers import spin_until, start_node, stop_node  # noqa: E402
from rclpy.node import Node  # noqa: E402

from imu_calib_ros.core.diagnostics import input_account  # noqa: E402
from imu_calib_ros.nodes.common import reliable_qos  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GAP_S = (8.0, 9.3)  # IMU samples lost while the table turns, longer than max_gap_s (1 s):
# the navigation restarts (a shorter gap is carried across with the encoders)
LOST_JOINTS = range(1400, 1405)  # five joint states lost later in the spin


@pytest.fixture(scope='module')
def ros() -> Iterator[Node]:
    rclpy.init(args=[])
    node = rclpy.create_node(f'test_overload_{os.getpid()}')
    yield node
    node.destroy_node()
    rclpy.try_shutdown()


@pytest.fixture(scope='module')
def spin() -> Any:
    """4 s at rest, then the outer axis at 20 deg/s for 20 s (no stationary window after the
    first): a MEMS unit at 200 Hz, joint states at 100 Hz."""
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.plans import build_profile, plan_from_dict
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fx = load_fixture('three_axis')
    plan = plan_from_dict({'name': 's', 'steps': [
        {'dwell': {'duration_s': 4}},
        {'spin': {'joint': 'outer', 'rate_deg_s': 20, 'duration_s': 20}}]})
    return simulate(fx, build_profile(plan, fx), load_grade('mems_mti1'),
                    SimConfig(imu_rate_hz=200, joint_rate_hz=100, seed=3))


def _publish(ros: Node, sim: Any, skip_imu: np.ndarray, skip_joint: set[int]) -> None:
    from sensor_msgs.msg import Imu, JointState
    from msg_adapters.convert import imu_msg_from_sample, \
        joint_state_msg_from_sample
    pub_i = ros.create_publisher(Imu, 'imu/data_raw', reliable_qos(5000))
    pub_j = ros.create_publisher(JointState, 'joint_states', reliable_qos(5000))
    try:
        assert spin_until(ros, lambda: pub_i.get_subscription_count() > 0
                          and pub_j.get_subscription_count() > 0, 90.0), 'node not matched'
        time.sleep(1.0)
        imu, jb = sim.imu, sim.joints
        events = sorted([(int(t), 0, i) for i, t in enumerate(jb.stamps_ns)
                         if i not in skip_joint]
                        + [(int(t), 1, i) for i, t in enumerate(imu.stamps_ns)
                           if not skip_imu[i]])
        for n, (_, kind, i) in enumerate(events):
            if kind == 0:
                pub_j.publish(joint_state_msg_from_sample(jb.sample(i), JointState))
            else:
                pub_i.publish(imu_msg_from_sample(imu.sample(i), Imu))
            if n % 30 == 0:  # ~4x real time: the node's queues never overflow
                rclpy.spin_once(ros, timeout_sec=0.0)
                time.sleep(0.03)
    finally:
        ros.destroy_publisher(pub_i)
        ros.destroy_publisher(pub_j)


def _status(diags: list[Any]) -> tuple[int, str, dict[str, str]]:
    s = [st for d in diags for st in d.status if st.name.endswith('IMU calibration')][-1]
    return s.level[0] if isinstance(s.level, bytes) else int(s.level), s.message, \
        {kv.key: kv.value for kv in s.values}


@pytest.mark.parametrize('force', [False, True])
def test_a_stopped_estimator_is_an_error_and_its_partial_calibration_is_not_saved_silently(
        ros: Node, spin: Any, tmp_path: Path, force: bool) -> None:
    """Samples lost while the table turns (longer than ``max_gap_s``) re-initialise the
    navigation; with no stationary
    window after it the filter never runs again. The node then says so and keeps saying so:
    WARN naming the restart, ERROR once the filter has been idle ``stopped_after_s`` of data
    (the estimator's own status falls back to OK after its 10 s hold: measured), the joint
    states lost upstream counted from their stamps; save on shutdown refuses (exit 1) unless
    ``force_save``, and what it writes says ``partial: used N of M samples, K navigation
    restarts`` on the terminal and under ``provenance.input`` in the file."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    sim = spin
    t = (sim.imu.stamps_ns - sim.imu.stamps_ns[0]) * 1e-9
    skip = (t > GAP_S[0]) & (t < GAP_S[1])
    out = tmp_path / 'calib.yaml'
    proc = start_node('calibration', {
        'fixture': 'three_axis', 'imu_grade': 'mems_mti1', 'estimator.auto_start': False,
        'estimator.noise_source': 'grade', 'stopped_after_s': 3.0, 'diagnostics_rate_hz': 4.0,
        'stale_timeout_s': 60.0,
        'output_file': str(out), 'save_on_shutdown': True, 'force_save': force}, tmp_path)
    diags: list[Any] = []
    sub = ros.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 100)
    try:
        _publish(ros, sim, skip, set(LOST_JOINTS))
        total = len(sim.imu)

        def settled() -> bool:
            return bool(diags) and int(_status(diags)[2].get('imu', 0)) + int(
                _status(diags)[2].get('missing_imu', 0)) >= total - 20
        spin_until(ros, settled, 30.0)
        spin_until(ros, lambda: False, 2.0)  # a few more periods: the level must stay
        level, message, values = _status(diags)
        levels = [int(s.level[0]) for d in diags for s in d.status
                  if s.name.endswith('IMU calibration')]
    finally:
        log = stop_node(proc, signal.SIGINT)
        ros.destroy_subscription(sub)
    assert level == int.from_bytes(DiagnosticStatus.ERROR, 'little'), (message, values)
    assert message.startswith('estimator stopped: partial: used '), message
    assert '1 navigation restart' in message, message
    # once WARN (the restart), never back to OK before the ERROR
    first_warn = levels.index(1)
    assert 0 not in levels[first_warn:], levels
    assert int(values['missing_imu']) == int(skip.sum()), values
    assert int(values['missing_joint']) == len(LOST_JOINTS), values
    m = int(values['imu']) + int(values['missing_imu'])
    # the first samples may go before DDS discovery completes (best effort), the last ones'
    # loss has no later stamp: neither can be counted
    assert total - 20 <= m <= total, (m, total)
    line = [ln for ln in log.splitlines() if 'save on shutdown' in ln]
    assert line, log[-3000:]
    assert 'partial: used ' in line[-1] and '1 navigation restart' in line[-1], line
    if not force:
        assert proc.returncode == 1, log[-3000:]
        assert 'not saved: the estimator stopped' in line[-1], line
        assert not out.exists()
        return
    assert proc.returncode == 0, log[-3000:]
    doc = yaml.safe_load(out.read_text())['imu_calibration']['provenance']['input']
    assert doc['partial'] is True and doc['navigation_restarts'] == 1, doc
    assert doc['lost_imu'] == int(skip.sum()) and doc['lost_joint_states'] == len(LOST_JOINTS)
    # the filter ran from the alignment at rest to the gap at 8 s, not after it: used
    # samples are that stretch only (within a block of 1000 samples of it)
    assert 1000 <= doc['used_samples'] <= 8.0 * 200, doc
    assert doc['samples'] == m and doc['summary'].startswith(
        f'partial: used {doc["used_samples"]} of {m} samples, 1 navigation restart'), doc
    assert 'STOPPED' in line[-1]


def test_input_account_counts() -> None:
    """The account's arithmetic: M = received + lost upstream, K = every navigation restart,
    partial as soon as anything was lost, dropped, rejected or restarted."""
    h = {'imu_processed': 900, 'gaps_reinitialised': 1, 'realignments': 2}
    a = input_account(h, 1000, 20, 0, 0, 0)
    assert (a['samples'], a['used_samples'], a['navigation_restarts']) == (1020, 900, 3)
    assert a['summary'] == 'partial: used 900 of 1020 samples, 3 navigation restarts'
    b = input_account({'imu_processed': 1000}, 1000, 0, 0, 0, 0)
    assert not b['partial'] and b['summary'].startswith('complete: used 1000 of 1000')
    assert input_account({'imu_processed': 1}, 1, 0, 0, 0, 1)['partial']
