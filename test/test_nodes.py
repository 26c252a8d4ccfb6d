"""Nodes over real DDS: node processes started with --ros-args, rclpy test node in this process.

No mocks of ROS. Each test session uses its own random ROS_DOMAIN_ID (set before rclpy starts)
and localhost discovery, so parallel workers do not see each other; every child process is
stopped in a ``finally``. Waits are generous (discovery on a loaded 2-core machine) but bounded.
"""
from __future__ import annotations

import os
import random
import signal
import subprocess
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 200)))  # conftest's
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402
from ros_helpers import spin_until, start_node, stop_node  # noqa: E402
from rclpy.node import Node  # noqa: E402

from imu_calib_ros.core.calibration import CalibrationResult  # noqa: E402
from imu_calib_ros.core.sensor_model import compensate, mean_rate_derivative  # noqa: E402
from imu_calib_ros.core.types import ImuSample  # noqa: E402
from msg_adapters.convert import imu_msg_from_sample  # noqa: E402
from imu_calib_ros.nodes.common import latched_qos, reliable_qos  # noqa

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope='module')
def ros() -> Iterator[Node]:
    rclpy.init(args=[])
    node = rclpy.create_node(f'test_nodes_{os.getpid()}')
    yield node
    node.destroy_node()
    rclpy.try_shutdown()


def start(module: str, params: dict[str, Any], cwd: Path) -> subprocess.Popen[bytes]:
    if module == 'calibration':  # no default fixture: the tests' simulated table
        params = {'fixture': 'three_axis', **params}
    return start_node(module, params, cwd)


def stop(proc: subprocess.Popen[bytes], sig: int = signal.SIGINT) -> str:
    return stop_node(proc, sig, wait_s=10.0)


def known_calibration(tmp: Path, frame_id: str = 'imu_link') -> tuple[CalibrationResult, Path]:
    """A calibration with every term non-zero (MEMS-sized errors) and sigmas."""
    from imu_calib_ros.core.imu_grade import draw_errors, load_grade
    grade = load_grade('mems_mti1')
    errors = draw_errors(grade, np.random.default_rng(3))
    sigma = draw_errors(grade, np.random.default_rng(4))
    sigma = type(sigma).from_vector(np.abs(sigma.as_vector()))
    result = CalibrationResult(errors=errors, sigma=sigma, frame_id=frame_id)
    path = tmp / 'calib.yaml'
    result.save(path)
    return CalibrationResult.load(path), path


def feed_imu(ros: Node, pub: Any, stamps: Any, gyro: Any, accel: Any,
             got: list[Any] | None = None, in_flight: int = 50,
             answer_s: float = 30.0) -> int:
    """Publish raw IMU samples at ~500 Hz of wall time, spinning the test node between them.

    With ``got`` (the node's output as it arrives) the samples go one at a time until the node
    answers the first: a best-effort reader matches its writer a moment after the writer saw
    the reader (DDS discovery), and what is published in between is lost. The node's stream
    then starts at the first sample it got, and the returned index says which one. After that
    at most ``in_flight`` samples are ahead of the output: on a loaded machine the node's
    best-effort input and its reliable keep-last output otherwise drop a burst that the test
    never meant to be an overload test (the stamps, not the wall-clock pace, carry the rate
    the node measures). An output that stays behind for ``answer_s`` fails at once (a lost
    sample would otherwise hold every later one for the whole wait).
    """
    from sensor_msgs.msg import Imu
    for k in range(len(stamps)):
        if got is not None and not got and k > 0:
            spin_until(ros, lambda: bool(got), 5.0)  # the handshake: one at a time
        elif got is not None and k - len(got) >= in_flight:
            assert spin_until(ros, lambda: k - len(got) < in_flight, answer_s), \
                f'the node answered {len(got)} of {k} samples'
        pub.publish(imu_msg_from_sample(ImuSample(int(stamps[k]), gyro[k], accel[k],
                                                  'imu_link'), Imu))
        rclpy.spin_once(ros, timeout_sec=0.0)
        time.sleep(0.002)
    if got is None:
        return 0
    assert spin_until(ros, lambda: bool(got), answer_s), 'the node answered no sample'
    first = got[0].header.stamp.sec * 10**9 + got[0].header.stamp.nanosec
    return int(np.searchsorted(np.asarray(stamps, dtype=np.int64), first))


