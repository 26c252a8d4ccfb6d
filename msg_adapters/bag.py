"""Read and write ROS 2 bags of ``sensor_msgs/Imu`` and ``sensor_msgs/JointState`` (rosbags).

What works with rosbags 0.11 (measured, see ``test/test_bag.py``):

- writing: ``rosbags.rosbag2.Writer`` only creates bag *directories* (``metadata.yaml`` plus
  one storage file), version 9 (Jazzy), storage ``mcap`` or ``sqlite3``. A path ending in
  ``.mcap`` is written as a directory bag in a temporary place and its single ``.mcap`` file
  is moved to the path (the mcap file is self-contained: schemas, channels, chunk index and
  statistics are inside it; ``metadata.yaml`` only repeats them).
- reading: ``rosbags.rosbag2.Reader`` opens a bag directory of either storage, a lone
  ``.mcap`` file and a lone ``.db3`` file, and checks it (topics, types, counts). Messages
  come in log-time (record timestamp) order; the writer here sets the record timestamp equal
  to the header stamp, rosbag2 sets it to the receipt time (header stamp + transport delay:
  at 2 kHz a 1.5-2.5 ms delay puts one IMU message in eight behind a newer one). Every read
  path therefore delivers each topic in header-stamp order through a bounded reorder window
  (``reorder_window_s`` of log time, :mod:`imu_calib_ros.core.reorder`), and counts what it
  reordered, what came too late for the window, and backward jumps (a looping bag), which it
  passes on untouched.

One reader (:func:`_ordered_windows`) under all three read functions: windows of raw
messages (:mod:`.bag_raw`: indexed mcap chunk by chunk with no Python per message, else
rosbags' ``Reader.messages``), each topic's messages decoded at once by :mod:`.cdr` (those
without the fixed layout by rosbags, one by one, which also names what is wrong with a
corrupt one), put in stamp order, then handed out as batches (:func:`iter_bag_batches`),
samples (:func:`iter_bag`) or whole (:func:`read_bag`: the batches joined).

Every write is atomic: the bag is written under a temporary name in the target's directory
and renamed into place, so a failed or interrupted write leaves no partial bag.
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

from imu_calib_ros.core.errors import BagError, InputError
from imu_calib_ros.core.reorder import BatchReorder, ReorderStats
from imu_calib_ros.core.types import ImuBatch, ImuSample, JointBatch, JointSample
from . import DEFAULT_REORDER_WINDOW_S
from . import cdr
from .bag_raw import RawBlock, oneline, raw_windows
from .convert import (IMU_MSGTYPE, JOINT_STATE_MSGTYPE, ImuCovariances, imu_msg_from_sample,
                      imu_sample_from_msg, joint_sample_from_msg)

DEFAULT_IMU_TOPIC = '/imu/data_raw'
DEFAULT_JOINT_TOPIC = '/joint_states'
Storage = Literal['mcap', 'sqlite3']
IntArray = NDArray[np.int64]


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


@dataclass(frozen=True)
class TopicInfo:
    """A topic in a bag: message type and number of messages."""

    msgtype: str
    count: int

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
                       f'({oneline(exc)})') from None
    except Exception as exc:  # noqa: BLE001 - any other rosbags/sqlite failure: same story
        raise BagError(f'{p}: cannot open bag, truncated or corrupt? '
                       f'({type(exc).__name__}: {oneline(exc)})') from None
    try:
        yield reader
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001 - closing a broken file must not mask the error
            pass


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


def _deserialize(store: Any, path: Path, conn: Any, t_ns: int, raw: Any) -> Any:
    try:
        return store.deserialize_cdr(raw, conn.msgtype)
    except Exception as exc:  # noqa: BLE001 - any decoding failure means a corrupt message
        raise BagError(f'{path}: corrupt {conn.msgtype} message on {conn.topic!r} at log '
                       f'time {t_ns} ns ({type(exc).__name__}: {oneline(exc)})') from None


def _sample(store: Any, path: Path, conn: Any, t_ns: int, raw: Any) -> ImuSample | JointSample:
    msg = _deserialize(store, path, conn, t_ns, raw)
    try:
        if conn.msgtype == IMU_MSGTYPE:
            return imu_sample_from_msg(msg)
        return joint_sample_from_msg(msg)
    except InputError as exc:
        raise BagError(f'{path}: bad message on {conn.topic!r} at log time {t_ns} ns: '
                       f'{exc}') from None


# --------------------------------------------------------------------------------------------
# Decoding a block (numpy via .cdr; messages without the fixed layout via rosbags)
# --------------------------------------------------------------------------------------------

def _decode_imu(store: Any, path: Path, b: RawBlock) -> list[ImuBatch]:
    """The block's Imu messages as batches, one per run of one frame_id."""
    cols = cdr.decode_imu(b.buf, b.starts, b.lengths)
    ok = np.flatnonzero(cols.ok)
    if ok.size:  # the numpy decode agrees with rosbags on the first message, or is not used
        k = int(ok[0])
        ref = _sample(store, path, b.conn, int(b.clocks[k]), b.raw(k))
        assert isinstance(ref, ImuSample)
        if not (ref.stamp_ns == cols.stamps_ns[k] and ref.frame_id == cols.frame_ids[
                cols.frame[k]] and _same_bits(ref.gyro_rad_s, cols.gyro_rad_s[k])
                and _same_bits(ref.accel_m_s2, cols.accel_m_s2[k])):
            cols.ok[:] = False
    for k in np.flatnonzero(~cols.ok).tolist():
        s = _sample(store, path, b.conn, int(b.clocks[k]), b.raw(k))
        assert isinstance(s, ImuSample)
        cols.stamps_ns[k], cols.gyro_rad_s[k], cols.accel_m_s2[k] = \
            s.stamp_ns, s.gyro_rad_s, s.accel_m_s2
        if s.frame_id not in cols.frame_ids:
            cols.frame_ids.append(s.frame_id)
        cols.frame[k] = cols.frame_ids.index(s.frame_id)
    cuts = [0, *(np.flatnonzero(np.diff(cols.frame)) + 1).tolist(), len(cols.frame)]
    return [ImuBatch(cols.stamps_ns[a:e], cols.gyro_rad_s[a:e], cols.accel_m_s2[a:e],
                     cols.frame_ids[int(cols.frame[a])]) for a, e in zip(cuts, cuts[1:])]


