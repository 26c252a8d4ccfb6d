"""Read and write ROS 2 bags of ``sensor_msgs/Imu`` and ``sensor_msgs/JointState`` (rosbags).

What works with rosbags 0.11 (measured, see ``test/test_bag.py``):

- writing: ``rosbags.rosbag2.Writer`` only creates bag *directories* (``metadata.yaml`` plus
  one storage file), version 9 (Jazzy), storage ``mcap`` or ``sqlite3``. A path ending in
  ``.mcap`` is written as a directory bag in a temporary place and its single ``.mcap`` file
  is moved to the path (the mcap file is self-contained: schemas, channels, chunk index and
  statistics are inside it; ``metadata.yaml`` only repeats them).
- reading: ``rosbags.rosbag2.Reader`` reads a bag directory of either storage, a lone
  ``.mcap`` file and a lone ``.db3`` file. Messages come in log-time (record timestamp)
  order; the writer here sets the record timestamp equal to the header stamp.

Every write is atomic: the bag is written under a temporary name in the target's directory
and renamed into place, so a failed or interrupted write leaves no partial bag.

Speed: ``Typestore.deserialize_cdr`` costs about 10 us per Imu message (~100k msgs/s).
:func:`read_bag` therefore decodes the fixed CDR layout of a topic's messages with numpy
in one pass when every message on the topic has the same byte layout (one frame_id, one
joint-name list), checked byte for byte, and falls back to rosbags otherwise;
:func:`write_bag` packs Imu messages the same way. Both paths are tested to give the bytes
and values rosbags gives.
"""
from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..core.errors import BagError, InputError
from ..core.types import ImuBatch, ImuSample, JointBatch, JointSample
from .convert import (IMU_MSGTYPE, JOINT_STATE_MSGTYPE, ImuCovariances, NS_PER_S,
                      imu_msg_from_sample, imu_sample_from_msg, joint_sample_from_msg,
                      joint_state_msg_from_sample)

DEFAULT_IMU_TOPIC = '/imu/data_raw'
DEFAULT_JOINT_TOPIC = '/joint_states'
Storage = Literal['mcap', 'sqlite3']


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


@dataclass(frozen=True)
class TopicInfo:
    """A topic in a bag: message type and number of messages."""

    msgtype: str
    count: int


# --------------------------------------------------------------------------------------------
# Fixed-layout CDR packing/unpacking (numpy). rosbags handles one message per Python call;
# a topic whose messages share one byte layout is packed/unpacked for all rows at once.
# Layout (little-endian CDR, 4-byte encapsulation header, alignment relative to the body):
#   Header: int32 sec, uint32 nanosec, uint32 len(frame_id)+1, frame_id bytes, NUL
#   Imu: align 8, then 37 float64: orientation(4), orientation_cov(9), angular_velocity(3),
#        angular_velocity_cov(9), linear_acceleration(3), linear_acceleration_cov(9)
# --------------------------------------------------------------------------------------------

_CDR_LE = b'\x00\x01\x00\x00'


def _align(offset: int, n: int) -> int:
    return (offset + n - 1) // n * n


def _header_bytes(frame_id: str) -> tuple[bytes, int]:
    """Header bytes after the stamp (length-prefixed frame_id) and the body offset after it."""
    fid = frame_id.encode('utf-8') + b'\x00'
    tail = len(fid).to_bytes(4, 'little') + fid
    return tail, 8 + len(tail)


def _imu_layout(frame_id: str) -> tuple[bytes, int, int]:
    """(template prefix after the stamp, offset of the 37 doubles, message length) in bytes."""
    tail, end = _header_bytes(frame_id)
    doubles = _align(end, 8)
    prefix = tail + b'\x00' * (doubles - end)
    return prefix, 4 + doubles, 4 + doubles + 37 * 8


def _pack_imu(imu: ImuBatch, frame_id: str, cov: ImuCovariances) -> np.ndarray:
    """All Imu messages of ``imu`` serialised, as a (N, length) uint8 array."""
    prefix, off, length = _imu_layout(frame_id)
    n = len(imu)
    out = np.zeros((n, length), np.uint8)
    out[:, 0:4] = np.frombuffer(_CDR_LE, np.uint8)
    sec, nanosec = np.divmod(imu.stamps_ns.astype(np.int64), NS_PER_S)
    if n and (sec.min() < -2 ** 31 or sec.max() >= 2 ** 31):
        raise InputError('IMU stamps do not fit builtin_interfaces/Time (int32 seconds)')
    out[:, 4:8] = sec.astype('<i4').view(np.uint8).reshape(n, 4)
    out[:, 8:12] = nanosec.astype('<u4').view(np.uint8).reshape(n, 4)
    out[:, 12:off] = np.frombuffer(prefix, np.uint8)
    d = np.zeros((n, 37), '<f8')
    d[:, 3] = 1.0
    d[:, 4] = -1.0
    d[:, 13:16] = imu.gyro_rad_s
    d[:, 16:25] = np.asarray(cov.angular_velocity_rad2_s2, float).reshape(9)
    d[:, 25:28] = imu.accel_m_s2
    d[:, 28:37] = np.asarray(cov.linear_acceleration_m2_s4, float).reshape(9)
    out[:, off:] = d.view(np.uint8).reshape(n, 37 * 8)
    return out


