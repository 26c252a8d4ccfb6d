"""msg_adapters.convert: rclpy and rosbags messages <-> ImuSample/JointSample, both ways.

Property-based (hypothesis): any finite sample survives sample -> message -> sample
bit-exactly, for rclpy messages, rosbags messages, and rosbags messages through CDR bytes;
stamps across the sec/nanosec boundary; NaN and inf pass through unchanged.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from imu_calib_ros.core.errors import InputError
from imu_calib_ros.core.types import ImuSample, JointSample
from msg_adapters.convert import (IMU_MSGTYPE, JOINT_STATE_MSGTYPE, NS_PER_S,
                                  STAMP_MAX_NS, STAMP_MIN_NS, ImuCovariances,
                                  imu_msg_from_sample, imu_sample_from_msg,
                                  joint_sample_from_msg,
                                  joint_state_msg_from_sample,
                                  stamp_ns_from_time, time_fields_from_ns)

STORE = get_typestore(Stores.ROS2_JAZZY)

stamps = st.integers(min_value=STAMP_MIN_NS, max_value=STAMP_MAX_NS)
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
vec3 = st.lists(finite, min_size=3, max_size=3).map(np.array)
frame_ids = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=0x2FFF,
                                           blacklist_categories=('Cs',)), max_size=20)


def _rclpy_available() -> bool:
    try:
        import sensor_msgs.msg  # noqa: F401
    except ImportError:
        return False
    return True


TARGETS = ['rosbags', 'cdr'] + (['rclpy'] if _rclpy_available() else [])


def _round_trip_imu(sample: ImuSample, kind: str, **kw: object) -> tuple[object, ImuSample]:
    if kind == 'rclpy':
        msg = imu_msg_from_sample(sample, None, **kw)  # type: ignore[arg-type]
    else:
        msg = imu_msg_from_sample(sample, STORE, **kw)  # type: ignore[arg-type]
        if kind == 'cdr':
            msg = STORE.deserialize_cdr(STORE.serialize_cdr(msg, IMU_MSGTYPE), IMU_MSGTYPE)
    return msg, imu_sample_from_msg(msg)


def _assert_same_imu(a: ImuSample, b: ImuSample) -> None:
    assert a.stamp_ns == b.stamp_ns
    assert type(b.stamp_ns) is int
    assert a.frame_id == b.frame_id
    assert b.gyro_rad_s.dtype == np.float64 and b.accel_m_s2.dtype == np.float64
    # bit-exact, NaN payload aside: compare the float64 bit patterns of non-NaN values
    for x, y in ((a.gyro_rad_s, b.gyro_rad_s), (a.accel_m_s2, b.accel_m_s2)):
        assert np.array_equal(np.isnan(x), np.isnan(y))
        ok = ~np.isnan(x)
        assert np.array_equal(np.asarray(x, np.float64)[ok].view(np.int64), y[ok].view(np.int64))


@pytest.mark.parametrize('kind', TARGETS)
@settings(max_examples=150, deadline=None)
@given(stamp=stamps, gyro=vec3, accel=vec3, frame_id=frame_ids)
def test_finite_imu_sample_round_trips_bit_exact(kind: str, stamp: int, gyro: np.ndarray,
                                                 accel: np.ndarray, frame_id: str) -> None:
    sample = ImuSample(stamp, gyro, accel, frame_id)
    msg, back = _round_trip_imu(sample, kind)
    _assert_same_imu(sample, back)
    # REP-145: no orientation
    assert msg.orientation_covariance[0] == -1.0  # type: ignore[attr-defined]
    assert list(msg.orientation_covariance[1:]) == [0.0] * 8  # type: ignore[attr-defined]


@pytest.mark.parametrize('kind', TARGETS)
@settings(max_examples=60, deadline=None)
@given(gyro=st.lists(any_float, min_size=3, max_size=3).map(np.array),
       accel=st.lists(any_float, min_size=3, max_size=3).map(np.array))
def test_nan_and_inf_pass_through_unchanged(kind: str, gyro: np.ndarray,
                                            accel: np.ndarray) -> None:
    sample = ImuSample(123, gyro, accel, 'imu_link')
    _, back = _round_trip_imu(sample, kind)
    _assert_same_imu(sample, back)


def test_explicit_nan_is_kept_not_rejected() -> None:
    sample = ImuSample(5, np.array([np.nan, 0.0, 1.0]), np.array([0.0, -np.inf, 9.8]), 'i')
    for kind in TARGETS:
        _, back = _round_trip_imu(sample, kind)
        assert np.isnan(back.gyro_rad_s[0]) and back.accel_m_s2[1] == -np.inf


@pytest.mark.parametrize('stamp_ns,sec,nanosec', [
    (0, 0, 0), (999_999_999, 0, 999_999_999), (1_000_000_000, 1, 0),
    (1_000_000_001, 1, 1), (-1, -1, 999_999_999), (-1_000_000_000, -1, 0),
    (-1_000_000_001, -2, 999_999_999), (STAMP_MAX_NS, 2 ** 31 - 1, 999_999_999),
    (STAMP_MIN_NS, -(2 ** 31), 0), (1_700_000_000_123_456_789, 1_700_000_000, 123_456_789)])
def test_stamp_split_at_the_second_boundary(stamp_ns: int, sec: int, nanosec: int) -> None:
    assert time_fields_from_ns(stamp_ns) == (sec, nanosec)

    class T:
        pass
    t = T()
    t.sec, t.nanosec = sec, nanosec  # type: ignore[attr-defined]
    assert stamp_ns_from_time(t) == stamp_ns


@settings(max_examples=200, deadline=None)
@given(sec=st.integers(-(2 ** 31), 2 ** 31 - 1),
       delta=st.integers(-3, 3))
def test_stamps_near_second_boundary_round_trip(sec: int, delta: int) -> None:
    stamp = min(max(sec * NS_PER_S + delta, STAMP_MIN_NS), STAMP_MAX_NS)
    s, ns = time_fields_from_ns(stamp)
    assert 0 <= ns < NS_PER_S and -(2 ** 31) <= s < 2 ** 31
    for kind in TARGETS:
        _, back = _round_trip_imu(ImuSample(stamp, np.zeros(3), np.zeros(3)), kind)
        assert back.stamp_ns == stamp


@pytest.mark.parametrize('stamp', [STAMP_MAX_NS + 1, STAMP_MIN_NS - 1])
def test_stamp_outside_int32_seconds_is_refused(stamp: int) -> None:
    with pytest.raises(InputError, match='int32'):
        imu_msg_from_sample(ImuSample(stamp, np.zeros(3), np.zeros(3)), STORE)


def test_covariances_are_written_row_major() -> None:
    cov = ImuCovariances(np.arange(9.0).reshape(3, 3), np.arange(9.0, 18.0))
    for kind in TARGETS:
        msg, _ = _round_trip_imu(ImuSample(1, np.ones(3), np.ones(3)), kind, covariances=cov)
        assert list(msg.angular_velocity_covariance) == list(range(9))  # type: ignore
        assert list(msg.linear_acceleration_covariance) == list(range(9, 18))  # type: ignore
    sig = ImuCovariances.from_sigmas(2e-3, 3e-2)
    np.testing.assert_allclose(sig.angular_velocity_rad2_s2.reshape(3, 3), np.eye(3) * 4e-6)
    with pytest.raises(InputError, match='9 values'):
        imu_msg_from_sample(ImuSample(1, np.ones(3), np.ones(3)), STORE,
                            ImuCovariances(np.zeros(4), np.zeros(9)))


def test_frame_id_override() -> None:
    msg = imu_msg_from_sample(ImuSample(1, np.ones(3), np.ones(3), 'a'), STORE, frame_id='b')
    assert msg.header.frame_id == 'b'


# ---------------------------------------------------------------- joint states

names_st = st.lists(st.text(alphabet='abcdefghijklmnopqrstuvwxyz_0123456789', min_size=1,
                            max_size=12), min_size=0, max_size=5, unique=True)


@st.composite
def joint_samples(draw: st.DrawFn) -> JointSample:
    names = tuple(draw(names_st))
    n = len(names)
    pos = np.array(draw(st.lists(any_float, min_size=n, max_size=n)), dtype=np.float64)
    has_vel = draw(st.booleans()) and n > 0
    vel = (np.array(draw(st.lists(any_float, min_size=n, max_size=n)), dtype=np.float64)
           if has_vel else None)
    return JointSample(draw(stamps), names, pos, vel)


def _round_trip_joint(sample: JointSample, kind: str) -> JointSample:
    if kind == 'rclpy':
        msg = joint_state_msg_from_sample(sample)
    else:
        msg = joint_state_msg_from_sample(sample, STORE)
        if kind == 'cdr':
            msg = STORE.deserialize_cdr(STORE.serialize_cdr(msg, JOINT_STATE_MSGTYPE),
                                        JOINT_STATE_MSGTYPE)
    return joint_sample_from_msg(msg)


@pytest.mark.parametrize('kind', TARGETS)
@settings(max_examples=100, deadline=None)
@given(sample=joint_samples())
def test_joint_sample_round_trips(kind: str, sample: JointSample) -> None:
    back = _round_trip_joint(sample, kind)
    assert back.stamp_ns == sample.stamp_ns and back.names == sample.names
    np.testing.assert_array_equal(back.positions_rad, sample.positions_rad)
    assert back.positions_rad.dtype == np.float64
    if sample.velocities_rad_s is None:
        assert back.velocities_rad_s is None
    else:
        assert back.velocities_rad_s is not None
        np.testing.assert_array_equal(back.velocities_rad_s, sample.velocities_rad_s)


class _Stamp:
    def __init__(self, sec: int, nanosec: int) -> None:
        self.sec, self.nanosec = sec, nanosec


class _Header:
    def __init__(self) -> None:
        self.stamp = _Stamp(3, 4)
        self.frame_id = ''


class _FakeJointState:
    """Duck-typed JointState (as any rclpy/rosbags message looks to the adapter)."""

    def __init__(self, name: list[str], position: list[float], velocity: list[float]) -> None:
        self.header = _Header()
        self.name, self.position, self.velocity, self.effort = name, position, velocity, []


def test_empty_velocity_gives_none_and_duck_typing_works() -> None:
    s = joint_sample_from_msg(_FakeJointState(['a', 'b'], [0.5, -0.25], []))
    assert s.velocities_rad_s is None and s.stamp_ns == 3 * NS_PER_S + 4
    assert s.names == ('a', 'b') and s.positions_rad.tolist() == [0.5, -0.25]


@pytest.mark.parametrize('pos,vel,match', [([1.0], [], '2 names but 1 positions'),
                                           ([1.0, 2.0], [1.0], '2 names but 1 velocities')])
def test_malformed_joint_state_is_refused(pos: list[float], vel: list[float],
                                          match: str) -> None:
    with pytest.raises(InputError, match=match):
        joint_sample_from_msg(_FakeJointState(['a', 'b'], pos, vel))


def test_bad_target_is_refused() -> None:
    with pytest.raises(InputError, match='Typestore'):
        imu_msg_from_sample(ImuSample(1, np.ones(3), np.ones(3)), target=int)


def test_convert_does_not_import_rclpy_at_module_import() -> None:
    import subprocess
    import sys
    code = ('import sys, msg_adapters.convert, msg_adapters.bag; '
            'bad = [m for m in sys.modules if m.split(".")[0] in '
            '("rclpy", "sensor_msgs", "rosbags")]; print(bad); assert not bad')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