def _same_bits(a: Any, b: Any) -> bool:
    return bool(np.array_equal(np.asarray(a, np.float64).view(np.int64),
                                np.asarray(b, np.float64).view(np.int64)))


def _decode_joints(store: Any, path: Path, b: RawBlock) -> list[JointBatch]:
    """The block's JointState messages as batches, one per run of one layout (names in the
    message's own order, velocities present or not)."""
    n = len(b.starts)
    group = np.full(n, -1, np.int64)
    rank = np.zeros(n, np.int64)
    decoded: list[Any] = []
    for length in np.unique(b.lengths).tolist():  # messages of one length may share a layout
        sel = np.flatnonzero(b.lengths == length)
        res = cdr.decode_joint_rows(cdr.gather_rows(b.buf, b.starts[sel], length))
        if res is None:
            continue
        k = int(sel[0])
        ref = _sample(store, path, b.conn, int(b.clocks[k]), b.raw(k))
        assert isinstance(ref, JointSample)
        stamps, names, pos, vel = res
        if not (ref.stamp_ns == stamps[0] and ref.names == names
                and _same_bits(ref.positions_rad, pos[0])
                and (vel is None) == (ref.velocities_rad_s is None)
                and (vel is None or _same_bits(ref.velocities_rad_s, vel[0]))):
            continue
        group[sel], rank[sel] = len(decoded), np.arange(len(sel))
        decoded.append(res)
    out: list[JointBatch] = []
    cuts = [0, *(np.flatnonzero(np.diff(group)) + 1).tolist(), n]
    for a, e in zip(cuts, cuts[1:]):
        g = int(group[a])
        if g >= 0:
            stamps, names, pos, vel = decoded[g]
            r = slice(int(rank[a]), int(rank[e - 1]) + 1)
            out.append(JointBatch(stamps[r], names, pos[r], None if vel is None else vel[r]))
        else:
            out += _joint_runs([_sample(store, path, b.conn, int(b.clocks[k]),  # type: ignore[misc]
                                        b.raw(k)) for k in range(a, e)])
    return out