def test_compensator_stamps_values_bit_for_bit(ros: Node, tmp_path: Path) -> None:
    """Corrected IMU: same stamps and frame, REP-145 marker, values = offline compensation."""
    from sensor_msgs.msg import Imu
    calib, path = known_calibration(tmp_path)
    proc = start('compensator', {'calibration_file': str(path), 'imu_rate_hz': 200.0,
                                 'imu_grade': 'mems_mti1'}, tmp_path)
    got: list[Any] = []
    sub = ros.create_subscription(Imu, 'imu/data_corrected', got.append, reliable_qos(1000))
    pub = ros.create_publisher(Imu, 'imu/data_raw', reliable_qos(1000))
    try:
        assert spin_until(ros, lambda: pub.get_subscription_count() > 0
                          and sub.get_publisher_count() > 0, 60.0), stop(proc)
        time.sleep(0.5)
        rng = np.random.default_rng(7)
        n = 300
        stamps = 5_000_000_000 + 5_000_000 * np.arange(1, n + 1, dtype=np.int64)
        stamps[150:] += 20_000_000  # a gap: the rate derivative restarts there
        t = (stamps - stamps[0]) * 1e-9
        gyro = np.c_[np.sin(3 * t), 0.5 * np.cos(2 * t), 0.2 * t] + rng.normal(0, 1e-3, (n, 3))
        accel = np.c_[0.1 * t, -0.2 + 0 * t, 9.81 + 0 * t] + rng.normal(0, 1e-2, (n, 3))
        first = feed_imu(ros, pub, stamps, gyro, accel, got)
        # the node's stream starts at the first sample it got (see feed_imu)
        stamps, gyro, accel, n, gap = stamps[first:], gyro[first:], accel[first:], n - first, \
            150 - first
        assert gap > 50, first
        assert spin_until(ros, lambda: len(got) >= n, 30.0), f'{len(got)} of {n}'
    finally:
        log = stop(proc)
        ros.destroy_subscription(sub)
        ros.destroy_publisher(pub)
    assert proc.returncode == 0, (proc.returncode, log)

    out_stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in got])
    np.testing.assert_array_equal(out_stamps, stamps, err_msg=log)
    assert all(m.header.frame_id == 'imu_link' for m in got)
    assert all(m.orientation_covariance[0] == -1.0 for m in got)
    omega = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                      for m in got])
    f = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                  for m in got])
    # offline: the core's compensate, one sample per call (a batch call may differ in the
    # last bit: BLAS matmul is not row-independent), omega_dot from
    # the causal difference with the 1.5-period gap rule
    omega_dot = mean_rate_derivative(stamps, gyro, causal=True, nominal_period_s=0.005)
    assert np.all(omega_dot[gap] == 0) and np.any(omega_dot[gap + 1] != 0)
    ref = [compensate(calib.errors, gyro[k:k + 1], accel[k:k + 1],
                      omega_dot_imu_rad_s2=omega_dot[k:k + 1]) for k in range(n)]
    omega_ref = np.vstack([r[0] for r in ref])
    f_ref = np.vstack([r[1] for r in ref])
    np.testing.assert_array_equal(omega, omega_ref)  # bit for bit
    np.testing.assert_array_equal(f, f_ref)
    # the correction is real: raw and corrected differ by about the calibration errors
    assert np.max(np.abs(omega - gyro)) > 10 * np.max(np.abs(omega - omega_ref) + 1e-300)
    # covariance: at least the white noise of the mean, N^2 / dt, on the diagonal
    from imu_calib_ros.core.imu_grade import load_grade
    g = load_grade('mems_mti1')
    var_w = np.array([m.angular_velocity_covariance[0] for m in got])
    assert np.all(var_w >= g.gyro_noise_rad_s_rt_hz ** 2 / 0.005 * (1 - 1e-12))
    assert np.all(var_w >= calib.sigma.gyro_bias_rad_s[0] ** 2)


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_compensator_stops_cleanly_on_a_signal(ros: Node, tmp_path: Path, sig: int) -> None:
    """Idle (no input), then SIGINT or SIGTERM: exit status 0. Its input thread, left
    waiting in rcl while the node and the context went away, aborted the process (SIGABRT,
    'terminate called without an active exception', exit 134)."""
    from sensor_msgs.msg import Imu
    _, path = known_calibration(tmp_path)
    proc = start('compensator', {'calibration_file': str(path)}, tmp_path)
    sub = ros.create_subscription(Imu, 'imu/data_corrected', lambda m: None, reliable_qos(10))
    try:
        assert spin_until(ros, lambda: sub.get_publisher_count() > 0, 60.0), stop(proc)
        time.sleep(1.0)
    finally:
        log = stop(proc, sig)
        ros.destroy_subscription(sub)
    assert proc.returncode == 0, (proc.returncode, log)
    assert 'terminate called' not in log, log


