"""Message <-> sample conversion for ``sensor_msgs/Imu`` and ``sensor_msgs/JointState``.

The readers are duck-typed: they only touch ``header.stamp.sec/nanosec``,
``header.frame_id`` and the message fields, so the same function maps an rclpy message
(``sensor_msgs.msg.Imu``) and a rosbags message (``Stores.ROS2_JAZZY`` typestore) onto
:class:`~imu_calib_ros.core.types.ImuSample` / :class:`JointSample`. Values pass through
unchanged, NaN and inf included: rejecting bad values is the estimator's job (issue 6), not
the adapter's. Only a message whose *structure* is wrong (e.g. three joint names but two
positions) is refused, with :class:`~imu_calib_ros.core.errors.InputError`.

The writers build a message of either kind. ``target`` selects it:

- ``None`` or the string ``'rclpy'``: rclpy classes (imported lazily, so this module can be
  imported, and the rosbags path used, without a ROS installation);
- an rclpy message class (``sensor_msgs.msg.Imu`` or ``JointState``): the same;
- a rosbags :class:`~rosbags.typesys.store.Typestore`: rosbags dataclasses.

Stamps are integer nanoseconds; ``builtin_interfaces/Time`` holds ``sec`` (int32) and
``nanosec`` (uint32, ``0 <= nanosec < 1e9``), so the representable range is
``[-2**31 s, 2**31 s)``. Semantics of the values: CONTRACT section 1.

Raw CDR bytes (the live nodes' fast path, the bag reader and writer) are :mod:`.cdr`'s;
``imu_cdr`` and ``imu_fields_from_cdr`` are re-exported here for the nodes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from imu_calib_ros.core.errors import InputError
from imu_calib_ros.core.types import FloatArray, ImuSample, JointSample
from .cdr import NS_PER_S, imu_cdr, imu_fields_from_cdr  # noqa: F401 - the raw-bytes path

STAMP_MIN_NS = -(2 ** 31) * NS_PER_S
STAMP_MAX_NS = (2 ** 31) * NS_PER_S - 1

IMU_MSGTYPE = 'sensor_msgs/msg/Imu'
JOINT_STATE_MSGTYPE = 'sensor_msgs/msg/JointState'


def stamp_ns_from_time(stamp: Any) -> int:
    """Integer nanoseconds from a ``builtin_interfaces/Time`` (``sec``, ``nanosec``)."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def time_fields_from_ns(stamp_ns: int) -> tuple[int, int]:
    """``(sec, nanosec)`` of ``builtin_interfaces/Time`` for a stamp in nanoseconds.

    ``nanosec`` is always in ``[0, 1e9)`` (floor division), also for negative stamps.

    Raises
    ------
    InputError
        If the stamp does not fit the int32 seconds of the message.
    """
    stamp_ns = int(stamp_ns)
    if not STAMP_MIN_NS <= stamp_ns <= STAMP_MAX_NS:
        raise InputError(f'stamp {stamp_ns} ns does not fit builtin_interfaces/Time '
                         '(int32 seconds)')
    sec, nanosec = divmod(stamp_ns, NS_PER_S)
    return sec, nanosec


def time_msg_from_ns(stamp_ns: int, target: Any = None) -> Any:
    """``builtin_interfaces/Time`` from integer nanoseconds (rclpy, or a rosbags typestore).

    Raises
    ------
    InputError
        If the stamp does not fit the int32 seconds of the message.
    """
    sec, nanosec = time_fields_from_ns(stamp_ns)
    if _is_typestore(target):
        return target.types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)
    Time, _, _ = _rclpy_types()
    return Time(sec=sec, nanosec=nanosec)