def _joint_runs(samples: list[JointSample]) -> list[JointBatch]:
    """Samples decoded one by one as batches, one per run of one name list and velocities
    present or not (each sample keeps its own names and velocities)."""
    out = []
    k = 0
    while k < len(samples):
        key = (samples[k].names, samples[k].velocities_rad_s is None)
        j = k + 1
        while j < len(samples) and (samples[j].names,
                                    samples[j].velocities_rad_s is None) == key:
            j += 1
        run = samples[k:j]
        vel = None if key[1] else np.array([s.velocities_rad_s for s in run], float)
        out.append(JointBatch(np.array([s.stamp_ns for s in run], np.int64), key[0],
                              np.array([s.positions_rad for s in run], float), vel))
        k = j
    return out


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
        for bi in imu:
            samples += _samples_of(bi)
        return iter(samples)
    nj = len(samples)
    for bi in imu:
        samples += _samples_of(bi)
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
ITER_CHUNK_MSGS = 2048  # messages decoded together by iter_bag (~0.7 MB of Imu messages)
READ_WINDOW_MSGS = 65536  # messages per window of read_bag


def _ordered_windows(p: Path, imu_topic: str | None, joint_topic: str | None,
                     window_msgs: int, reorder_window_s: float,
                     stats: dict[str, ReorderStats] | None) -> Iterator[dict[str, list[Any]]]:
    """Per window of about ``window_msgs`` raw messages: each topic's decoded batches that
    its reorder window releases (``{topic: [batch, ...]}``), and at the end what it still
    holds. The one message-gathering loop of every read path.

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

        def released(out: dict[str, list[Any]]) -> dict[str, list[Any]]:
            if gate is not None:
                out[imu_topic] = gate.take(out[imu_topic])  # type: ignore[index]
            return out

        parts: dict[str, list[Any]] = {t: [] for t in wanted}
        clocks: dict[str, list[NDArray[np.int64]]] = {t: [] for t in wanted}
        count = 0

        def window() -> dict[str, list[Any]]:
            out = {t: orders[t].push(parts[t], np.concatenate(clocks[t]) if clocks[t] else
                                     np.zeros(0, np.int64)) for t in wanted}
            for t in wanted:
                parts[t], clocks[t] = [], []
            return released(out)

        # raw windows are decoded at once (their bytes are valid until the next is asked
        # for) and gathered, decoded, into windows of window_msgs
        for raw in raw_windows(reader, p, conns, window_msgs):
            for topic, blocks in raw.items():
                decode = _decode_joints if topic == joint_topic else _decode_imu
                for b in blocks:
                    parts[topic] += decode(store, p, b)
                    clocks[topic].append(b.clocks)
                    count += len(b.starts)
            del raw, blocks, b
            if count >= window_msgs:
                yield window()
                count = 0
        yield window()
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


def read_bag(path: str | os.PathLike[str], imu_topic: str = DEFAULT_IMU_TOPIC,
             joint_topic: str | None = DEFAULT_JOINT_TOPIC,
             reorder_window_s: float = DEFAULT_REORDER_WINDOW_S,
             reorder_stats: dict[str, ReorderStats] | None = None
             ) -> tuple[ImuBatch, JointBatch]:
    """Read a whole bag into an :class:`ImuBatch` and a :class:`JointBatch`.

    The batches of :func:`iter_bag_batches` joined: samples keep their header stamps; each
    topic is in header-stamp order through the same reorder window as :func:`iter_bag`
    (``reorder_window_s``; what it did goes into ``reorder_stats`` if given). Joint samples
    whose names are a permutation of the first message's names are reordered to it; missing
    velocities of some messages are NaN (all missing: ``None``). With ``joint_topic=None``
    the joint batch is empty. Raises :class:`BagError` as :func:`iter_bag` does.
    """
    imu_parts: list[ImuBatch] = []
    joint_parts: list[JointBatch] = []
    for b in iter_bag_batches(path, imu_topic, joint_topic, READ_WINDOW_MSGS,
                              reorder_window_s, reorder_stats):
        if isinstance(b, ImuBatch):
            imu_parts.append(b)
        else:
            joint_parts.append(b)
    imu = _concat_imu(imu_parts)
    if joint_topic is None:
        return imu, JointBatch(np.zeros(0, np.int64), (), np.zeros((0, 0)), None)
    return imu, _concat_joints(joint_parts, Path(path), joint_topic)


def _concat_imu(parts: list[ImuBatch]) -> ImuBatch:
    if not parts:
        return ImuBatch.from_samples([])
    if len(parts) == 1:
        return parts[0]
    return ImuBatch(np.concatenate([b.stamps_ns for b in parts]),
                    np.concatenate([b.gyro_rad_s for b in parts]),
                    np.concatenate([b.accel_m_s2 for b in parts]),
                    parts[0].frame_id)  # as ImuBatch.from_samples: the first one's


def _concat_joints(parts: list[JointBatch], path: Path, topic: str) -> JointBatch:
    """Join chunk batches onto the first chunk's joint-name order (messages that carry other
    sets of joints: :func:`_merge_joint_sets`)."""
    if len(parts) == 1:
        return parts[0]
    names = parts[0].names

    def change(b: JointBatch) -> str:
        return (f'{path}: joint names on {topic!r} change at stamp {int(b.stamps_ns[0])} ns: '
                f'{list(b.names)} vs {list(names)}')
    other = next((b for b in parts if set(b.names) != set(names)), None)
    if other is not None:
        merged = _merge_joint_sets(parts)
        if not len(merged):
            raise BagError(f'{change(other)}, and no instant has all of them')
        return merged
    pos, vel = [], []
    any_vel = any(b.velocities_rad_s is not None for b in parts)
    for b in parts:
        if b.names != names:
            if sorted(b.names) != sorted(names):  # the same names, one twice
                raise BagError(change(b))
            order = [b.names.index(n) for n in names]
        else:
            order = list(range(len(names)))
        pos.append(b.positions_rad[:, order])
        v = b.velocities_rad_s
        vel.append(np.full_like(b.positions_rad, np.nan) if v is None else v[:, order])
    return JointBatch(np.concatenate([b.stamps_ns for b in parts]), names,
                      np.concatenate(pos), np.concatenate(vel) if any_vel else None)


#: a joint whose merged positions are holes at more than this share of the instants is left
#: out of a merged joint batch (another publisher's joint, sent now and then)
MERGE_MAX_HOLE_SHARE = 0.5


def _merge_joint_sets(parts: list[JointBatch]) -> JointBatch:
    """One batch from joint states that carry different sets of joints (one message per
    axis; another publisher's joints on the same topic), as the estimator merges them
    (:class:`~imu_calib_ros.core.joint_merge.JointMerger`): at the stamps of the set sent
    over the longest time (then: most often; its first joint), every joint by its own
    series. A joint that is a hole at most instants is left out, then instants with a hole
    are; positions only."""
    from imu_calib_ros.core.joint_merge import JointMerger
    names: list[str] = []
    span: dict[tuple[str, ...], list[int]] = {}  # first stamp, last stamp, rows
    for b in parts:
        names += [n for n in b.names if n not in names]
        if not len(b):
            continue
        key = tuple(sorted(b.names))
        a = span.setdefault(key, [int(b.stamps_ns[0]), int(b.stamps_ns[-1]), 0])
        a[0], a[1] = min(a[0], int(b.stamps_ns[0])), max(a[1], int(b.stamps_ns[-1]))
        a[2] += len(b)
    main = max(span, key=lambda k: (span[k][1] - span[k][0], span[k][2]))
    first = next(b.names[0] for b in parts if tuple(sorted(b.names)) == main)
    merger = JointMerger(tuple(names), reference=names.index(first), hole=math.nan)
    out = [merger.push(b.stamps_ns, b.names, b.positions_rad) for b in parts]
    out.append(merger.finish())
    t = np.concatenate([o[0] for o in out])
    q = np.concatenate([o[1] for o in out])
    keep = np.isnan(q).mean(axis=0) <= MERGE_MAX_HOLE_SHARE if len(t) else \
        np.ones(len(names), bool)
    q = q[:, keep]
    full = ~np.isnan(q).any(axis=1)
    return JointBatch(t[full], tuple(n for n, k in zip(names, keep, strict=True) if k),
                      q[full], None)


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
        imu_rows = cdr.pack_imu(imu.stamps_ns, imu.gyro_rad_s, imu.accel_m_s2, fid,
                                cov.angular_velocity_rad2_s2, cov.linear_acceleration_m2_s4)
        joint_raws = [cdr.joint_state_cdr(s.stamp_ns, '', s.names, s.positions_rad,
                                          () if s.velocities_rad_s is None
                                          else s.velocities_rad_s) for s in joints]
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
            c_imu: Any = writer.add_connection(imu_topic, IMU_MSGTYPE, typestore=store) \
                if n_imu else None
            c_joint: Any = writer.add_connection(joint_topic, JOINT_STATE_MSGTYPE,
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
        raise BagError(f'{p}: cannot write bag ({type(exc).__name__}: {oneline(exc)})') \
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