def test_compensator_refuses_other_frame_and_bad_file(ros: Node, tmp_path: Path) -> None:
    _, path = known_calibration(tmp_path, frame_id='imu_link')
    proc = start('compensator', {'calibration_file': str(path), 'frame_id': 'other_imu'},
                 tmp_path)
    assert proc.wait(60) == 2
    log = stop(proc)
    assert 'imu_link' in log and 'other_imu' in log
    text = path.read_text().replace('format_version: 1', 'format_version: 9')
    bad = tmp_path / 'bad.yaml'
    bad.write_text(text)
    proc = start('compensator', {'calibration_file': str(bad)}, tmp_path)
    assert proc.wait(60) == 2
    assert 'format_version' in stop(proc)


def test_calibration_node_services_sim_time_and_latched_estimates(ros: Node,
                                                                  tmp_path: Path) -> None:
    """A short simulated run (sim publishes /clock): save reloads, estimates latched, reset."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Vector3Stamped
    from std_srvs.srv import Trigger
    out = tmp_path / 'calib_out.yaml'
    truth = tmp_path / 'truth.yaml'
    plan = tmp_path / 'plan.yaml'
    plan.write_text('name: t\ndescription: short\nsteps:\n  - dwell: {duration_s: 4}\n'
                    '  - rotate_imu: {axis: z, angle_deg: 180, duration_s: 3}\n'
                    '  - dwell: {duration_s: 3}\n')
    # 10 s with one half turn: the run fails its self-check (issue 17), force_save writes it
    cal = start('calibration', {'use_sim_time': True, 'output_file': str(out),
                                'estimate_rate_hz': 2.0, 'diagnostics_rate_hz': 2.0,
                                'force_save': True}, tmp_path)
    sim = start('turntable_sim', {'plan': str(plan), 'speed': 2.0, 'truth_file': str(truth),
                                  'wait_for_subscribers': 1, 'start_stamp_s': 5000.0},
                tmp_path)
    diags: list[Any] = []
    sub = ros.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 50)
    save = ros.create_client(Trigger, '/calibration/save_calibration')
    reset = ros.create_client(Trigger, '/calibration/reset')
    try:
        assert save.wait_for_service(timeout_sec=60.0), stop(cal)
        ok = spin_until(ros, lambda: any(d.header.stamp.sec >= 5008 for d in diags), 90.0)
        assert ok, f'{len(diags)} diagnostics\n{stop(sim)}\n{stop(cal)}'
        # use_sim_time: the node's clock is the simulated /clock (starts at 5000 s)
        stamps = [d.header.stamp.sec for d in diags if d.status[0].name.endswith('calibration')]
        assert stamps and min(stamps) >= 5000 and max(stamps) < 5100
        last = [d for d in diags if d.status[0].name.endswith('IMU calibration')][-1].status[0]
        values = {kv.key: kv.value for kv in last.values}
        assert float(values['imu_rate_hz']) == pytest.approx(200.0, rel=0.3), values
        assert 'rejected.node.frame_id' not in values  # zero counters are left out
        fut = save.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(ros, fut, timeout_sec=60.0)
        assert fut.result() is not None and fut.result().success, fut.result()
        saved = CalibrationResult.load(out)
        assert saved.frame_id == 'imu_link'
        assert np.all(np.isfinite(saved.sigma.as_vector()))
        verdict = saved.extra['provenance']['self_check']
        assert verdict['passed'] or verdict['forced'], verdict
        # late subscriber gets the latest estimate (transient local)
        late: list[Any] = []
        lsub = ros.create_subscription(Vector3Stamped, '/calibration/gyro_bias_sigma',
                                       late.append, latched_qos())
        assert spin_until(ros, lambda: len(late) > 0, 30.0)
        assert late[-1].vector.x > 0
        ros.destroy_subscription(lsub)
        fut = reset.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(ros, fut, timeout_sec=30.0)
        assert fut.result() is not None and fut.result().success
    finally:
        log = stop(sim) + stop(cal)
        ros.destroy_subscription(sub)
    assert 'Traceback' not in log, log


def test_estimates_converge_on_a_short_plan(ros: Node, tmp_path: Path) -> None:
    """turntable_sim (34 s: Savage's flip sequences 4 and 5, sim time at 4x) -> calibration node:
    the saved estimate is consistent with the simulator's truth within 4 sigma, and the
    data shrank the uncertainty of the accelerometer biases well below the prior."""
    from std_srvs.srv import Trigger
    from imu_calib_ros.core.config import resolve_config_file
    from imu_calib_ros.core.estimator import CalibrationEstimator
    from imu_calib_ros.core.estimator.config import EstimatorConfig
    from imu_calib_ros.core.fixture import Fixture
    from imu_calib_ros.core.imu_grade import load_grade
    out = tmp_path / 'calib_out.yaml'
    truth = tmp_path / 'truth.yaml'
    plan = tmp_path / 'plan.yaml'
    plan.write_text("name: t\ndescription: short\nsteps:\n  - dwell: {duration_s: 5}\n"
                    "  - srt_sequence: {id: '4', dwell_s: 3, rotation_s: 3}\n"
                    "  - srt_sequence: {id: '5', dwell_s: 3, rotation_s: 3}\n")  # 34 s
    # a navigation-grade unit: the hint separates bias, asymmetry and quadratic terms, which
    # flips between +1 g and -1 g alone cannot (a raw unit would need more poses)
    cal = start('calibration', {'use_sim_time': True, 'output_file': str(out),
                                'imu_grade': 'nav_grade'}, tmp_path)
    sim = start('turntable_sim', {'plan': str(plan), 'speed': 4.0, 'truth_file': str(truth),
                                  'wait_for_subscribers': 1}, tmp_path)
    from diagnostic_msgs.msg import DiagnosticArray
    diags: list[Any] = []
    sub = ros.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 50)
    save = ros.create_client(Trigger, '/calibration/save_calibration')
    try:
        assert save.wait_for_service(timeout_sec=60.0), stop(cal)
        # the node's clock is the sim's /clock (from 1000 s): wait for the plan's end
        done = spin_until(ros, lambda: any(d.header.stamp.sec >= 1036 for d in diags), 150.0)
        assert done, f'{len(diags)} diagnostics\n{stop(sim)}'
        fut = save.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(ros, fut, timeout_sec=90.0)
        assert fut.result() is not None and fut.result().success, fut.result()
    finally:
        log = stop(sim) + stop(cal)
        ros.destroy_client(save)
        ros.destroy_subscription(sub)
    assert out.exists() and truth.exists(), log[-3000:]
    est = CalibrationResult.load(out)
    true = CalibrationResult.load(truth)
    fx = Fixture.from_yaml(resolve_config_file('three_axis', 'fixtures'))
    prior = CalibrationEstimator(fx, load_grade('nav_grade'), EstimatorConfig()).estimate()
    e, t, s, p = (x.as_vector() for x in (est.errors, true.errors, est.sigma, prior.sigma))
    on = s > 0
    z = np.abs(e - t)[on] / s[on]
    assert np.all(z < 4.0), (np.max(z), log[-3000:])
    from imu_calib_ros.core.sensor_model import PARAMETER_SLICES as SL
    # 34 s at rest and flipping: the accelerometer biases are observed (gravity reverses
    # on every axis); a nav-grade gyro bias (~0.01 deg/h) needs far longer and is not checked
    shrink = s[SL['accelerometer.bias']] / p[SL['accelerometer.bias']]
    assert np.all(shrink < 0.5), shrink


def test_calibration_node_detects_the_imu_rate(ros: Node, tmp_path: Path) -> None:
    """No imu_rate_hz (default 0 = detect): 100 Hz raw IMU. The corrected covariance is the
    noise of the mean for dt = 0.01 s (N^2/dt, plus the prior's propagated sigmas: the
    estimator never aligns without joint states), from the second sample on; the node counts
    no missing samples and reports the measured rate. With a 200 Hz default, as before, the
    noise term would be twice as large and every interval would count one sample missing."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Imu
    from imu_calib_ros.core.config import resolve_config_file
    from imu_calib_ros.core.estimator import CalibrationEstimator
    from imu_calib_ros.core.estimator.config import EstimatorConfig
    from imu_calib_ros.core.fixture import Fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.stream_compensation import StreamCompensation
    # the grade hint gives the corrected stream its noise term (no grade: calibration
    # uncertainty only, until one is given)
    proc = start('calibration', {'diagnostics_rate_hz': 5.0, 'estimator_mode': 'thread',
                                 'imu_grade': 'nav_grade'}, tmp_path)
    got: list[Any] = []
    diags: list[Any] = []
    sub = ros.create_subscription(Imu, 'imu/data_corrected', got.append, reliable_qos(1000))
    dsub = ros.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 50)
    pub = ros.create_publisher(Imu, 'imu/data_raw', reliable_qos(1000))
    n = 300
    stamps = 7_000_000_000 + 10_000_000 * np.arange(n, dtype=np.int64)  # 100 Hz
    rng = np.random.default_rng(11)
    gyro = rng.normal(0, 1e-5, (n, 3))
    accel = np.array([0.0, 0.0, 9.80]) + rng.normal(0, 1e-3, (n, 3))
    try:
        assert spin_until(ros, lambda: pub.get_subscription_count() > 0
                          and sub.get_publisher_count() > 0, 60.0), stop(proc)
        time.sleep(0.5)
        first = feed_imu(ros, pub, stamps, gyro, accel, got)
        # the node's stream starts at the first sample it got (see feed_imu)
        stamps, gyro, accel, n = stamps[first:], gyro[first:], accel[first:], n - first
        assert n > 200, first
        assert spin_until(ros, lambda: len(got) >= n, 30.0), f'{len(got)} of {n}'

        def last_values() -> dict[str, str]:
            st = [d.status[0] for d in diags if d.status[0].name.endswith('IMU calibration')]
            return {kv.key: kv.value for kv in st[-1].values} if st else {}
        assert spin_until(ros, lambda: int(last_values().get('imu', 0)) >= n, 30.0), diags
        values = last_values()
    finally:
        log = stop(proc)
        ros.destroy_subscription(sub)
        ros.destroy_subscription(dsub)
        ros.destroy_publisher(pub)
    assert 'Traceback' not in log, log
    assert 'missing_imu' not in values  # zero counters are left out
    assert not [k for k in values if k.startswith('rejected.')], values
    assert float(values['imu_rate_measured_hz']) == pytest.approx(100.0, rel=1e-9)
    assert 'imu_rate_warning' not in values
    grade = load_grade('nav_grade')
    fx = Fixture.from_yaml(resolve_config_file('three_axis', 'fixtures'))
    prior = CalibrationEstimator(fx, grade, EstimatorConfig()).estimate(frame_id='imu_link')
    ref = StreamCompensation(prior, grade.gyro_noise_rad_s_rt_hz,
                             grade.accel_noise_m_s2_rt_hz, 0.01)  # the rate given
    exp_w, exp_a = [], []
    for k in range(n):
        if k <= StreamCompensation.RATE_INTERVALS:
            ref.reset()  # until the rate is known: no rate derivative (dt still 0.01 s)
        _, _, gv, av = ref(int(stamps[k]), tuple(gyro[k]), tuple(accel[k]))
        exp_w.append(gv)
        exp_a.append(av)
    var_w = np.array([[m.angular_velocity_covariance[i] for i in (0, 4, 8)] for m in got])
    var_a = np.array([[m.linear_acceleration_covariance[i] for i in (0, 4, 8)] for m in got])
    np.testing.assert_allclose(var_w[1:], np.array(exp_w)[1:], rtol=1e-12)
    np.testing.assert_allclose(var_a[1:], np.array(exp_a)[1:], rtol=1e-12)
    # the white noise of the mean is what sets these variances: N^2 / 0.01 s dominates
    noise_w = grade.gyro_noise_rad_s_rt_hz ** 2 / 0.01
    assert np.all(var_w[1:] >= noise_w) and np.all(var_w[1:] < 1.5 * noise_w)
    # the first sample (no interval yet) errs on the large side
    assert np.all(var_w[0] > var_w[1])


