"""Issue 17 item 2 live: the calibration node's save service and save on shutdown refuse a run
that fails its self-check (no file; exit 1 after a refused save on shutdown) unless
``force_save``, which writes it marked as failing. Real DDS, as test/test_nodes.py."""
from __future__ import annotations

import os
import random
import signal
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 200)))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402
from ros_helpers import spin_until, start_node, stop_node  # noqa: E402
from rclpy.node import Node  # noqa: E402

from imu_calib_ros.core.config import share_dir  # noqa: E402

# 16 s at 200 Hz: the tilted axis shows in the dwell after each of the two turns
PLAN = ('name: t\ndescription: short\nsteps:\n  - dwell: {duration_s: 4}\n'
        '  - rotate_imu: {axis: z, angle_deg: 180, duration_s: 3}\n'
        '  - dwell: {duration_s: 3}\n'
        '  - rotate_imu: {axis: z, angle_deg: -180, duration_s: 3}\n'
        '  - dwell: {duration_s: 3}\n')
# the simulator exits after the plan and 1 s of holding: the same data in every run (a
# simulator left running until the save held a varying length of rest at the end)
PLAN_IMU_SAMPLES = 3400


@pytest.fixture(scope='module')
def ros() -> Iterator[Node]:
    rclpy.init(args=[])
    node = rclpy.create_node(f'test_nodes_selfcheck_{os.getpid()}')
    yield node
    node.destroy_node()
    rclpy.try_shutdown()


def wrong_fixture(tmp: Path, rotvec_deg: tuple[float, float, float] = (2.0, 0.0, 0.0)) -> Path:
    """three_axis with its inner axis (the plan's rotation, north) tilted 2 deg up: gravity in
    the dwell after each turn is 4 deg from where the fixture puts it (windows chi2/dof about
    1,000). Tilted about the vertical instead, the axis error is nearly a gyro misalignment
    on this one-axis plan: earth rate alone shows it, and runs passed or failed by chance."""
    d = yaml.safe_load((share_dir() / 'config' / 'fixtures' / 'three_axis.yaml').read_text())
    d['joints'][2]['axis'] = [float(x) for x in Rotation.from_rotvec(
        np.radians(rotvec_deg)).apply(d['joints'][2]['axis'])]
    p = tmp / 'wrong_fixture.yaml'
    p.write_text(yaml.safe_dump(d))
    return p


def received(diags: list[Any]) -> int:
    """The node's count of raw IMU samples received, from its latest /diagnostics."""
    st = [d.status[0] for d in diags if d.status and d.status[0].name.endswith('IMU calibration')]
    values = {kv.key: kv.value for kv in st[-1].values} if st else {}
    return int(values.get('imu', 0))


