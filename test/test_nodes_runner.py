"""The estimator runner (no ROS): divergence fallback, bounded queue, process mode, CDR.

The corrected stream of the calibration node uses ``EstimatorRunner.last_good``; these tests
check that a diverged or non-finite estimate never becomes it, that a full queue drops and
counts instead of growing, and that the child-process mode round-trips real estimates.
"""
from __future__ import annotations

import threading
from typing import Any

import numpy as np
import pytest

from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.sensor_model import SensorErrors
from imu_calib_ros.core.types import ImuBatch, JointBatch, JointSample
from imu_calib_ros.core.estimator.runner import EstimatorRunner, is_diverged


class FakeEstimator:
    """Scripted health/estimate sequence: one 'chunk' per push."""

    def __init__(self, script: list[tuple[dict[str, Any], float]], gate: threading.Event
                 | None = None):
        self.script = script
        self.k = -1
        self.gate = gate
        self.pushed = 0

    def push_imu_batch(self, batch: Any) -> None:
        if self.gate is not None:
            self.gate.wait(10.0)
        self.pushed += len(batch)
        self.k = min(self.k + 1, len(self.script) - 1)

    def push_joint(self, sample: Any) -> None:
        pass

    def health(self) -> dict[str, Any]:
        return {'chunks': self.k, **self.script[max(self.k, 0)][0]}

    def estimate(self, frame_id: str = 'imu_link') -> CalibrationResult:
        v = np.full(45, 1e-4 * (self.k + 1))
        v[0] = self.script[max(self.k, 0)][1]
        return CalibrationResult(SensorErrors.from_vector(np.abs(v) * 0 + v),
                                 SensorErrors.from_vector(np.full(45, 1e-5)), frame_id)

    def reset(self) -> None:
        self.k = -1

    def flush(self) -> None:
        pass


def imu(*ks: int) -> ImuBatch:
    """IMU samples ``ks`` (5 ms apart, at rest) as one batch."""
    return ImuBatch.from_rows([(10**9 + k * 5_000_000, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81))
                               for k in ks], 'imu_link')


def test_diverged_estimate_never_replaces_the_last_good_one() -> None:
    script = [({'status': 'OK'}, 1e-5), ({'status': 'OK'}, 2e-5),
              ({'diverged': True, 'status': 'DIVERGED'}, 5.0),  # the filter blew up
              ({'status': 'OK'}, 3e-5)]
    fake = FakeEstimator(script)
    runner = EstimatorRunner('thread', None, 'imu_link', factory=lambda: fake)
    try:
        seen = []
        for k in range(3):
            assert runner.submit(imu(k))
            assert runner.request('estimate', 10.0)
            runner.poll()
            seen.append((runner.latest.diverged, runner.last_good.result.errors
                         .gyro_bias_rad_s[0]))
        assert seen[0] == (False, 1e-5) and seen[1] == (False, 2e-5)
        # diverged: the latest says so, the stream keeps the last good calibration
        assert seen[2] == (True, 2e-5)
        assert runner.latest.result.errors.gyro_bias_rad_s[0] == 5.0
        assert runner.submit(imu(3)) and runner.request('estimate', 10.0)
        runner.poll()
        assert runner.last_good.result.errors.gyro_bias_rad_s[0] == 3e-5  # recovered
    finally:
        runner.stop()


def test_is_diverged_flags() -> None:
    ok = CalibrationResult(SensorErrors.zeros(), SensorErrors.zeros(), 'imu_link')
    assert not is_diverged({'status': 'OK'}, ok)
    assert is_diverged({'diverged': True}, ok)
    assert is_diverged({'status': 'error'}, ok)
    assert not is_diverged({'status': 'WARN'}, None)