def test_compensator_warns_when_the_configured_rate_is_wrong(ros: Node, tmp_path: Path) -> None:
    """imu_rate_hz 200 configured, 100 Hz stamps: one WARN line and a WARN in /diagnostics
    naming both rates (more than 20 % apart)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Imu
    _, path = known_calibration(tmp_path)
    proc = start('compensator', {'calibration_file': str(path), 'imu_rate_hz': 200.0,
                                 'diagnostics_rate_hz': 5.0}, tmp_path)
    got: list[Any] = []
    diags: list[Any] = []
    sub = ros.create_subscription(Imu, 'imu/data_corrected', got.append, reliable_qos(1000))
    dsub = ros.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 50)
    pub = ros.create_publisher(Imu, 'imu/data_raw', reliable_qos(1000))
    n = 60

    def comp_status() -> Any:
        st = [d.status[0] for d in diags if d.status[0].name.endswith('IMU compensation')]
        return st[-1] if st else None
    try:
        assert spin_until(ros, lambda: pub.get_subscription_count() > 0
                          and sub.get_publisher_count() > 0, 60.0), stop(proc)
        time.sleep(0.5)
        n -= feed_imu(ros, pub, 9_000_000_000 + 10_000_000 * np.arange(n), np.zeros((n, 3)),
                      np.tile([0.0, 0.0, 9.8], (n, 1)), got)
        assert spin_until(ros, lambda: len(got) >= n, 30.0), f'{len(got)} of {n}'
        assert spin_until(ros, lambda: comp_status() is not None
                          and comp_status().level == b'\x01', 30.0)
    finally:
        log = stop(proc)
        ros.destroy_subscription(sub)
        ros.destroy_subscription(dsub)
        ros.destroy_publisher(pub)
    st = comp_status()
    values = {kv.key: kv.value for kv in st.values}
    assert float(values['imu_rate_measured_hz']) == pytest.approx(100.0, rel=1e-9)
    assert '200' in st.message and '100' in st.message, st.message
    assert log.count('configured imu_rate_hz 200') == 1, log


def test_save_without_data_is_refused(ros: Node, tmp_path: Path) -> None:
    """No IMU data yet: ~/save_calibration fails and writes nothing (a file of prior values
    would look like a calibration)."""
    from std_srvs.srv import Trigger
    out = tmp_path / 'nothing.yaml'
    cal = start('calibration', {'output_file': str(out)}, tmp_path)
    save = ros.create_client(Trigger, '/calibration/save_calibration')
    try:
        assert save.wait_for_service(timeout_sec=60.0), stop(cal)
        fut = save.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(ros, fut, timeout_sec=90.0)
        res = fut.result()
    finally:
        log = stop(cal)
        ros.destroy_client(save)
    assert res is not None and not res.success, log
    assert 'nothing to save' in res.message, res.message
    assert not out.exists()