@dataclass(frozen=True)
class ImuCovariances:
    """Covariances written into ``sensor_msgs/Imu`` (row-major 3x3, SI units squared).

    All zeros means "unknown" (sensor_msgs/Imu comment); orientation is always marked as
    absent with ``orientation_covariance[0] = -1`` (REP-145).
    """

    angular_velocity_rad2_s2: FloatArray
    linear_acceleration_m2_s4: FloatArray

    @classmethod
    def unknown(cls) -> 'ImuCovariances':
        """All-zero covariances ("unknown")."""
        return cls(np.zeros(9), np.zeros(9))

    @classmethod
    def from_sigmas(cls, gyro_sigma_rad_s: float, accel_sigma_m_s2: float) -> 'ImuCovariances':
        """Diagonal covariances from per-sample one-sigma noise of each axis."""
        return cls(np.diag(np.full(3, gyro_sigma_rad_s ** 2)).ravel(),
                   np.diag(np.full(3, accel_sigma_m_s2 ** 2)).ravel())


def _covariance9(value: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (9,):
        raise InputError(f'{name}: expected 9 values (row-major 3x3), got {arr.size}')
    return arr.copy()


_ORIENTATION_COV = np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0])


def imu_sample_from_msg(msg: Any) -> ImuSample:
    """Map a ``sensor_msgs/Imu`` (rclpy or rosbags) onto an :class:`ImuSample`.

    Orientation and covariances are ignored (raw IMU data, CONTRACT section 1).
    """
    w = msg.angular_velocity
    a = msg.linear_acceleration
    return ImuSample(stamp_ns_from_time(msg.header.stamp),
                     np.array((w.x, w.y, w.z), dtype=np.float64),
                     np.array((a.x, a.y, a.z), dtype=np.float64),
                     str(msg.header.frame_id))


def joint_sample_from_msg(msg: Any) -> JointSample:
    """Map a ``sensor_msgs/JointState`` (rclpy or rosbags) onto a :class:`JointSample`.

    An empty ``velocity`` gives ``velocities_rad_s=None``; ``effort`` is ignored.

    Raises
    ------
    InputError
        If ``position`` (or a non-empty ``velocity``) does not have one value per name.
    """
    names = tuple(str(n) for n in msg.name)
    positions = np.array(msg.position, dtype=np.float64)
    if positions.shape != (len(names),):
        raise InputError(f'JointState: {len(names)} names but {positions.size} positions')
    vel = np.array(msg.velocity, dtype=np.float64).reshape(-1)
    if vel.size not in (0, len(names)):
        raise InputError(f'JointState: {len(names)} names but {vel.size} velocities')
    return JointSample(stamp_ns_from_time(msg.header.stamp), names, positions,
                       vel if vel.size else None)


def _is_typestore(target: Any) -> bool:
    return hasattr(target, 'types') and hasattr(target, 'serialize_cdr')


def _typestore_header(types: Any, sec: int, nanosec: int, frame_id: str) -> Any:
    """A rosbags ``std_msgs/Header`` (the Imu and JointState builders' shared part)."""
    return types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
        frame_id=frame_id)


def _rclpy_types() -> Any:
    """The rclpy message modules, imported on first use only."""
    try:
        from builtin_interfaces.msg import Time
        from sensor_msgs.msg import Imu, JointState
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise InputError(f'rclpy message classes are not available ({exc}); pass a rosbags '
                         'typestore instead') from None
    return Time, Imu, JointState


def _check_target(target: Any, expected: str) -> None:
    """Accept None, 'rclpy', a typestore or an rclpy class of the expected message type."""
    if target is None or target == 'rclpy' or _is_typestore(target):
        return
    name = getattr(target, '__name__', None)
    module = getattr(target, '__module__', '')
    if name == expected.rsplit('/', 1)[-1] and module.startswith('sensor_msgs'):
        return
    raise InputError(f'cannot build {expected} from target {target!r}: expected None, '
                     "'rclpy', an rclpy message class or a rosbags Typestore")