def run_and_save(ros: Node, tmp: Path, force: bool,
                 rotvec_deg: tuple[float, float, float] = (2.0, 0.0, 0.0)
                 ) -> tuple[Any, str, int | None, Path]:
    """Simulated plan into a node with the wrong fixture; ~/save_calibration at the end, then
    SIGINT (save on shutdown). Returns (service response, log, exit status, output path)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import Trigger
    plan = tmp / 'plan.yaml'
    plan.write_text(PLAN)
    out = tmp / 'calib.yaml'
    # the coarse start waits for the save's flush (bootstrap_min_s beyond the plan): measured
    # on every sample, as imu-calib replay does, not on what a busy machine had delivered
    # when it first looked determined (such a start once let this run pass its self-check)
    fixture = str(wrong_fixture(tmp, rotvec_deg))
    cal = start_node('calibration', {'fixture': fixture, 'use_sim_time': True,
                                     'output_file': str(out), 'save_on_shutdown': True,
                                     'force_save': force, 'diagnostics_rate_hz': 2.0,
                                     'estimator.bootstrap_min_s': 1000.0,
                                     # every sample, even on a loaded machine: the 2 deg
                                     # tilt shows at chi2/dof 3.5-3.7 against 2.62 on the
                                     # whole record, and a 3 % best-effort loss once let the
                                     # run pass (CI, fresh clone)
                                     'queue_depth': 20000}, tmp)
    sim = start_node('turntable_sim', {'plan': str(plan), 'speed': 2.0,
                                       'wait_for_subscribers': 1, 'start_stamp_s': 5000.0,
                                       'exit_when_done': True, 'exit_after_s': 1.0}, tmp)
    diags: list[Any] = []
    sub = ros.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 50)
    save = ros.create_client(Trigger, '/calibration/save_calibration')
    log, status, resp = '', None, None
    try:
        assert save.wait_for_service(timeout_sec=60.0), stop_node(cal)
        assert spin_until(ros, lambda: sim.poll() is not None, 90.0), \
            stop_node(sim) + stop_node(cal)
        # every sample the node received is with the estimator (a busy machine delays them;
        # a best-effort loss ends the wait after 20 s, and the node's account says partial)
        spin_until(ros, lambda: received(diags) >= PLAN_IMU_SAMPLES, 20.0)
        fut = save.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(ros, fut, timeout_sec=60.0)
        resp = fut.result()
    finally:
        log = stop_node(sim)
        if resp is not None:
            log += stop_node(cal, signal.SIGINT, wait_s=120.0)
            status = cal.returncode
        else:
            log += stop_node(cal)
        ros.destroy_subscription(sub)
        ros.destroy_client(save)
    return resp, log, status, out


def test_a_run_failing_its_self_check_is_not_saved(ros: Node, tmp_path: Path) -> None:
    resp, log, status, out = run_and_save(ros, tmp_path, force=False)
    assert resp is not None and not resp.success, (resp, log[-3000:])
    assert 'self-check failed' in resp.message and 'force_save' in resp.message, resp.message
    assert status == 1, log[-2000:]  # the refused save on shutdown
    assert 'save on shutdown: not saved, self-check failed' in log, log[-2000:]
    assert not out.exists()
    assert 'Traceback' not in log, log


def test_force_save_writes_it_marked_as_failing(ros: Node, tmp_path: Path) -> None:
    from imu_calib_ros.core.calibration import CalibrationResult
    resp, log, status, out = run_and_save(ros, tmp_path, force=True)
    assert resp is not None, log[-3000:]
    if not resp.success:
        # a loaded machine lost samples and the filter had just diverged at the service's
        # save: refused with that reason (never 'no data'); the save on shutdown, after the
        # restart, writes it marked (checked below)
        assert resp.message.startswith('nothing to save yet: the estimator diverged'), \
            (resp, log[-3000:])
        assert 'FAILED its self-check: written because of force_save' in log, log[-3000:]
    else:
        assert 'FAILED its self-check' in resp.message, resp.message
    assert status == 0, log[-2000:]
    v = CalibrationResult.load(out).extra['provenance']['self_check']
    assert v['passed'] is False and v['forced'] is True, v
    assert v['summary'].startswith('FAILED, written with force: self-check failed')
    assert 'Traceback' not in log, log



def test_a_fixture_the_gyros_contradict_is_named_at_the_save(ros: Node, tmp_path: Path) -> None:
    """The inner axis reversed (turned 180 deg about the vertical): the coarse start refuses
    (the gyro outputs do not follow the encoder rotations). The save says that, not 'no IMU
    data yet' (it said so, with 3,400 samples received)."""
    resp, log, status, out = run_and_save(ros, tmp_path, force=False, rotvec_deg=(0, 0, 180.0))
    assert resp is not None and not resp.success, (resp, log[-3000:])
    assert 'do not follow the' in resp.message, resp.message
    assert 'not used any IMU data' not in resp.message, resp.message
    assert status == 1, log[-2000:]  # the save on shutdown is refused too, with the reason
    assert 'save on shutdown: nothing to save' in log and 'do not follow' in log, log[-2000:]
    assert not out.exists()
    assert 'Traceback' not in log, log