def test_full_queue_drops_and_counts_instead_of_growing() -> None:
    gate = threading.Event()  # the estimator is stuck on its first batch
    fake = FakeEstimator([({'status': 'OK'}, 0.0)], gate)
    runner = EstimatorRunner('thread', None, 'imu_link', max_batches=3, factory=lambda: fake)
    try:
        accepted = [runner.submit(imu(k, k + 1)) for k in range(0, 20, 2)]
        # one batch in the worker, three queued, the rest dropped with a count
        assert sum(accepted) <= 4 and runner.dropped == 2 * (10 - sum(accepted))
        gate.set()
        assert runner.request('estimate', 10.0)
        assert fake.pushed == 2 * sum(accepted)
    finally:
        gate.set()
        runner.stop()


def test_process_mode_runs_the_real_estimator_and_answers() -> None:
    from imu_calib_ros.core.config import resolve_config_file
    from imu_calib_ros.core.estimator.config import EstimatorConfig
    spec = (str(resolve_config_file('three_axis', 'fixtures')), 'nav_grade', EstimatorConfig())
    runner = EstimatorRunner('process', spec, 'my_imu')
    try:
        joints = JointBatch.runs([JointSample(10**9, ('outer', 'middle', 'inner'),
                                              np.zeros(3))])
        assert runner.submit(imu(*range(1, 400)), joints)
        assert runner.request('estimate', 60.0, flush=True)
        runner.poll()
        snap = runner.latest
        assert snap is not None and snap.result is not None and not snap.diverged
        assert snap.result.frame_id == 'my_imu'
        assert snap.health.get('imu_samples') == 399
        assert runner.request('reset_navigation', 30.0)
        assert runner.alive
    finally:
        runner.stop()
    assert not runner.alive


def test_imu_cdr_round_trip_matches_rclpy() -> None:
    rclpy_ser = pytest.importorskip('rclpy.serialization')
    from sensor_msgs.msg import Imu
    from msg_adapters.convert import imu_cdr, imu_fields_from_cdr
    for frame in ('', 'a', 'imu', 'imu_link', 'a_longer_frame_name'):
        cov_w = tuple(np.arange(9.0) + 0.5)
        cov_a = tuple(np.arange(9.0) * -2.0)
        data = imu_cdr(1_700_000_000_123_456_789, frame, (1.0, -2.0, 3.5), (4.0, 5.0, 9.81),
                       cov_w, cov_a)
        msg = rclpy_ser.deserialize_message(data, Imu)
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
        assert msg.header.frame_id == frame
        assert msg.orientation.w == 1.0 and msg.orientation_covariance[0] == -1.0
        assert list(msg.angular_velocity_covariance) == list(cov_w)
        assert list(msg.linear_acceleration_covariance) == list(cov_a)
        assert (msg.linear_acceleration.z, msg.angular_velocity.y) == (9.81, -2.0)
        # and back: rclpy's bytes decode to the same fields
        ns, fid, g, a = imu_fields_from_cdr(rclpy_ser.serialize_message(msg))
        assert (ns, fid, g, a) == (1_700_000_000_123_456_789, frame, (1.0, -2.0, 3.5),
                                   (4.0, 5.0, 9.81))


class CrashingEstimator(FakeEstimator):
    """Raises what no ``except`` of the worker named before (compensate's old RuntimeError)."""

    def push_imu_batch(self, batch: Any) -> None:
        super().push_imu_batch(batch)
        raise RuntimeError('compensate did not converge')


def test_an_unexpected_error_keeps_the_worker_answering() -> None:
    """The worker reports any exception of the estimator and stays up: a dead worker never
    drained its queue, so the node's save on shutdown waited 60 s for nothing and the node was
    killed (CI, issue 16's trust: a node that does not stop)."""
    fake = CrashingEstimator([({'status': 'OK'}, 0.0)])
    runner = EstimatorRunner('thread', None, 'imu_link', factory=lambda: fake)
    try:
        assert runner.submit(imu(0, 1))
        assert runner.request('estimate', 10.0)
        assert runner.alive
        runner.poll()
        assert runner.latest is not None
        assert 'RuntimeError: compensate did not converge' in runner.latest.error
        assert runner.submit(imu(2)) and runner.request('estimate', 10.0)  # still serving
    finally:
        runner.stop()