def imu_msg_from_sample(sample: ImuSample, target: Any = None,
                        covariances: ImuCovariances | None = None,
                        frame_id: str | None = None) -> Any:
    """Build a ``sensor_msgs/Imu`` from an :class:`ImuSample`.

    Parameters
    ----------
    sample:
        Stamp, mean angular rate and specific force (CONTRACT section 1).
    target:
        ``None``/``'rclpy'``/``sensor_msgs.msg.Imu`` for an rclpy message, or a rosbags
        ``Typestore`` for a rosbags message.
    covariances:
        Rate and specific-force covariances; ``None`` writes zeros ("unknown").
    frame_id:
        ``header.frame_id``; ``None`` uses ``sample.frame_id``.

    Notes
    -----
    ``orientation`` is the identity quaternion and ``orientation_covariance[0] = -1``:
    no orientation estimate (REP-145).
    """
    _check_target(target, IMU_MSGTYPE)
    cov = covariances or ImuCovariances.unknown()
    cov_w = _covariance9(cov.angular_velocity_rad2_s2, 'angular_velocity covariance')
    cov_a = _covariance9(cov.linear_acceleration_m2_s4, 'linear_acceleration covariance')
    sec, nanosec = time_fields_from_ns(sample.stamp_ns)
    fid = sample.frame_id if frame_id is None else frame_id
    w = np.asarray(sample.gyro_rad_s, dtype=np.float64)
    a = np.asarray(sample.accel_m_s2, dtype=np.float64)
    if w.shape != (3,) or a.shape != (3,):
        raise InputError(f'ImuSample at {sample.stamp_ns} ns: gyro and accel must have 3 '
                         f'values, got {w.shape} and {a.shape}')
    if _is_typestore(target):
        t = target.types
        return t[IMU_MSGTYPE](
            header=_typestore_header(t, sec, nanosec, fid),
            orientation=t['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=_ORIENTATION_COV.copy(),
            angular_velocity=t['geometry_msgs/msg/Vector3'](
                x=float(w[0]), y=float(w[1]), z=float(w[2])),
            angular_velocity_covariance=cov_w,
            linear_acceleration=t['geometry_msgs/msg/Vector3'](
                x=float(a[0]), y=float(a[1]), z=float(a[2])),
            linear_acceleration_covariance=cov_a)
    Time, Imu, _ = _rclpy_types()
    msg = Imu()
    msg.header.stamp = Time(sec=sec, nanosec=nanosec)
    msg.header.frame_id = fid
    msg.orientation.w = 1.0
    msg.orientation_covariance = _ORIENTATION_COV.copy()
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = map(float, w)
    msg.angular_velocity_covariance = cov_w
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = \
        map(float, a)
    msg.linear_acceleration_covariance = cov_a
    return msg


def joint_state_msg_from_sample(sample: JointSample, target: Any = None,
                                frame_id: str = '') -> Any:
    """Build a ``sensor_msgs/JointState`` from a :class:`JointSample`.

    ``velocities_rad_s=None`` writes an empty ``velocity``; ``effort`` is always empty.
    ``target`` as in :func:`imu_msg_from_sample`.
    """
    _check_target(target, JOINT_STATE_MSGTYPE)
    sec, nanosec = time_fields_from_ns(sample.stamp_ns)
    names = [str(n) for n in sample.names]
    pos = np.asarray(sample.positions_rad, dtype=np.float64).reshape(-1)
    vel = (np.zeros(0) if sample.velocities_rad_s is None
           else np.asarray(sample.velocities_rad_s, dtype=np.float64).reshape(-1))
    if pos.size != len(names) or vel.size not in (0, len(names)):
        raise InputError(f'JointSample at {sample.stamp_ns} ns: {len(names)} names, '
                         f'{pos.size} positions, {vel.size} velocities')
    if _is_typestore(target):
        t = target.types
        return t[JOINT_STATE_MSGTYPE](
            header=_typestore_header(t, sec, nanosec, frame_id),
            name=names, position=pos.copy(), velocity=vel.copy(), effort=np.zeros(0))
    Time, _, JointState = _rclpy_types()
    msg = JointState()
    msg.header.stamp = Time(sec=sec, nanosec=nanosec)
    msg.header.frame_id = frame_id
    msg.name = names
    msg.position = pos.tolist()
    msg.velocity = vel.tolist()
    return msg