def _stamps_from_rows(rows: np.ndarray) -> np.ndarray:
    sec = rows[:, 4:8].copy().view('<i4').reshape(-1).astype(np.int64)
    nanosec = rows[:, 8:12].copy().view('<u4').reshape(-1).astype(np.int64)
    return sec * NS_PER_S + nanosec


def _same_layout(rows: np.ndarray, mask: np.ndarray) -> bool:
    """Whether every row equals the first on the structural bytes ``mask``."""
    return bool(np.all(rows[:, mask] == rows[0, mask]))


def _unpack_imu(rows: np.ndarray) -> ImuBatch | None:
    """Decode equal-length Imu messages, or None if their layout is not one fixed layout."""
    first = bytes(rows[0])
    if first[:4] != _CDR_LE:
        return None
    flen = int.from_bytes(first[12:16], 'little')
    if flen < 1 or 16 + flen > len(first):
        return None
    try:
        frame_id = first[16:16 + flen - 1].decode('utf-8')
    except UnicodeDecodeError:
        return None
    prefix, off, length = _imu_layout(frame_id)
    if length != rows.shape[1] or first[12:off] != prefix:
        return None
    mask = np.zeros(length, bool)
    mask[0:4] = True
    mask[12:off] = True
    if not _same_layout(rows, mask):
        return None
    d = rows[:, off:].copy().view('<f8').reshape(-1, 37)
    return ImuBatch(_stamps_from_rows(rows), d[:, 13:16].astype(np.float64),
                    d[:, 25:28].astype(np.float64), frame_id)


def _joint_layout(frame_id: str, names: tuple[str, ...], n_vel: int,
                  n_eff: int) -> tuple[np.ndarray, int, int, int]:
    """Structural mask, offsets of position and velocity doubles, and length of a JointState.

    JointState: Header, sequence<string> name, then sequence<float64> position, velocity,
    effort (uint32 count aligned to 4, doubles aligned to 8). The mask covers the bytes that
    must be equal in every message of one layout: encapsulation, frame_id, counts, names.
    """
    _, body = _header_bytes(frame_id)
    spans = [(0, 4), (4 + 8, 4 + body)]

    def count_at(body: int) -> int:
        body = _align(body, 4)
        spans.append((4 + body, 4 + body + 4))
        return body + 4

    body = count_at(body)
    for name in names:
        body = _align(body, 4)
        encoded = name.encode('utf-8') + b'\x00'
        spans.append((4 + body, 4 + body + 4 + len(encoded)))
        body += 4 + len(encoded)
    offsets = []
    for count in (len(names), n_vel, n_eff):
        body = count_at(body)
        if count:
            body = _align(body, 8)
        offsets.append(4 + body)
        body += 8 * count
    length = 4 + body
    mask = np.zeros(length, bool)
    for a, b in spans:
        mask[a:b] = True
    return mask, offsets[0], offsets[1], length


def _unpack_joints(rows: np.ndarray, first_msg: Any) -> JointBatch | None:
    """Decode equal-length JointState messages laid out like ``first_msg`` (deserialised)."""
    names = tuple(str(n) for n in first_msg.name)
    n_pos, n_vel, n_eff = len(first_msg.position), len(first_msg.velocity), len(first_msg.effort)
    if n_pos != len(names) or n_vel not in (0, len(names)):
        return None
    mask, off_p, off_v, length = _joint_layout(str(first_msg.header.frame_id), names, n_vel,
                                               n_eff)
    if length != rows.shape[1] or not _same_layout(rows, mask):
        return None
    n = len(names)
    pos = rows[:, off_p:off_p + 8 * n].copy().view('<f8').reshape(-1, n).astype(np.float64)
    vel = (rows[:, off_v:off_v + 8 * n].copy().view('<f8').reshape(-1, n).astype(np.float64)
           if n_vel else None)
    if not (np.array_equal(pos[0], np.asarray(first_msg.position, float), equal_nan=True)
            and (vel is None or np.array_equal(vel[0], np.asarray(first_msg.velocity, float),
                                               equal_nan=True))):
        return None  # layout guess disagrees with rosbags: use the slow path
    return JointBatch(_stamps_from_rows(rows), names, pos, vel)


