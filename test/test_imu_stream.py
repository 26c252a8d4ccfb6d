"""ImuStream (core, no ROS): the per-sample path both nodes share (issue 14 item 1)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.imu_stream import STREAM_REASONS, ImuStream, Step
from imu_calib_ros.core.sensor_model import SensorErrors
from imu_calib_ros.core.stream_compensation import StreamCompensation
from imu_calib_ros.core.types import ImuBatch, JointBatch, JointSample

MS = 1_000_000
T0 = 10**9
GYRO = (0.01, -0.02, 0.03)
ACCEL = (0.1, 0.2, 9.81)


def stream(frame: str = '', window_s: float = 0.0, adopt: bool = False,
           rate_hz: float = 0.0, bias: float = 0.0) -> ImuStream:
    v = np.zeros(45)
    v[:3] = bias  # gyro_bias_rad_s first (SensorErrors.as_vector)
    errors = SensorErrors.from_vector(v)
    assert errors.gyro_bias_rad_s.tolist() == [bias] * 3
    cal = CalibrationResult(errors, SensorErrors.zeros(), frame or 'imu_link')
    comp = StreamCompensation(cal, 1e-4, 1e-3, 1.0 / rate_hz if rate_hz else 0.0)
    return ImuStream(comp, frame, window_s, adopt_frame=adopt)


def push(s: ImuStream, ns: int, frame: str = 'imu', clock_ns: int | None = None,
         gyro: tuple[float, float, float] = GYRO,
         accel: tuple[float, float, float] = ACCEL) -> Step:
    return s.push(ns, frame, gyro, accel, ns if clock_ns is None else clock_ns)


def test_accepted_samples_are_compensated_with_the_calibration() -> None:
    s = stream('imu', bias=0.01)
    step = push(s, T0)
    assert not step.rejected and len(step.accepted) == 1
    c = step.accepted[0]
    assert (c.stamp_ns, c.frame_id, c.gyro, c.accel) == (T0, 'imu', GYRO, ACCEL)
    assert c.values is not None
    omega, f, gvar, avar = c.values
    assert omega == pytest.approx((0.0, -0.03, 0.02))  # bias removed
    assert f == pytest.approx(ACCEL)
    assert all(v > 0 for v in gvar + avar)
    assert s.rejected == dict.fromkeys(STREAM_REASONS, 0)
    assert (s.first_ns, s.last_ns) == (T0, T0)


def test_frames_required_or_adopted() -> None:
    fixed = stream('imu')
    step = push(fixed, T0, 'other')
    assert not step.accepted and [r.reason for r in step.rejected] == ['frame_id']
    assert step.rejected[0].frame_id == 'other' and fixed.rejected_frame == 'other'
    assert fixed.rejected['frame_id'] == 1 and fixed.frame_id == 'imu'
    # empty frame, no adoption (the compensator with a frame-less calibration): exact match
    strict = stream('', adopt=False)
    assert [r.reason for r in push(strict, T0, 'imu').rejected] == ['frame_id']
    assert len(push(strict, T0 + MS, '').accepted) == 1
    # the calibration node: the first frame becomes the accepted one, once
    adopt = stream('', adopt=True)
    first = push(adopt, T0, 'imu_a')
    assert first.adopted_frame == 'imu_a' and len(first.accepted) == 1
    assert adopt.frame_id == 'imu_a'
    second = push(adopt, T0 + MS, 'imu_b')
    assert second.adopted_frame == '' and [r.reason for r in second.rejected] == ['frame_id']
    assert adopt.rejected_frame == 'imu_b' and adopt.rejected['frame_id'] == 1
    assert push(adopt, T0 + 2 * MS, 'imu_a').accepted


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_non_finite_raw_values_are_rejected_before_the_window(bad: float) -> None:
    s = stream('imu', window_s=0.01)
    assert [r.reason for r in push(s, T0, gyro=(0.0, bad, 0.0)).rejected] == ['non_finite']
    assert [r.reason for r in push(s, T0 + MS, accel=(bad, 0.0, 9.8)).rejected] == [
        'non_finite']
    assert s.rejected['non_finite'] == 2 and len(s.reorder) == 0
    assert s.last_ns is None  # nothing reached the ordered stream


def test_compensation_non_finite_is_counted_not_published() -> None:
    s = stream('imu')
    step = push(s, T0, gyro=(1e200, 0.0, 0.0))  # finite in, variance overflows
    assert [r.reason for r in step.rejected] == ['compensation_non_finite']
    assert len(step.accepted) == 1 and step.accepted[0].values is None  # accepted raw
    assert s.rejected['compensation_non_finite'] == 1 and s.last_ns == T0


def test_reorder_window_puts_samples_back_in_stamp_order() -> None:
    s = stream('imu', window_s=0.005)
    out: list[int] = []
    # arrival order 0, 2, 1, 3 ms (stamps), each arriving at its stamp + 0.5 ms
    for k in (0, 2, 1, 3):
        step = push(s, T0 + k * MS, clock_ns=T0 + k * MS + MS // 2)
        assert not step.rejected
        out += [c.stamp_ns for c in step.accepted]
    out += [c.stamp_ns for c in s.release(T0 + 100 * MS).accepted]
    assert out == [T0 + k * MS for k in range(4)]
    assert s.reorder.stats.reordered == 1 and s.rejected['out_of_order'] == 0
    assert s.due_ns() is None


def test_out_of_order_after_the_window_and_duplicates() -> None:
    s = stream('imu')  # no wait: every sample goes through at once
    assert push(s, T0 + 2 * MS).accepted
    late = push(s, T0 + MS)
    assert not late.accepted and [r.reason for r in late.rejected] == ['out_of_order']
    dup = push(s, T0 + 2 * MS)
    assert [r.reason for r in dup.rejected] == ['out_of_order']
    assert s.rejected['out_of_order'] == 2 and s.last_ns == T0 + 2 * MS
    # a restart (time jump, reset) forgets the order: an older stamp is accepted again
    s.restart()
    assert s.last_ns is None
    assert push(s, T0).accepted and s.first_ns == T0 + 2 * MS  # the first is kept


def test_missing_samples_counted_from_the_configured_period() -> None:
    s = stream('imu', rate_hz=1000.0)
    stamps = [T0, T0 + MS, T0 + 2 * MS, T0 + 5 * MS, T0 + 6 * MS]  # 2 lost
    assert all(push(s, t).accepted for t in stamps)
    assert s.missing == 2


def test_missing_samples_counted_from_the_measured_period() -> None:
    s = stream('imu')  # rate detected from the first 20 intervals
    stamps = [T0 + k * MS for k in range(10)] + [T0 + (k + 13) * MS for k in range(30)]
    known = []
    for t in stamps:
        step = push(s, t)
        assert step.accepted
        if step.rate_known:
            known.append(t)
    assert len(known) == 1  # reported once, when the period became known
    assert s.compensation.measured_period_s == pytest.approx(1e-3)
    assert s.missing == 3  # the gap among the learning intervals, counted then
    push(s, stamps[-1] + 3 * MS)
    assert s.missing == 5


def test_bad_message_and_reset_counts() -> None:
    s = stream('imu')
    step = s.reject('bad_message')
    assert [r.reason for r in step.rejected] == ['bad_message'] and not step.accepted
    push(s, T0, 'x')
    assert s.rejected['bad_message'] == 1 and s.rejected['frame_id'] == 1
    s.reset_counts()
    assert set(s.rejected.values()) == {0}


def test_batches_for_the_estimator_are_sorted_arrays() -> None:
    rows = [(T0 + 2 * MS, (1.0, 2.0, 3.0), (4.0, 5.0, 6.0)), (T0, (0.0, 0.0, 0.0), ACCEL)]
    b = ImuBatch.from_rows(rows, 'imu')
    assert b.stamps_ns.tolist() == [T0, T0 + 2 * MS] and b.frame_id == 'imu'
    assert b.gyro_rad_s[1].tolist() == [1.0, 2.0, 3.0] and b.accel_m_s2.shape == (2, 3)
    assert len(ImuBatch.from_rows([])) == 0
    names, other = ('a', 'b'), ('c',)
    joints = [JointSample(T0 + 3, names, np.array([3.0, 3.0])),
              JointSample(T0 + 1, names, np.array([1.0, 1.0])),
              JointSample(T0 + 4, other, np.array([4.0])),
              JointSample(T0 + 5, names, np.array([5.0, 5.0]))]
    runs = JointBatch.runs(joints)
    assert [(r.names, r.stamps_ns.tolist()) for r in runs] == [
        (names, [T0 + 1, T0 + 3]), (other, [T0 + 4]), (names, [T0 + 5])]
    assert runs[0].positions_rad.tolist() == [[1.0, 1.0], [3.0, 3.0]]
    assert JointBatch.runs([]) == []
