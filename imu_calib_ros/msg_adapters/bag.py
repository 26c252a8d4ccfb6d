"""Read and write ROS 2 bags of ``sensor_msgs/Imu`` and ``sensor_msgs/JointState`` (rosbags).

What works with rosbags 0.11 (measured, see ``test/test_bag.py``):

- writing: ``rosbags.rosbag2.Writer`` only creates bag *directories* (``metadata.yaml`` plus
  one storage file), version 9 (Jazzy), storage ``mcap`` or ``sqlite3``. A path ending in
  ``.mcap`` is written as a directory bag in a temporary place and its single ``.mcap`` file
  is moved to the path (the mcap file is self-contained: schemas, channels, chunk index and
  statistics are inside it; ``metadata.yaml`` only repeats them).
- reading: ``rosbags.rosbag2.Reader`` reads a bag directory of either storage, a lone
  ``.mcap`` file and a lone ``.db3`` file. Messages come in log-time (record timestamp)
  order; the writer here sets the record timestamp equal to the header stamp, rosbag2 sets
  it to the receipt time (header stamp + transport delay: at 2 kHz a 1.5-2.5 ms delay puts
  one IMU message in eight behind a newer one). Every read path therefore delivers each
  topic in header-stamp order through a bounded reorder window (``reorder_window_s`` of log
  time, :mod:`imu_calib_ros.core.reorder`), and counts what it reordered, what came too
  late for the window, and backward jumps (a looping bag), which it passes on untouched.

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

import math
import os
import shutil
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ..core.errors import BagError, InputError
from ..core.reorder import BatchReorder, ReorderStats
from ..core.types import ImuBatch, ImuSample, JointBatch, JointSample
from . import DEFAULT_REORDER_WINDOW_S
from .convert import (IMU_MSGTYPE, JOINT_STATE_MSGTYPE, ImuCovariances, NS_PER_S,
                      imu_msg_from_sample, imu_sample_from_msg, joint_sample_from_msg,
                      joint_state_msg_from_sample)

DEFAULT_IMU_TOPIC = '/imu/data_raw'
DEFAULT_JOINT_TOPIC = '/joint_states'
#: Default longest wait of a message for its topic's stamp order [s of log time]: far above
#: rosbag2's receipt jitter (milliseconds), far below a looping bag's backward jump.
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
             joint_topic: str | None = DEFAULT_JOINT_TOPIC,
             reorder_window_s: float = DEFAULT_REORDER_WINDOW_S) -> 'BagSamples':
    """Stream the IMU and joint samples of a bag, each topic in header-stamp order, with
    bounded memory.

    Parameters
    ----------
    path:
        Bag directory (mcap or sqlite3 storage), or a single ``.mcap``/``.db3`` file.
    imu_topic, joint_topic:
        ``sensor_msgs/Imu`` and ``sensor_msgs/JointState`` topics; ``None`` skips one.
    reorder_window_s:
        Longest time [s of log time] a message is held back to put its topic in stamp order
        (:mod:`imu_calib_ros.core.reorder`; rosbag2's log time is the receipt time).

    Yields
    ------
    ImuSample | JointSample
        Stamped with the header stamp; each topic in stamp order (a message later than the
        window stays where it arrived, duplicates stay next to each other, a backward jump
        stays as recorded: the estimator counts them), the two topics merged by stamp, IMU
        first on equal stamps.
        Values are not checked (NaN passes through: the estimator rejects it).
        The returned iterator also has :meth:`BagSamples.batches` (the same data as
        :func:`iter_bag_batches`), which replay uses to skip the per-sample objects, and
        :attr:`BagSamples.reorder_stats`, what the window did per topic.

    Raises
    ------
    BagError
        Missing path, not a bag, empty bag, missing topic, wrong type, corrupt data.
    InputError
        A negative or non-finite ``reorder_window_s`` (at once).
    """
    return BagSamples(Path(path), imu_topic, joint_topic, reorder_window_s)


class BagSamples:
    """The iterator :func:`iter_bag` returns: samples one by one, or :meth:`batches`.

    Nothing is opened before the first ``next()`` (errors surface while iterating, as from
    a generator). :attr:`reorder_stats` maps each topic to the
    :class:`~imu_calib_ros.core.reorder.ReorderStats` of the current (or last) pass, by
    samples or by :meth:`batches`; complete once the iteration has ended.
    """

    def __init__(self, path: Path, imu_topic: str | None, joint_topic: str | None,
                 reorder_window_s: float = DEFAULT_REORDER_WINDOW_S) -> None:
        self.path = path
        self.imu_topic = imu_topic
        self.joint_topic = joint_topic
        self.reorder_window_s = _check_window(reorder_window_s)
        self.reorder_stats: dict[str, ReorderStats] = {}
        self._it: Iterator[ImuSample | JointSample] | None = None

    def __iter__(self) -> 'BagSamples':
        return self

    def __next__(self) -> ImuSample | JointSample:
        if self._it is None:
            self._it = _iter_samples(self.path, self.imu_topic, self.joint_topic,
                                     self.reorder_window_s, self.reorder_stats)
        return next(self._it)

    def batches(self, window_msgs: int | None = None) -> Iterator[ImuBatch | JointBatch]:
        """:func:`iter_bag_batches` of the same bag, topics and reorder window."""
        return iter_bag_batches(self.path, self.imu_topic, self.joint_topic,
                                window_msgs or BATCH_WINDOW_MSGS, self.reorder_window_s,
                                self.reorder_stats)


def _check_window(reorder_window_s: float) -> float:
    w = float(reorder_window_s)
    if not (math.isfinite(w) and w >= 0.0):
        raise InputError(f'reorder window must be a finite number of seconds >= 0, got '
                         f'{reorder_window_s}')
    return w


def _iter_samples(p: Path, imu_topic: str | None, joint_topic: str | None,
                  reorder_window_s: float, stats: dict[str, ReorderStats] | None
                  ) -> Iterator[ImuSample | JointSample]:
    for out in _ordered_windows(p, imu_topic, joint_topic, ITER_CHUNK_MSGS, reorder_window_s,
                                stats):
        joints = out.get(joint_topic, []) if joint_topic else []
        yield from _merge_samples(joints, out.get(imu_topic, []) if imu_topic else [])


def _merge_samples(joints: list[JointBatch], imu: list[ImuBatch]
                   ) -> Iterator[ImuSample | JointSample]:
    """The samples of two topics merged by stamp (IMU first on equal stamps, as
    :func:`write_bag` records them), each topic's own order kept (a late message stays where
    it is: merged by the newest stamp so far of its topic)."""
    samples: list[ImuSample | JointSample] = []
    for b in joints:
        samples += _samples_of(b)
    if not joints or not imu:
        for b in imu:
            samples += _samples_of(b)
        return iter(samples)
    nj = len(samples)
    for b in imu:
        samples += _samples_of(b)
    kj = np.maximum.accumulate(np.concatenate([b.stamps_ns for b in joints]))
    ki = np.maximum.accumulate(np.concatenate([b.stamps_ns for b in imu]))
    order = np.empty(len(samples), np.int64)  # merged position -> index into samples
    order[np.arange(nj) + np.searchsorted(ki, kj, side='right')] = np.arange(nj)
    order[np.arange(len(ki)) + np.searchsorted(kj, ki, side='left')] = \
        nj + np.arange(len(ki))
    return map(samples.__getitem__, order.tolist())


def _samples_of(b: ImuBatch | JointBatch) -> list[Any]:
    """The samples of a batch (as ``batch.sample(i)`` gives them, built faster)."""
    stamps = b.stamps_ns.tolist()
    if isinstance(b, ImuBatch):
        fid = b.frame_id
        return [ImuSample(t, w, f, fid) for t, w, f in zip(stamps, b.gyro_rad_s, b.accel_m_s2)]
    names, vel = b.names, b.velocities_rad_s
    if vel is None:
        return [JointSample(t, names, q, None) for t, q in zip(stamps, b.positions_rad)]
    return [JointSample(t, names, q, v) for t, q, v in zip(stamps, b.positions_rad, vel)]


BATCH_WINDOW_MSGS = 16384  # raw messages per window of iter_bag_batches (~5 MB of Imu)


def iter_bag_batches(path: str | os.PathLike[str], imu_topic: str | None = DEFAULT_IMU_TOPIC,
                     joint_topic: str | None = DEFAULT_JOINT_TOPIC,
                     window_msgs: int = BATCH_WINDOW_MSGS,
                     reorder_window_s: float = DEFAULT_REORDER_WINDOW_S,
                     reorder_stats: dict[str, ReorderStats] | None = None
                     ) -> Iterator[ImuBatch | JointBatch]:
    """Stream a bag as :class:`JointBatch` / :class:`ImuBatch` chunks, with bounded memory.

    The messages are read in log-time order in windows of ``window_msgs``; each window is
    decoded with the numpy fast path (:func:`read_bag`'s), each topic is put in header-stamp
    order by its reorder window (``reorder_window_s`` of log time, as :func:`iter_bag`),
    and the window yields the joint states it releases first, then the IMU samples, as
    batches; IMU samples wait for the joint states stamped before them, so joint states
    arrive early, never late, relative to the IMU samples (the estimator buffers joint
    states; its results do not depend on how far ahead they are). Where the fast path does
    not apply, messages are decoded one by one and split into runs of one joint-name list /
    one IMU frame_id, so that every sample keeps its own names and frame_id (as with
    :func:`iter_bag`). Memory: one window of raw and decoded messages plus the reorder
    window.

    ``reorder_stats``, if given, is cleared and filled with each topic's
    :class:`~imu_calib_ros.core.reorder.ReorderStats` (complete at the end).

    Raises
    ------
    BagError
        As :func:`iter_bag`.
    """
    if window_msgs < 1:
        raise InputError(f'window_msgs must be >= 1, got {window_msgs}')
    window_s = _check_window(reorder_window_s)
    for out in _ordered_windows(Path(path), imu_topic, joint_topic, window_msgs, window_s,
                                reorder_stats):
        for topic in sorted(out, key=lambda t: t != joint_topic):  # the joint topic first
            yield from out[topic]


Part = ImuBatch | JointBatch


def _ordered_windows(p: Path, imu_topic: str | None, joint_topic: str | None,
                     window_msgs: int, reorder_window_s: float,
                     stats: dict[str, ReorderStats] | None) -> Iterator[dict[str, list[Any]]]:
    """Per window of ``window_msgs`` raw messages: each topic's decoded batches that its
    reorder window releases (``{topic: [batch, ...]}``), and at the end what it still holds.

    The IMU samples are released no later than the joint states stamped before them
    (:class:`_JointGate`), so a consumer that takes each window's joint states first never
    gets a joint state after an IMU sample stamped later.
    """
    wanted = _wanted(imu_topic, joint_topic)
    with _open_reader(p) as reader:
        conns = _connections(reader, p, wanted)
        store = _typestore()
        orders = {t: _TopicOrder(reorder_window_s) for t in wanted}
        if stats is not None:
            stats.clear()
            stats.update({t: o.stats for t, o in orders.items()})
        gate = _JointGate(orders[imu_topic], orders[joint_topic]) \
            if imu_topic and joint_topic else None
        pending: dict[str, list[Any]] = {t: [] for t in wanted}
        clocks: dict[str, list[int]] = {t: [] for t in wanted}
        first: dict[str, tuple[Any, int]] = {}
        count = 0
        for conn, t_ns, raw in _raw_messages(reader, p, conns):
            topic = conn.topic
            raws = pending[topic]
            if not raws:
                first[topic] = (conn, t_ns)
            raws.append(raw)
            clocks[topic].append(t_ns)
            count += 1
            if count >= window_msgs:
                out = _decode_window(store, p, pending, clocks, first, orders, joint_topic)
                if gate is not None:
                    out[imu_topic] = gate.take(out[imu_topic])  # type: ignore[index]
                yield out
                count = 0
        out = _decode_window(store, p, pending, clocks, first, orders, joint_topic)
        if gate is not None:
            out[imu_topic] = gate.take(out[imu_topic])  # type: ignore[index]
        yield out
        out = {t: o.flush() for t, o in orders.items()}
        if gate is not None:
            out[imu_topic] = gate.flush(out[imu_topic])  # type: ignore[index]
        yield out


GATE_MAX_MSGS = 65536  # IMU samples at most held back for the joint states (~3.6 MB)


class _JointGate:
    """Holds back released IMU samples until the joint states stamped before them are out.

    Every joint state still to come is stamped at or after the joint topic's release mark
    (or is late), so IMU samples stamped before that mark may go. Should the joint states
    fall behind (they stopped, or run on another clock), an IMU sample waits at most one
    more reorder window of stamps, and never more than :data:`GATE_MAX_MSGS` samples. After
    a backward jump (a looping bag) the gate opens once: the consumer restarts anyway.
    """

    def __init__(self, imu: '_TopicOrder', joints: '_TopicOrder') -> None:
        self.imu = imu
        self.joints = joints
        self.held: list[Any] = []
        self._jumps = 0

    def _jumped(self) -> bool:
        jumps = self.imu.stats.backward_jumps + self.joints.stats.backward_jumps
        jumped, self._jumps = jumps != self._jumps, jumps
        return jumped

    def take(self, parts: list[Any]) -> list[Any]:
        """The IMU batches that may go now (``parts`` just released by the IMU window)."""
        parts = _merge_parts(self.held + parts)
        if self._jumped() or not parts:
            self.held = []
            return parts
        newest = np.maximum.accumulate(np.concatenate([b.stamps_ns for b in parts]))
        n = len(newest)
        k = 0
        j_mark, i_mark = self.joints.engine.mark, self.imu.engine.mark
        if j_mark is not None:
            k = int(np.searchsorted(newest, j_mark, side='left'))  # stamped before it
        if i_mark is not None:
            k = max(k, int(np.searchsorted(newest, i_mark - self.imu.engine.window_ns,
                                           side='right')))
        k = max(k, n - GATE_MAX_MSGS)
        self.held = _take_parts(parts, np.arange(k, n))
        return _take_parts(parts, np.arange(k))

    def flush(self, parts: list[Any]) -> list[Any]:
        """Everything (end of the bag)."""
        out = _merge_parts(self.held + parts)
        self.held = []
        return out


def _decode_window(store: Any, path: Path, pending: dict[str, list[Any]],
                   clocks: dict[str, list[int]], first: dict[str, tuple[Any, int]],
                   orders: dict[str, '_TopicOrder'], joint_topic: str | None
                   ) -> dict[str, list[Any]]:
    """Decode the window's messages of each topic and pass them through its reorder window;
    empties ``pending`` and ``clocks``."""
    out: dict[str, list[Any]] = {}
    for topic, raws in pending.items():
        if not raws:
            out[topic] = []
            continue
        conn, t0 = first[topic]
        parts: list[Any] = list(_window_joints(store, path, conn, t0, raws)
                                if topic == joint_topic else
                                _window_imu(store, path, conn, t0, raws))
        out[topic] = orders[topic].push(parts, np.array(clocks[topic], np.int64))
        pending[topic] = []
        clocks[topic] = []
    return out


class _TopicOrder:
    """One topic's reorder window over decoded batches: the engine and the batches it holds.

    The decoded messages stay in their batches (numpy); the engine only sees stamps and log
    times and answers with message ids, which are taken from the held + new batches.
    """

    def __init__(self, window_s: float) -> None:
        self.engine = BatchReorder(window_s)
        self.held: list[Any] = []  # batches of the held messages, in id order
        self.pushed = 0

    @property
    def stats(self) -> ReorderStats:
        return self.engine.stats

    def push(self, parts: list[Any], clocks: NDArray[np.int64]) -> list[Any]:
        """The batches released by the new messages ``parts`` (log times ``clocks``)."""
        parts = [b for b in parts if len(b)]
        if not parts:
            return []
        held_ids = self.engine.pending_ids
        base = self.pushed
        stamps = np.concatenate([b.stamps_ns for b in parts])
        released = self.engine.push(stamps, clocks)
        self.pushed += len(stamps)
        return self._take(self.held + parts, held_ids, base, released)

    def flush(self) -> list[Any]:
        """Everything still held, in stamp order."""
        held_ids = self.engine.pending_ids
        return self._take(self.held, held_ids, self.pushed, self.engine.flush())

    def _take(self, parts: list[Any], held_ids: NDArray[np.int64], base: int,
              released: NDArray[np.int64]) -> list[Any]:
        """Released ids -> batches; the batches of the ids still pending become ``held``."""
        parts = _merge_parts(parts)

        def positions(ids: NDArray[np.int64]) -> NDArray[np.int64]:
            return np.where(ids >= base, len(held_ids) + ids - base,
                            np.searchsorted(held_ids, ids))

        out = _take_parts(parts, positions(released))
        self.held = _merge_parts(_take_parts(parts, positions(self.engine.pending_ids)))
        return out


def _merge_parts(parts: list[Any]) -> list[Any]:
    """Consecutive batches of one layout (IMU frame_id; joint names and velocities) joined."""
    out: list[Any] = []
    for b in parts:
        a = out[-1] if out else None
        if isinstance(a, ImuBatch) and isinstance(b, ImuBatch) and a.frame_id == b.frame_id:
            out[-1] = ImuBatch(np.concatenate([a.stamps_ns, b.stamps_ns]),
                               np.concatenate([a.gyro_rad_s, b.gyro_rad_s]),
                               np.concatenate([a.accel_m_s2, b.accel_m_s2]), a.frame_id)
        elif (isinstance(a, JointBatch) and isinstance(b, JointBatch) and a.names == b.names
              and a.positions_rad.shape[1:] == b.positions_rad.shape[1:]
              and (a.velocities_rad_s is None) == (b.velocities_rad_s is None)):
            vel = None if a.velocities_rad_s is None or b.velocities_rad_s is None else \
                np.concatenate([a.velocities_rad_s, b.velocities_rad_s])
            out[-1] = JointBatch(np.concatenate([a.stamps_ns, b.stamps_ns]), a.names,
                                 np.concatenate([a.positions_rad, b.positions_rad]), vel)
        else:
            out.append(b)
    return out


def _take_parts(parts: list[Any], pos: NDArray[np.int64]) -> list[Any]:
    """The messages at positions ``pos`` of the concatenated ``parts``, in that order, as
    batches (one per run of positions in one part)."""
    if not len(pos):
        return []
    ends = np.cumsum([len(b) for b in parts])
    which = np.searchsorted(ends, pos, side='right')
    local = pos - (ends - [len(b) for b in parts])[which]
    cuts = np.flatnonzero(np.diff(which)) + 1
    out = []
    for run_which, run in zip(np.split(which, cuts), np.split(local, cuts)):
        b = parts[int(run_which[0])]
        lo, hi = int(run[0]), int(run[-1]) + 1
        idx: Any = run
        if hi - lo == len(run) and np.all(np.diff(run) == 1):  # a slice: views, no copy
            if hi - lo == len(b):
                out.append(b)
                continue
            idx = slice(lo, hi)
        if isinstance(b, ImuBatch):
            out.append(ImuBatch(b.stamps_ns[idx], b.gyro_rad_s[idx], b.accel_m_s2[idx],
                                b.frame_id))
        else:
            vel = None if b.velocities_rad_s is None else b.velocities_rad_s[idx]
            out.append(JointBatch(b.stamps_ns[idx], b.names, b.positions_rad[idx], vel))
    return out


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
             joint_topic: str | None = DEFAULT_JOINT_TOPIC,
             reorder_window_s: float = DEFAULT_REORDER_WINDOW_S,
             reorder_stats: dict[str, ReorderStats] | None = None
             ) -> tuple[ImuBatch, JointBatch]:
    """Read a whole bag into an :class:`ImuBatch` and a :class:`JointBatch`.

    Samples keep their header stamps; each topic is in header-stamp order through the same
    reorder window as :func:`iter_bag` (``reorder_window_s``; what it did goes into
    ``reorder_stats`` if given). Joint samples whose names are a permutation of the first
    message's names are reordered to it; missing velocities of some messages are NaN (all
    missing: ``None``). With ``joint_topic=None`` the joint batch is empty. Raises
    :class:`BagError` as :func:`iter_bag` does.
    """
    p = Path(path)
    wanted = _wanted(imu_topic, joint_topic)
    window_s = _check_window(reorder_window_s)
    imu_parts: list[ImuBatch] = []
    joint_parts: list[JointBatch] = []
    orders = {t: _TopicOrder(window_s) for t in wanted}
    if reorder_stats is not None:
        reorder_stats.clear()
        reorder_stats.update({t: o.stats for t, o in orders.items()})

    def keep(topic: str, batches: list[Any]) -> None:
        (imu_parts if topic == imu_topic else joint_parts).extend(batches)

    def flush(topic: str) -> None:
        """Decode the pending raw messages of ``topic`` (bounds the raw bytes held)."""
        raws = pending[topic]
        if not raws:
            return
        conn, t0 = first[topic]
        batch = (_read_imu(store, p, conn, t0, raws) if topic == imu_topic else
                 _read_joints(store, p, conn, t0, raws))
        keep(topic, orders[topic].push([batch], np.array(clocks[topic], np.int64)))
        pending[topic] = []
        clocks[topic] = []

    with _open_reader(p) as reader:
        conns = _connections(reader, p, wanted)
        store = _typestore()
        pending: dict[str, list[Any]] = {t: [] for t in wanted}
        clocks: dict[str, list[int]] = {t: [] for t in wanted}
        first: dict[str, tuple[Any, int]] = {}
        for conn, t_ns, raw in _raw_messages(reader, p, conns):
            topic = conn.topic
            raws = pending[topic]
            if not raws:
                first[topic] = (conn, t_ns)
            raws.append(raw)
            clocks[topic].append(t_ns)
            if len(raws) >= READ_CHUNK_MSGS:
                flush(topic)
        for topic in wanted:
            flush(topic)
            keep(topic, orders[topic].flush())
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


__all__ = ['BagSamples', 'DEFAULT_IMU_TOPIC', 'DEFAULT_JOINT_TOPIC', 'DEFAULT_REORDER_WINDOW_S',
           'ReorderStats', 'TopicInfo',
           'imu_msg_bytes', 'iter_bag', 'iter_bag_batches', 'list_topics', 'read_bag',
           'remove_bag', 'write_bag']