# --------------------------------------------------------------------------------------------
# Opening and checking a bag
# --------------------------------------------------------------------------------------------

def _check_path(path: Path) -> None:
    if not path.exists():
        raise BagError(f'{path}: no such bag (file or directory not found)')
    if path.is_dir():
        if not (path / 'metadata.yaml').is_file():
            raise BagError(f'{path}: not a ROS 2 bag (directory without metadata.yaml)')
    elif path.suffix not in ('.mcap', '.db3'):
        raise BagError(f'{path}: not a ROS 2 bag (expected a bag directory, a .mcap or a '
                       '.db3 file)')


@contextmanager
def _open_reader(path: str | os.PathLike[str]) -> Iterator[Any]:
    """An open rosbags Reader, with every failure turned into one BagError line."""
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.errors import ReaderError
    p = Path(path)
    _check_path(p)
    try:
        reader = Reader(p)
        reader.open()
    except (ReaderError, OSError, KeyError, ValueError, TypeError, IndexError) as exc:
        raise BagError(f'{p}: cannot open bag, truncated or corrupt? '
                       f'({_oneline(exc)})') from None
    except Exception as exc:  # noqa: BLE001 - any other rosbags/sqlite failure: same story
        raise BagError(f'{p}: cannot open bag, truncated or corrupt? '
                       f'({type(exc).__name__}: {_oneline(exc)})') from None
    try:
        yield reader
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001 - closing a broken file must not mask the error
            pass


