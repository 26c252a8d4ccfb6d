"""The CDR byte layouts of ``sensor_msgs/Imu`` and ``sensor_msgs/JointState``, written once.

Every raw-bytes path of the package goes through here: the live nodes (one message: struct,
no message objects; rclpy's (de)serialisation into Python objects costs ~30-60 us per Imu,
which a 5 kHz node cannot afford) and the bag reader and writer (many messages at once:
numpy, no per-message Python). rosbags' ``Typestore.deserialize_cdr`` is the reference: the
tests compare both against it (and the one-message Imu path against rclpy.serialization)
bit for bit.

Layout (little-endian XCDR1, what rmw publishes and rosbag2 records): a 4-byte
encapsulation header ``00 01 00 00``, then the body, aligned relative to the body start:

- ``std_msgs/Header``: int32 sec, uint32 nanosec, uint32 length of frame_id with its NUL,
  the bytes, NUL;
- ``sensor_msgs/Imu``: padding to 8, then 37 float64: orientation (4), its covariance (9),
  angular_velocity (3), covariance (9), linear_acceleration (3), covariance (9). Only the
  frame_id length varies, so a message's layout is fixed by it;
- ``sensor_msgs/JointState``: sequence<string> name (uint32 count; per name uint32 length
  with NUL aligned to 4, bytes, NUL), then sequence<float64> position, velocity, effort
  (uint32 count aligned to 4; doubles aligned to 8 when the count is not zero).

The many-message decoders take the messages as one byte buffer with start offsets and
lengths (a decompressed mcap chunk, or messages joined) and decode every message that has
the fixed layout; the rest are flagged for the caller to decode with rosbags (which then
decodes them or says what is wrong, so the errors are rosbags' own).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imu_calib_ros.core.errors import InputError

NS_PER_S = 1_000_000_000
CDR_LE = b'\x00\x01\x00\x00'
_CDR_LE_U32 = int.from_bytes(CDR_LE, 'little')
#: float64 indices in the Imu's 37 doubles
IMU_GYRO, IMU_ACCEL, IMU_DOUBLES = 13, 25, 37
_ORIENTATION_AND_COV = (0.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

IntArray = NDArray[np.int64]
U8Array = NDArray[np.uint8]


def _align(offset: int, n: int) -> int:
    return (offset + n - 1) // n * n


def check_stamps(stamps_ns: Any) -> tuple[IntArray, IntArray]:
    """``(sec, nanosec)`` arrays of ``builtin_interfaces/Time`` (nanosec in [0, 1e9)).

    Raises
    ------
    InputError
        A stamp outside the int32 seconds of the message.
    """
    sec, nanosec = np.divmod(np.asarray(stamps_ns, np.int64), NS_PER_S)
    if sec.size and (sec.min() < -2 ** 31 or sec.max() >= 2 ** 31):
        raise InputError('stamps do not fit builtin_interfaces/Time (int32 seconds)')
    return sec, nanosec


# --------------------------------------------------------------------------------- Imu

def imu_layout(frame_id: str) -> tuple[bytes, int, int]:
    """``(bytes after the stamp up to the doubles, offset of the 37 doubles, length)`` of an
    Imu message with this frame_id (offsets from the start of the message)."""
    fid = frame_id.encode('utf-8') + b'\x00'
    end = 12 + len(fid)  # body offset after the frame_id
    doubles = _align(end, 8)
    prefix = len(fid).to_bytes(4, 'little') + fid + b'\x00' * (doubles - end)
    return prefix, 4 + doubles, 4 + doubles + 8 * IMU_DOUBLES


_IMU_HEAD = struct.Struct('<iII')
_IMU_STRUCTS: dict[str, tuple[struct.Struct, bytes]] = {}


def _imu_struct(frame_id: str) -> tuple[struct.Struct, bytes]:
    entry = _IMU_STRUCTS.get(frame_id)
    if entry is None:
        prefix, _, _ = imu_layout(frame_id)
        entry = (struct.Struct(f'<4siI{len(prefix)}s{IMU_DOUBLES}d'), prefix)
        if len(_IMU_STRUCTS) < 64:
            _IMU_STRUCTS[frame_id] = entry
    return entry


def imu_fields_from_cdr(data: bytes) -> tuple[int, str, tuple[float, float, float],
                                                tuple[float, float, float]]:
    """``(stamp_ns, frame_id, gyro, accel)`` of one serialised ``sensor_msgs/Imu``.

    Raises
    ------
    InputError
        Not a little-endian CDR Imu (wrong header, too short).
    """
    if len(data) < 16 or data[:4] != CDR_LE:
        raise InputError('not a little-endian CDR sensor_msgs/Imu')
    sec, nanosec, n = _IMU_HEAD.unpack_from(data, 4)
    off = 4 + _align(12 + n, 8)
    if off + 8 * IMU_DOUBLES > len(data) or n == 0:
        raise InputError('truncated CDR sensor_msgs/Imu')
    g = struct.unpack_from('<3d', data, off + 8 * IMU_GYRO)
    a = struct.unpack_from('<3d', data, off + 8 * IMU_ACCEL)
    return sec * NS_PER_S + nanosec, data[16:16 + n - 1].decode(errors='replace'), g, a


def imu_cdr(stamp_ns: int, frame_id: str, gyro_rad_s: Any, accel_m_s2: Any,
            angular_velocity_cov: Any, linear_acceleration_cov: Any) -> bytes:
    """One serialised ``sensor_msgs/Imu`` (identity orientation, ``orientation_covariance[0]
    = -1``, REP-145), e.g. to publish as raw bytes (``Publisher.publish(bytes)``).

    Raises
    ------
    InputError
        A stamp outside the int32 seconds of ``builtin_interfaces/Time``.
    """
    stamp_ns = int(stamp_ns)
    sec, nanosec = divmod(stamp_ns, NS_PER_S)
    if not -2 ** 31 <= sec < 2 ** 31:
        raise InputError(f'stamp {stamp_ns} ns does not fit builtin_interfaces/Time '
                         '(int32 seconds)')
    st, prefix = _imu_struct(frame_id)
    return st.pack(CDR_LE, sec, nanosec, prefix, *_ORIENTATION_AND_COV, *gyro_rad_s,
                   *angular_velocity_cov, *accel_m_s2, *linear_acceleration_cov)


def pack_imu(stamps_ns: Any, gyro_rad_s: Any, accel_m_s2: Any, frame_id: str,
             angular_velocity_cov: Any, linear_acceleration_cov: Any) -> U8Array:
    """Many Imu messages of one frame_id serialised at once, as an ``(N, length)`` uint8
    array (row k = :func:`imu_cdr` of sample k).

    Raises
    ------
    InputError
        A stamp outside the int32 seconds of ``builtin_interfaces/Time``.
    """
    prefix, off, length = imu_layout(frame_id)
    sec, nanosec = check_stamps(stamps_ns)
    n = len(sec)
    out = np.zeros((n, length), np.uint8)
    out[:, 0:4] = np.frombuffer(CDR_LE, np.uint8)
    out[:, 4:8] = sec.astype('<i4').view(np.uint8).reshape(n, 4)
    out[:, 8:12] = nanosec.astype('<u4').view(np.uint8).reshape(n, 4)
    out[:, 12:off] = np.frombuffer(prefix, np.uint8)
    d = np.zeros((n, IMU_DOUBLES), '<f8')
    d[:, :13] = _ORIENTATION_AND_COV
    d[:, IMU_GYRO:IMU_GYRO + 3] = gyro_rad_s
    d[:, IMU_GYRO + 3:IMU_ACCEL] = np.asarray(angular_velocity_cov, float).reshape(9)
    d[:, IMU_ACCEL:IMU_ACCEL + 3] = accel_m_s2
    d[:, IMU_ACCEL + 3:] = np.asarray(linear_acceleration_cov, float).reshape(9)
    out[:, off:] = d.view(np.uint8).reshape(n, 8 * IMU_DOUBLES)
    return out


def _gather(buf: U8Array, at: IntArray, width: int) -> U8Array:
    """``buf[at[k] : at[k] + width]`` for every k, as an ``(N, width)`` array."""
    return buf[at[:, None] + np.arange(width)]


def _windows(buf: Any, width: int) -> U8Array:
    """Row p = ``buf[p : p + width]``: a zero-copy strided view of the bytes."""
    b = buf if isinstance(buf, np.ndarray) else np.frombuffer(buf, np.uint8)
    return np.lib.stride_tricks.as_strided(b, (max(len(b) - width + 1, 0), width), (1, 1),
                                           writeable=False)


def read_at(buf: Any, at: IntArray, dtype: str, count: int = 1) -> NDArray[Any]:
    """``count`` values of ``dtype`` (little-endian, any alignment) starting at each byte
    offset ``at[k]`` of ``buf``, as an ``(N, count)`` array.

    Takes rows of a strided view of the bytes (one row per offset), so the temporaries are
    the values' own bytes plus one index per message (bounded memory per mcap chunk).
    """
    dt = np.dtype(dtype)
    return _windows(buf, dt.itemsize * count)[at].view(dt)


@dataclass
class ImuColumns:
    """Decoded Imu messages (:func:`decode_imu`), in message order.

    ``ok[k]`` is False where message k does not have the fixed layout (its row of the other
    arrays is then meaningless); ``frame[k]`` indexes ``frame_ids``.
    """

    stamps_ns: IntArray
    gyro_rad_s: NDArray[np.float64]
    accel_m_s2: NDArray[np.float64]
    frame: IntArray
    frame_ids: list[str]
    ok: NDArray[np.bool_]


def decode_imu(buf: U8Array, starts: Any, lengths: Any) -> ImuColumns:
    """Decode the Imu messages ``buf[starts[k] : starts[k] + lengths[k]]`` all at once.

    Vectorised over the messages: the frame_id length of each message gives its layout, the
    stamps and the six values are gathered at their offsets, and the frame_ids are told
    apart by their bytes (one comparison when all are equal, the usual case). A message is
    ``ok`` when its encapsulation is little-endian CDR, its frame_id is UTF-8 with at least
    the NUL, and its length is exactly the layout's.
    """
    buf = np.frombuffer(buf, np.uint8) if not isinstance(buf, np.ndarray) else buf
    s = np.asarray(starts, np.int64)
    ln = np.asarray(lengths, np.int64)
    n = len(s)
    ok = ln >= 16
    s_safe = s if ok.all() else np.where(ok, s, 0)
    head = read_at(buf, s_safe, '<u4', 4)  # encapsulation, sec, nanosec, frame_id length
    flen = head[:, 3].astype(np.int64)
    off = 4 + (12 + flen + 7) // 8 * 8
    ok &= (head[:, 0] == _CDR_LE_U32) & (flen >= 1) & (ln == off + 8 * IMU_DOUBLES)
    stamps = head[:, 1].view('<i4').astype(np.int64) * NS_PER_S + head[:, 2]
    at = np.where(ok, s + off, 0)
    gyro = read_at(buf, at + 8 * IMU_GYRO, '<f8', 3).astype(np.float64)
    accel = read_at(buf, at + 8 * IMU_ACCEL, '<f8', 3).astype(np.float64)
    frame = np.zeros(n, np.int64)
    frame_ids: list[str] = []
    lengths = flen[ok]
    for length in (lengths[:1] if (lengths == lengths[:1]).all() else
                   np.unique(lengths)).tolist():
        sel = np.flatnonzero(ok & (flen == length))
        text = _gather(buf, s[sel] + 16, length - 1) if length > 1 else \
            np.zeros((len(sel), 0), np.uint8)
        if (text == text[0]).all():
            uniq, inverse = text[:1], np.zeros(len(sel), np.int64)
        else:
            uniq, inverse = np.unique(text, axis=0, return_inverse=True)
        for k, row in enumerate(uniq):
            try:
                fid = row.tobytes().decode('utf-8')
            except UnicodeDecodeError:
                ok[sel[inverse.reshape(-1) == k]] = False
                continue
            frame[sel[inverse.reshape(-1) == k]] = len(frame_ids)
            frame_ids.append(fid)
    return ImuColumns(stamps, gyro, accel, frame, frame_ids, ok)


# -------------------------------------------------------------------------- JointState

def joint_state_layout(frame_id: str, names: tuple[str, ...], n_vel: int, n_eff: int
                       ) -> tuple[NDArray[np.bool_], int, int, int]:
    """Structural mask, offsets of the position and velocity doubles, and length of a
    JointState message (offsets from the start of the message).

    The mask covers the bytes that are equal in every message of this layout: the
    encapsulation, frame_id, the counts and the names (not the stamp, not the values).
    """
    fid = frame_id.encode('utf-8') + b'\x00'
    body = 12 + len(fid)
    spans = [(0, 4), (12, 4 + body)]

    def count_at(body: int) -> int:
        body = _align(body, 4)
        spans.append((4 + body, 8 + body))
        return body + 4

    body = count_at(body)
    for name in names:
        body = _align(body, 4)
        encoded = name.encode('utf-8') + b'\x00'
        spans.append((4 + body, 8 + body + len(encoded)))
        body += 4 + len(encoded)
    offsets = []
    for count in (len(names), n_vel, n_eff):
        body = count_at(body)
        if count:
            body = _align(body, 8)
        offsets.append(4 + body)
        body += 8 * count
    mask = np.zeros(4 + body, bool)
    for a, b in spans:
        mask[a:b] = True
    return mask, offsets[0], offsets[1], 4 + body


def joint_state_cdr(stamp_ns: int, frame_id: str, names: Any, positions: Any,
                    velocities: Any = (), efforts: Any = ()) -> bytes:
    """One serialised ``sensor_msgs/JointState``.

    Raises
    ------
    InputError
        A stamp outside the int32 seconds of ``builtin_interfaces/Time``; not one position
        (and none or one velocity) per name.
    """
    n_pos, n_vel = np.size(positions), np.size(velocities)
    if n_pos != len(names) or n_vel not in (0, len(names)):
        raise InputError(f'JointState at {stamp_ns} ns: {len(names)} names, {n_pos} '
                         f'positions, {n_vel} velocities')
    sec, nanosec = check_stamps([stamp_ns])
    out = bytearray(CDR_LE)
    fid = frame_id.encode('utf-8') + b'\x00'
    out += struct.pack('<iII', int(sec[0]), int(nanosec[0]), len(fid)) + fid

    def pad(n: int) -> None:
        out.extend(b'\x00' * (-(len(out) - 4) % n))

    pad(4)
    out += struct.pack('<I', len(names))
    for name in names:
        pad(4)
        encoded = str(name).encode('utf-8') + b'\x00'
        out += struct.pack('<I', len(encoded)) + encoded
    for values in (positions, velocities, efforts):
        v = np.asarray(values, '<f8').reshape(-1)
        pad(4)
        out += struct.pack('<I', len(v))
        if len(v):
            pad(8)
            out += v.tobytes()
    return bytes(out)


def joint_state_fields_from_cdr(data: bytes) -> tuple[int, str, tuple[str, ...],
                                                      NDArray[np.float64],
                                                      NDArray[np.float64], int]:
    """``(stamp_ns, frame_id, names, positions, velocities, n_efforts)`` of one serialised
    ``sensor_msgs/JointState`` (``velocities`` empty when the message has none).

    Raises
    ------
    InputError
        Not a little-endian CDR JointState, or truncated.
    """
    try:
        if len(data) < 16 or data[:4] != CDR_LE:
            raise ValueError('encapsulation')
        sec, nanosec, n = _IMU_HEAD.unpack_from(data, 4)
        frame_id = data[16:16 + n - 1].decode('utf-8')
        pos = 16 + n

        def count() -> int:
            nonlocal pos
            pos += -(pos - 4) % 4
            (c,) = struct.unpack_from('<I', data, pos)
            pos += 4
            return int(c)

        names = []
        for _ in range(count()):
            ln = count()
            names.append(data[pos:pos + ln - 1].decode('utf-8'))
            pos += ln
        arrays = []
        for _ in range(3):
            c = count()
            if c:
                pos += -(pos - 4) % 8
            if pos + 8 * c > len(data):
                raise ValueError('truncated')
            arrays.append(np.frombuffer(data, '<f8', c, pos).astype(np.float64))
            pos += 8 * c
    except (ValueError, struct.error, UnicodeDecodeError) as exc:
        raise InputError(f'not a CDR sensor_msgs/JointState ({exc})') from None
    return (sec * NS_PER_S + nanosec, frame_id, tuple(names), arrays[0], arrays[1],
            len(arrays[2]))


def decode_joint_rows(rows: U8Array) -> tuple[IntArray, tuple[str, ...],
                                              NDArray[np.float64],
                                              NDArray[np.float64] | None] | None:
    """Decode equal-length JointState messages (rows of one array) that share the first
    row's layout (frame_id, names, counts): ``(stamps_ns, names, positions, velocities or
    None)``, or None when they do not (or the first is not one position per name, or some
    but not all velocities)."""
    try:
        _, frame_id, names, pos0, vel0, n_eff = joint_state_fields_from_cdr(rows[0].tobytes())
    except InputError:
        return None
    n, n_vel = len(names), len(vel0)
    if len(pos0) != n or n_vel not in (0, n):
        return None
    mask, off_p, off_v, length = joint_state_layout(frame_id, names, n_vel, n_eff)
    if length != rows.shape[1] or not np.all(rows[:, mask] == rows[0, mask]):
        return None
    pos = rows[:, off_p:off_p + 8 * n].copy().view('<f8').astype(np.float64)
    vel = rows[:, off_v:off_v + 8 * n].copy().view('<f8').astype(np.float64) if n_vel \
        else None
    head = rows[:, 4:12].copy().view('<u4')
    stamps = head[:, 0].view('<i4').astype(np.int64) * NS_PER_S + head[:, 1]
    return stamps, names, pos.reshape(-1, n), None if vel is None else vel.reshape(-1, n)


def gather_rows(buf: U8Array, starts: Any, length: int) -> U8Array:
    """Messages of one length as rows: ``buf[starts[k] : starts[k] + length]``."""
    return _windows(buf, length)[np.asarray(starts, np.int64)]


__all__ = ['CDR_LE', 'ImuColumns', 'NS_PER_S', 'check_stamps', 'decode_imu',
           'decode_joint_rows', 'gather_rows', 'imu_cdr', 'imu_fields_from_cdr', 'imu_layout',
           'read_at',
           'joint_state_cdr', 'joint_state_fields_from_cdr', 'joint_state_layout', 'pack_imu']