def _oneline(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _topics_of(reader: Any) -> dict[str, TopicInfo]:
    out: dict[str, TopicInfo] = {}
    for c in reader.connections:
        prev = out.get(c.topic)
        count = int(c.msgcount) + (prev.count if prev else 0)
        out[c.topic] = TopicInfo(c.msgtype, count)
    return dict(sorted(out.items()))


def list_topics(path: str | os.PathLike[str]) -> dict[str, TopicInfo]:
    """Topics of a bag: ``{name: TopicInfo(msgtype, count)}`` (sorted by name)."""
    with _open_reader(path) as reader:
        return _topics_of(reader)


def _describe(topics: dict[str, TopicInfo]) -> str:
    return ', '.join(f'{t} ({i.msgtype}, {i.count} msgs)' for t, i in topics.items()) or 'none'


def _connections(reader: Any, path: Path, wanted: dict[str, str]) -> list[Any]:
    """Connections for ``{topic: msgtype}``; BagError for empty bag, missing topic, bad type."""
    topics = _topics_of(reader)
    if reader.message_count == 0 or not topics:
        raise BagError(f'{path}: bag is empty (no messages)')
    for topic, msgtype in wanted.items():
        info = topics.get(topic)
        if info is None:
            raise BagError(f'{path}: no topic {topic!r} in bag (topics: {_describe(topics)})')
        if info.msgtype != msgtype:
            raise BagError(f'{path}: topic {topic!r} has type {info.msgtype}, '
                           f'expected {msgtype}')
        if info.count == 0:
            raise BagError(f'{path}: topic {topic!r} has no messages')
    return [c for c in reader.connections if c.topic in wanted]


def _wanted(imu_topic: str | None, joint_topic: str | None) -> dict[str, str]:
    wanted: dict[str, str] = {}
    if imu_topic:
        wanted[imu_topic] = IMU_MSGTYPE
    if joint_topic:
        if joint_topic == imu_topic:
            raise BagError(f'IMU and joint topics are the same ({joint_topic!r})')
        wanted[joint_topic] = JOINT_STATE_MSGTYPE
    if not wanted:
        raise BagError('no topic to read: give an IMU topic, a joint topic or both')
    return wanted


def _raw_messages(reader: Any, path: Path, conns: list[Any]) -> Iterator[tuple[Any, int, Any]]:
    """rosbags' message stream with read errors (truncated data) turned into BagError."""
    from rosbags.rosbag2.errors import ReaderError
    it = reader.messages(connections=conns)
    last = None
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except (ReaderError, OSError, ValueError, KeyError, IndexError) as exc:
            where = f' after log time {last} ns' if last is not None else ''
            raise BagError(f'{path}: corrupt or truncated data{where} '
                           f'({_oneline(exc)})') from None
        except Exception as exc:  # noqa: BLE001 - e.g. sqlite/zstd errors from the storage
            raise BagError(f'{path}: corrupt or truncated data ({type(exc).__name__}: '
                           f'{_oneline(exc)})') from None
        last = item[1]
        yield item


def _deserialize(store: Any, path: Path, conn: Any, t_ns: int, raw: Any) -> Any:
    try:
        return store.deserialize_cdr(raw, conn.msgtype)
    except Exception as exc:  # noqa: BLE001 - any decoding failure means a corrupt message
        raise BagError(f'{path}: corrupt {conn.msgtype} message on {conn.topic!r} at log '
                       f'time {t_ns} ns ({type(exc).__name__}: {_oneline(exc)})') from None


def _sample(store: Any, path: Path, conn: Any, t_ns: int, raw: Any) -> ImuSample | JointSample:
    msg = _deserialize(store, path, conn, t_ns, raw)
    try:
        if conn.msgtype == IMU_MSGTYPE:
            return imu_sample_from_msg(msg)
        return joint_sample_from_msg(msg)
    except InputError as exc:
        raise BagError(f'{path}: bad message on {conn.topic!r} at log time {t_ns} ns: '
                       f'{exc}') from None


def iter_bag(path: str | os.PathLike[str], imu_topic: str | None = DEFAULT_IMU_TOPIC,
             joint_topic: str | None = DEFAULT_JOINT_TOPIC) -> 'BagSamples':
    """Stream the IMU and joint samples of a bag in log-time order, with bounded memory.

    Parameters
    ----------
    path:
        Bag directory (mcap or sqlite3 storage), or a single ``.mcap``/``.db3`` file.
    imu_topic, joint_topic:
        ``sensor_msgs/Imu`` and ``sensor_msgs/JointState`` topics; ``None`` skips one.

    Yields
    ------
    ImuSample | JointSample
        Stamped with the header stamp, in the order of the record (log) timestamps.
        Values are not checked (NaN passes through: the estimator rejects it).
        The returned iterator also has :meth:`BagSamples.batches` (the same data as
        :func:`iter_bag_batches`), which replay uses to skip the per-sample objects.

    Raises
    ------
    BagError
        Missing path, not a bag, empty bag, missing topic, wrong type, corrupt data.
    """
    return BagSamples(Path(path), imu_topic, joint_topic)


class BagSamples:
    """The iterator :func:`iter_bag` returns: samples one by one, or :meth:`batches`.

    Nothing is opened before the first ``next()`` (errors surface while iterating, as from
    a generator).
    """

    def __init__(self, path: Path, imu_topic: str | None, joint_topic: str | None) -> None:
        self.path = path
        self.imu_topic = imu_topic
        self.joint_topic = joint_topic
        self._it: Iterator[ImuSample | JointSample] | None = None

    def __iter__(self) -> 'BagSamples':
        return self

    def __next__(self) -> ImuSample | JointSample:
        if self._it is None:
            self._it = _iter_samples(self.path, self.imu_topic, self.joint_topic)
        return next(self._it)

    def batches(self, window_msgs: int | None = None) -> Iterator[ImuBatch | JointBatch]:
        """:func:`iter_bag_batches` of the same bag and topics."""
        return iter_bag_batches(self.path, self.imu_topic, self.joint_topic,
                                window_msgs or BATCH_WINDOW_MSGS)


def _iter_samples(p: Path, imu_topic: str | None, joint_topic: str | None
                  ) -> Iterator[ImuSample | JointSample]:
    wanted = _wanted(imu_topic, joint_topic)
    with _open_reader(p) as reader:
        conns = _connections(reader, p, wanted)
        store = _typestore()
        buf: list[tuple[Any, int, Any]] = []
        for item in _raw_messages(reader, p, conns):
            buf.append(item)
            if len(buf) >= ITER_CHUNK_MSGS:
                yield from _decode_chunk(store, p, buf)
                buf = []
        yield from _decode_chunk(store, p, buf)


BATCH_WINDOW_MSGS = 16384  # raw messages per window of iter_bag_batches (~5 MB of Imu)


def iter_bag_batches(path: str | os.PathLike[str], imu_topic: str | None = DEFAULT_IMU_TOPIC,
                     joint_topic: str | None = DEFAULT_JOINT_TOPIC,
                     window_msgs: int = BATCH_WINDOW_MSGS) -> Iterator[ImuBatch | JointBatch]:
    """Stream a bag as :class:`JointBatch` / :class:`ImuBatch` chunks, with bounded memory.

    The messages are read in log-time order in windows of ``window_msgs``; each window is
    decoded with the numpy fast path (:func:`read_bag`'s) and yields its joint states first,
    then its IMU samples, each as batches in log-time order. Joint states thus arrive up to
    one window *early*, never late, relative to the IMU samples (the estimator buffers joint
    states; its results do not depend on how far ahead they are). Where the fast path does
    not apply, messages are decoded one by one and split into runs of one joint-name list /
    one IMU frame_id, so that every sample keeps its own names and frame_id (as with
    :func:`iter_bag`). Memory: one window of raw and decoded messages.

    Raises
    ------
    BagError
        As :func:`iter_bag`.
    """
    if window_msgs < 1:
        raise InputError(f'window_msgs must be >= 1, got {window_msgs}')
    p = Path(path)
    wanted = _wanted(imu_topic, joint_topic)
    with _open_reader(p) as reader:
        conns = _connections(reader, p, wanted)
        store = _typestore()
        pending: dict[str, list[Any]] = {t: [] for t in wanted}
        first: dict[str, tuple[Any, int]] = {}
        count = 0
        for conn, t_ns, raw in _raw_messages(reader, p, conns):
            if not pending[conn.topic]:
                first[conn.topic] = (conn, t_ns)
            pending[conn.topic].append(raw)
            count += 1
            if count >= window_msgs:
                yield from _decode_window(store, p, pending, first, joint_topic)
                count = 0
        yield from _decode_window(store, p, pending, first, joint_topic)


def _decode_window(store: Any, path: Path, pending: dict[str, list[Any]],
                   first: dict[str, tuple[Any, int]], joint_topic: str | None
                   ) -> Iterator[ImuBatch | JointBatch]:
    """The window's joint batches, then its IMU batches; empties ``pending``."""
    order = sorted(pending, key=lambda t: t != joint_topic)  # the joint topic first
    for topic in order:
        raws = pending[topic]
        if not raws:
            continue
        conn, t0 = first[topic]
        pending[topic] = []
        if topic == joint_topic:
            yield from _window_joints(store, path, conn, t0, raws)
        else:
            yield from _window_imu(store, path, conn, t0, raws)


def _window_imu(store: Any, path: Path, conn: Any, t0: int, raws: list[Any]
                ) -> Iterator[ImuBatch]:
    first = _sample(store, path, conn, t0, raws[0])
    rows = _rows(raws)
    batch = _unpack_imu(rows) if rows is not None else None
    if batch is not None and _same_sample(batch, first):
        yield batch
        return
    samples = [_sample(store, path, conn, t0, r) for r in raws]
    k = 0
    while k < len(samples):  # runs of one frame_id
        j = k + 1
        while j < len(samples) and samples[j].frame_id == samples[k].frame_id:
            j += 1
        yield ImuBatch.from_samples(samples[k:j])  # type: ignore[arg-type]
        k = j


def _fast_joints(store: Any, path: Path, conn: Any, t0: int, raws: list[Any]
                 ) -> JointBatch | None:
    """The numpy decode of a run of JointState messages of one layout, or None when the
    messages differ in layout (the first one is decoded by rosbags and checked either way)."""
    first_msg = _deserialize(store, path, conn, t0, raws[0])
    _sample(store, path, conn, t0, raws[0])
    rows = _rows(raws)
    return _unpack_joints(rows, first_msg) if rows is not None else None


def _window_joints(store: Any, path: Path, conn: Any, t0: int, raws: list[Any]
                   ) -> Iterator[JointBatch]:
    batch = _fast_joints(store, path, conn, t0, raws)
    if batch is not None:
        yield batch
        return
    samples: list[JointSample] = [_sample(store, path, conn, t0, r)  # type: ignore[misc]
                                  for r in raws]
    k = 0
    while k < len(samples):  # runs of one name list and one position count
        names = samples[k].names
        n_pos = np.shape(samples[k].positions_rad)
        j = k + 1
        while j < len(samples) and samples[j].names == names \
                and np.shape(samples[j].positions_rad) == n_pos:
            j += 1
        run = samples[k:j]
        vel = None
        if all(s.velocities_rad_s is not None
               and np.shape(s.velocities_rad_s) == n_pos for s in run):
            vel = np.array([s.velocities_rad_s for s in run], float)
        pos = np.array([s.positions_rad for s in run], float)
        if pos.ndim != 2:  # positions not one per name: one sample per batch (guard rejects)
            for s in run:
                yield JointBatch(np.array([s.stamp_ns], np.int64), s.names,
                                 np.asarray(s.positions_rad, float)[None], None)
        else:
            yield JointBatch(np.array([s.stamp_ns for s in run], np.int64), names, pos, vel)
        k = j


ITER_CHUNK_MSGS = 2048  # messages decoded together by iter_bag (~0.7 MB of Imu messages)


def _decode_chunk(store: Any, path: Path, buf: list[tuple[Any, int, Any]]
                  ) -> Iterator[ImuSample | JointSample]:
    """The samples of consecutive raw messages, in their order (numpy fast path per topic)."""
    if not buf:
        return
    groups: dict[str, list[int]] = {}
    for k, (conn, _, _) in enumerate(buf):
        groups.setdefault(conn.topic, []).append(k)
    decoded: dict[str, Any] = {}
    for topic, idx in groups.items():
        conn, t0, raw0 = buf[idx[0]]
        raws = [buf[k][2] for k in idx]
        rows = _rows(raws)
        batch: ImuBatch | JointBatch | None = None
        if rows is not None and conn.msgtype == IMU_MSGTYPE:
            first = _sample(store, path, conn, t0, raw0)
            batch = _unpack_imu(rows)
            if batch is not None and not _same_sample(batch, first):
                batch = None
        elif rows is not None:
            first_msg = _deserialize(store, path, conn, t0, raw0)
            _sample(store, path, conn, t0, raw0)
            batch = _unpack_joints(rows, first_msg)
        decoded[topic] = batch
    pos = dict.fromkeys(groups, 0)
    for conn, t_ns, raw in buf:
        batch = decoded[conn.topic]
        if batch is None:
            yield _sample(store, path, conn, t_ns, raw)
        else:
            yield batch.sample(pos[conn.topic])
            pos[conn.topic] += 1


def _same_sample(batch: ImuBatch, first: ImuSample | JointSample) -> bool:
    """Whether the fast decode's first sample equals rosbags' decode of the same message."""
    assert isinstance(first, ImuSample)
    s = batch.sample(0)
    return (s.stamp_ns == first.stamp_ns and s.frame_id == first.frame_id
            and np.array_equal(s.gyro_rad_s, first.gyro_rad_s, equal_nan=True)
            and np.array_equal(s.accel_m_s2, first.accel_m_s2, equal_nan=True))


def _joint_batch_slow(samples: list[JointSample], path: Path, topic: str) -> JointBatch:
    """Stack joint samples onto the first sample's name order (names may be permuted)."""
    names = samples[0].names
    index = {n: i for i, n in enumerate(names)}
    m, n = len(samples), len(names)
    pos = np.empty((m, n))
    vel = np.full((m, n), np.nan)
    any_vel = False
    for k, s in enumerate(samples):
        if s.names != names:
            if sorted(s.names) != sorted(names):
                raise BagError(f'{path}: joint names on {topic!r} change at stamp '
                               f'{s.stamp_ns} ns: {list(s.names)} vs {list(names)}')
            order = [index[x] for x in s.names]
        else:
            order = list(range(n))
        pos[k, order] = s.positions_rad
        if s.velocities_rad_s is not None:
            vel[k, order] = s.velocities_rad_s
            any_vel = True
    stamps = np.array([s.stamp_ns for s in samples], np.int64)
    return JointBatch(stamps, names, pos, vel if any_vel else None)


def read_bag(path: str | os.PathLike[str], imu_topic: str = DEFAULT_IMU_TOPIC,
             joint_topic: str | None = DEFAULT_JOINT_TOPIC) -> tuple[ImuBatch, JointBatch]:
    """Read a whole bag into an :class:`ImuBatch` and a :class:`JointBatch`.

    Samples keep the bag's log-time order and their header stamps. Joint samples whose names
    are a permutation of the first message's names are reordered to it; missing velocities
    of some messages are NaN (all missing: ``None``). With ``joint_topic=None`` the joint
    batch is empty. Raises :class:`BagError` as :func:`iter_bag` does.
    """
    p = Path(path)
    wanted = _wanted(imu_topic, joint_topic)
    imu_parts: list[ImuBatch] = []
    joint_parts: list[JointBatch] = []

    def flush(topic: str) -> None:
        """Decode the pending raw messages of ``topic`` (bounds the raw bytes held)."""
        raws = pending[topic]
        if not raws:
            return
        conn, t0 = first[topic]
        if topic == imu_topic:
            imu_parts.append(_read_imu(store, p, conn, t0, raws))
        else:
            joint_parts.append(_read_joints(store, p, conn, t0, raws))
        pending[topic] = []

    with _open_reader(p) as reader:
        conns = _connections(reader, p, wanted)
        store = _typestore()
        pending: dict[str, list[Any]] = {t: [] for t in wanted}
        first: dict[str, tuple[Any, int]] = {}
        for conn, t_ns, raw in _raw_messages(reader, p, conns):
            if conn.topic not in first or not pending[conn.topic]:
                first[conn.topic] = (conn, t_ns)
            pending[conn.topic].append(raw)
            if len(pending[conn.topic]) >= READ_CHUNK_MSGS:
                flush(conn.topic)
        for topic in wanted:
            flush(topic)
    imu = _concat_imu(imu_parts)
    if joint_topic is None:
        return imu, JointBatch(np.zeros(0, np.int64), (), np.zeros((0, 0)), None)
    return imu, _concat_joints(joint_parts, p, joint_topic)


READ_CHUNK_MSGS = 65536  # raw messages per topic decoded together by read_bag


def _concat_imu(parts: list[ImuBatch]) -> ImuBatch:
    if len(parts) == 1:
        return parts[0]
    return ImuBatch(np.concatenate([b.stamps_ns for b in parts]),
                    np.concatenate([b.gyro_rad_s for b in parts]),
                    np.concatenate([b.accel_m_s2 for b in parts]),
                    parts[0].frame_id)  # as ImuBatch.from_samples: the first one's


def _concat_joints(parts: list[JointBatch], path: Path, topic: str) -> JointBatch:
    """Join chunk batches onto the first chunk's joint-name order."""
    if len(parts) == 1:
        return parts[0]
    names = parts[0].names
    pos, vel = [], []
    any_vel = any(b.velocities_rad_s is not None for b in parts)
    for b in parts:
        if b.names != names:
            if sorted(b.names) != sorted(names):
                raise BagError(f'{path}: joint names on {topic!r} change at stamp '
                               f'{int(b.stamps_ns[0])} ns: {list(b.names)} vs {list(names)}')
            order = [b.names.index(n) for n in names]
        else:
            order = list(range(len(names)))
        pos.append(b.positions_rad[:, order])
        v = b.velocities_rad_s
        vel.append(np.full_like(b.positions_rad, np.nan) if v is None else v[:, order])
    return JointBatch(np.concatenate([b.stamps_ns for b in parts]), names,
                      np.concatenate(pos), np.concatenate(vel) if any_vel else None)


def _rows(raws: list[Any]) -> np.ndarray | None:
    """The messages as one (N, length) uint8 array if they all have one length."""
    length = len(raws[0])
    if any(len(r) != length for r in raws):
        return None
    return np.frombuffer(b''.join(raws), np.uint8).reshape(len(raws), length)


def _read_imu(store: Any, path: Path, conn: Any, t0: int, raws: list[Any]) -> ImuBatch:
    first = _sample(store, path, conn, t0, raws[0])  # also validates that it decodes at all
    rows = _rows(raws)
    batch = _unpack_imu(rows) if rows is not None else None
    if batch is not None and _same_sample(batch, first):
        return batch
    samples = [_sample(store, path, conn, t0, r) for r in raws]
    return ImuBatch.from_samples(samples)  # type: ignore[arg-type]


def _read_joints(store: Any, path: Path, conn: Any, t0: int, raws: list[Any]) -> JointBatch:
    batch = _fast_joints(store, path, conn, t0, raws)
    if batch is not None:
        return batch
    samples = [_sample(store, path, conn, t0, r) for r in raws]
    return _joint_batch_slow(samples, path, conn.topic)  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------

def _temp_sibling(path: Path, what: str) -> Path:
    return path.with_name(f'.{path.name}.{what}-{os.getpid()}-{uuid.uuid4().hex[:8]}')


def remove_bag(path: Path) -> None:
    """Remove a bag directory or file (or a partial one); a missing path is fine."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


def _install(tmp: Path, path: Path, overwrite: bool) -> None:
    """Rename ``tmp`` to ``path``; with ``overwrite`` the old ``path`` goes only after that."""
    old: Path | None = None
    if path.exists() or path.is_symlink():
        if not overwrite:
            raise BagError(f'{path}: exists already (use --force to replace it)')
        old = _temp_sibling(path, 'old')
        os.rename(path, old)
    try:
        os.rename(tmp, path)
    except OSError:
        if old is not None:
            os.rename(old, path)
        raise
    if old is not None:
        remove_bag(old)


def write_bag(path: str | os.PathLike[str], imu: ImuBatch, joints: JointBatch,
              imu_topic: str = DEFAULT_IMU_TOPIC, joint_topic: str = DEFAULT_JOINT_TOPIC,
              storage: Storage = 'mcap', frame_id: str | None = None,
              covariances: ImuCovariances | None = None, overwrite: bool = False,
              progress: Callable[[int], None] | None = None) -> Path:
    """Write IMU and joint samples to a ROS 2 (Jazzy, version 9) bag, atomically.

    Parameters
    ----------
    path:
        Bag directory to create, or a ``.mcap`` file (single-file bag, storage mcap).
    imu, joints:
        The samples; written interleaved in stamp order (IMU first on equal stamps), each
        with record timestamp = header stamp.
    imu_topic, joint_topic:
        Topic names.
    storage:
        ``'mcap'`` (default) or ``'sqlite3'`` for a bag directory.
    frame_id:
        ``header.frame_id`` of the Imu messages; ``None`` uses ``imu.frame_id`` or
        ``'imu_link'`` if that is empty.
    covariances:
        Imu covariances (default zeros = unknown; orientation_covariance[0] = -1 always).
    overwrite:
        Replace an existing ``path`` (only after the new bag is complete).
    progress:
        Called with the number of messages written since the last call.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    BagError
        Existing path (without ``overwrite``), missing parent directory, bad arguments,
        storage errors. Nothing is left behind on failure.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    p = Path(path)
    single = p.suffix == '.mcap'
    if storage not in ('mcap', 'sqlite3'):
        raise BagError(f'{p}: unknown storage {storage!r} (mcap or sqlite3)')
    if single and storage != 'mcap':
        raise BagError(f'{p}: a .mcap file needs storage mcap, not {storage}')
    if imu_topic == joint_topic:
        raise BagError(f'{p}: IMU and joint topics are the same ({imu_topic!r})')
    if (p.exists() or p.is_symlink()) and not overwrite:
        raise BagError(f'{p}: exists already (use --force to replace it)')
    if not p.parent.is_dir():
        raise BagError(f'{p}: directory {p.parent} does not exist')
    if len(imu) + len(joints) == 0:
        raise BagError(f'{p}: nothing to write (no IMU and no joint samples)')
    fid = frame_id if frame_id is not None else (imu.frame_id or 'imu_link')
    cov = covariances or ImuCovariances.unknown()
    store = _typestore()
    try:
        imu_rows = _pack_imu(imu, fid, cov)
        joint_raws = [store.serialize_cdr(joint_state_msg_from_sample(s, store),
                                          JOINT_STATE_MSGTYPE) for s in joints]
    except InputError as exc:
        raise BagError(f'{p}: {exc}') from None
    stamps = np.concatenate([imu.stamps_ns.astype(np.int64),
                             joints.stamps_ns.astype(np.int64)])
    order = np.argsort(stamps, kind='stable')
    n_imu = len(imu)
    # The writer names its storage file after the bag directory, so the bag is built as
    # tmp/<final name> and only that is renamed into place (tmp is always removed).
    tmp = _temp_sibling(p, 'partial')
    tmp.mkdir()
    bagdir = tmp / (p.stem if single else p.name)
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    try:
        writer = Writer(bagdir, version=9, storage_plugin=plugin)
        writer.open()
        try:
            c_imu = writer.add_connection(imu_topic, IMU_MSGTYPE, typestore=store) \
                if n_imu else None
            c_joint = writer.add_connection(joint_topic, JOINT_STATE_MSGTYPE,
                                            typestore=store) if len(joints) else None
            done = 0
            for k in order.tolist():
                if k < n_imu:
                    writer.write(c_imu, int(stamps[k]), imu_rows[k].tobytes())
                else:
                    writer.write(c_joint, int(stamps[k]), joint_raws[k - n_imu])
                done += 1
                if progress is not None and done % 10000 == 0:
                    progress(10000)
            writer.close()
        except BaseException:
            writer.abort()
            raise
        if progress is not None and done % 10000:
            progress(done % 10000)
        result = bagdir
        if single:
            files = list(bagdir.glob('*.mcap'))
            if len(files) != 1:
                raise BagError(f'{p}: expected one .mcap file from the writer, got {files}')
            result = files[0]
        _install(result, p, overwrite)
        remove_bag(tmp)
    except BagError:
        remove_bag(tmp)
        raise
    except Exception as exc:
        remove_bag(tmp)
        raise BagError(f'{p}: cannot write bag ({type(exc).__name__}: {_oneline(exc)})') \
            from None
    except BaseException:
        remove_bag(tmp)
        raise
    return p


def imu_msg_bytes(sample: ImuSample, frame_id: str | None = None,
                  covariances: ImuCovariances | None = None) -> bytes:
    """CDR bytes of one Imu message via rosbags (reference for the fast packer's tests)."""
    store = _typestore()
    msg = imu_msg_from_sample(sample, store, covariances, frame_id)
    return bytes(store.serialize_cdr(msg, IMU_MSGTYPE))


__all__ = ['BagSamples', 'DEFAULT_IMU_TOPIC', 'DEFAULT_JOINT_TOPIC', 'TopicInfo',
           'imu_msg_bytes', 'iter_bag', 'iter_bag_batches', 'list_topics', 'read_bag',
           'remove_bag', 'write_bag']
