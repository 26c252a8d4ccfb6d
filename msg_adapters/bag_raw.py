"""Raw messages of a bag, window by window: indexed mcap chunk by chunk, anything else
through rosbags' ``Reader.messages``.

A window is ``{topic: [RawBlock, ...]}``: each block one byte buffer with the messages'
offsets, lengths and log times, for :mod:`.cdr` to decode many messages at once.

- indexed mcap (what rosbag2 and rosbags write): rosbags opens the file and reads its
  summary (schemas, channels, chunk index); the chunks are then read here, one file read and
  rosbags' own decompressor (size and CRC checked) per chunk, and each chunk's MessageIndex
  records (mcap specification: opcode 0x07, (log_time, offset) pairs per channel) give the
  message records' offsets, so no Python runs per message. The order is ``Reader.messages``'s:
  log time, then chunk, then record order (rosbags merges the chunks by log time and sorts
  each chunk's records stably by it); chunks that overlap in log time, unindexed files,
  per-message compression and other storages are left to ``Reader.messages``;
- ``Reader.messages``: one Python step per message (~1 us), joined into one buffer per topic
  and window.

Damage (a chunk cut short, a record that does not match its index, a failed decompression
or checksum) is one :class:`BagError` line naming the bag, as from ``Reader.messages``.
"""
from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imu_calib_ros.core.errors import BagError
from . import cdr

IntArray = NDArray[np.int64]


def oneline(exc: BaseException) -> str:
    """The first line of an exception's text (or its type's name)."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def raw_messages(reader: Any, path: Path, conns: list[Any]) -> Iterator[tuple[Any, int, Any]]:
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
                           f'({oneline(exc)})') from None
        except Exception as exc:  # noqa: BLE001 - e.g. sqlite/zstd errors from the storage
            raise BagError(f'{path}: corrupt or truncated data ({type(exc).__name__}: '
                           f'{oneline(exc)})') from None
        last = item[1]
        yield item


@dataclass
class RawBlock:
    """Raw messages of one topic in one byte buffer: message k is
    ``buf[starts[k] : starts[k] + lengths[k]]``, logged at ``clocks[k]``."""

    conn: Any
    buf: NDArray[np.uint8]
    starts: IntArray
    lengths: IntArray
    clocks: IntArray

    def raw(self, k: int) -> bytes:
        s = int(self.starts[k])
        return self.buf[s:s + int(self.lengths[k])].tobytes()


Window = dict[str, list[RawBlock]]


def raw_windows(reader: Any, p: Path, conns: list[Any], window_msgs: int) -> Iterator[Window]:
    """The wanted messages in windows of about ``window_msgs`` (whole mcap chunks), in
    ``Reader.messages`` order, each topic's as blocks."""
    sources = _mcap_sources(reader, conns)
    if sources is None:
        yield from rosbags_windows(reader, p, conns, window_msgs)
    else:
        yield from _mcap_windows(p, sources, window_msgs)


def rosbags_windows(reader: Any, p: Path, conns: list[Any], window_msgs: int
                    ) -> Iterator[Window]:
    """Windows of ``window_msgs`` messages from ``Reader.messages`` (any storage)."""
    raws: dict[str, list[Any]] = {}
    clocks: dict[str, list[int]] = {}
    first: dict[str, Any] = {}
    count = 0

    def window() -> Window:
        out = {t: [_block_of(first[t], r, clocks[t])] for t, r in raws.items()}
        raws.clear()
        clocks.clear()
        return out

    for conn, t_ns, raw in raw_messages(reader, p, conns):
        topic = conn.topic
        if topic not in raws:
            raws[topic], clocks[topic], first[topic] = [], [], conn
        raws[topic].append(raw)
        clocks[topic].append(t_ns)
        count += 1
        if count >= window_msgs:
            yield window()
            count = 0
    if raws:
        yield window()


def _block_of(conn: Any, raws: list[Any], clocks: list[int]) -> RawBlock:
    lengths = np.fromiter(map(len, raws), np.int64, len(raws))
    starts = np.zeros(len(raws), np.int64)
    np.cumsum(lengths[:-1], out=starts[1:])
    return RawBlock(conn, np.frombuffer(b''.join(raws), np.uint8), starts, lengths,
                    np.array(clocks, np.int64))


def _mcap_sources(reader: Any, conns: list[Any]) -> list[tuple[Any, dict[int, Any], list[Any]]]\
        | None:
    """Per mcap storage file: (rosbags' McapReader, {channel id: connection}, the chunks to
    read in order), or None where the bulk path does not apply (then ``Reader.messages``)."""
    from rosbags.rosbag2.storage_mcap import McapReader
    storage = reader.storage
    storages = getattr(storage, 'storages', None)
    if storages is None:
        storages = [storage]
    elif reader.compression_mode == 'message':
        return None
    out = []
    for s in storages:
        if not isinstance(s, McapReader) or not s.chunks or not s.bio:
            return None
        cmap = {c.id: conn for c in s.connections for conn in conns
                if c.topic == conn.topic and c.msgtype == conn.msgtype}
        chunks = sorted((c for c in s.chunks if any(c.channel_count.get(i, 0) for i in cmap)),
                        key=lambda c: (c.message_start_time, c.chunk_start_offset))
        end, offset = -1, -1
        for c in chunks:  # Reader.messages merges overlapping chunks: leave that to it
            if c.message_start_time < end or (c.message_start_time == end
                                              and c.chunk_start_offset < offset):
                return None
            if c.message_index_length <= 0:
                return None
            end, offset = max(end, c.message_end_time), max(offset, c.chunk_start_offset)
        out.append((s, cmap, chunks))
    return out


_REC_HEAD = 31  # mcap Message record: opcode 1, length 8, channel 2, sequence 4, times 8 + 8


def _mcap_windows(p: Path, sources: list[tuple[Any, dict[int, Any], list[Any]]],
                  window_msgs: int) -> Iterator[Window]:
    """A window per chunk (several if the chunk holds more than ``window_msgs``). The
    chunks are read into one reused buffer: a window's bytes are valid until the next
    window is asked for."""
    from rosbags.rosbag2.storage_mcap import decompress
    last: int | None = None
    buffer = bytearray()
    for storage, cmap, chunks in sources:
        with open(storage.path, 'rb') as fh:
            for chunk in chunks:
                try:
                    size = chunk.chunk_length + chunk.message_index_length
                    if len(buffer) < size:  # with room: chunks differ a little in size
                        buffer = bytearray(max(size + size // 4, 2 << 20))
                    blocks = _mcap_chunk(fh, memoryview(buffer)[:size], chunk, cmap,
                                         decompress)
                except Exception as exc:  # noqa: BLE001 - any damage: one line, as rosbags
                    where = f' after log time {last} ns' if last is not None else ''
                    raise BagError(f'{p}: corrupt or truncated data{where} '
                                   f'({type(exc).__name__}: {oneline(exc)})') from None
                for b in blocks:
                    last = int(b.clocks[-1]) if last is None else max(last, int(b.clocks[-1]))
                while blocks:  # windows of at most window_msgs, cut inside the chunk
                    if sum(len(b.starts) for b in blocks) <= window_msgs:
                        head, blocks = blocks, []
                    else:
                        head, blocks = _split_blocks(blocks, window_msgs)
                    window: Window = {}
                    for b in head:
                        window.setdefault(b.conn.topic, []).append(b)
                    del head
                    yield window
                    del window


def _split_blocks(blocks: list[RawBlock], n: int) -> tuple[list[RawBlock], list[RawBlock]]:
    """The first ``n`` messages of one chunk's blocks (in Reader.messages order: log time,
    then record offset) and the rest (views of the same chunk)."""
    clocks = np.concatenate([b.clocks for b in blocks])
    starts = np.concatenate([b.starts for b in blocks])
    k = np.lexsort((starts, clocks))[n - 1]
    head: list[RawBlock] = []
    tail: list[RawBlock] = []
    for b in blocks:
        m = int(np.count_nonzero(
            (b.clocks < clocks[k]) | ((b.clocks == clocks[k]) & (b.starts <= starts[k]))))
        for part, sl in ((head, slice(None, m)), (tail, slice(m, None))):
            if len(b.starts[sl]):
                part.append(RawBlock(b.conn, b.buf, b.starts[sl], b.lengths[sl], b.clocks[sl]))
    return head, tail


def _mcap_chunk(fh: Any, data: memoryview, chunk: Any, cmap: dict[int, Any], decompress: Any
                ) -> list[RawBlock]:
    """The wanted messages of one mcap chunk, per topic (mcap spec: Chunk, MessageIndex),
    read into ``data`` (the chunk record and its message indexes)."""
    fh.seek(chunk.chunk_start_offset)
    size = len(data)
    if fh.readinto(data) != size or data[0] != 0x06:
        raise ValueError('chunk record missing or cut short')
    (n,) = struct.unpack_from('<I', data, 37)
    compression = bytes(data[41:41 + n]).decode()
    (csize,) = struct.unpack_from('<Q', data, 41 + n)
    (crc,) = struct.unpack_from('<I', data, 33)
    records = decompress(data[49 + n:49 + n + csize], compression,
                         chunk.uncompressed_size, crc)
    buf = np.frombuffer(records, np.uint8)
    offsets: dict[str, list[IntArray]] = {}
    conns: dict[str, Any] = {}
    for cid, conn in cmap.items():
        at = chunk.message_index_offsets.get(cid)
        if at is None:
            continue
        rel = at - chunk.chunk_start_offset
        op, _, index_cid, nbytes = struct.unpack_from('<BQHI', data, rel)
        if op != 0x07 or index_cid != cid or rel + 15 + nbytes > size:
            raise ValueError(f'bad message index of channel {cid}')
        entries = np.frombuffer(data, '<u8', nbytes // 8, rel + 15).reshape(-1, 2)
        offsets.setdefault(conn.topic, []).append(entries[:, 1].astype(np.int64))
        conns[conn.topic] = conn
    out = []
    for topic, parts in offsets.items():
        rec = np.concatenate(parts)
        if rec.size and (rec.min() < 0 or rec.max() > len(buf) - _REC_HEAD):
            raise ValueError('message index points outside the chunk')
        opcode = buf[rec]
        length = cdr.read_at(buf, rec + 1, '<u8')[:, 0].astype(np.int64)
        channel = cdr.read_at(buf, rec + 9, '<u2')[:, 0]
        clocks = cdr.read_at(buf, rec + 15, '<u8')[:, 0].astype(np.int64)
        if not (np.all(opcode == 0x05) and np.all(length >= 22)
                and np.all(rec + 9 + length <= len(buf))
                and np.all(np.isin(channel, [c for c, x in cmap.items() if x.topic == topic]))):
            raise ValueError('message record does not match its index')
        order = np.lexsort((rec, clocks))  # Reader.messages: log time, then record order
        rec, length, clocks = rec[order], length[order], clocks[order]
        out.append(RawBlock(conns[topic], buf, rec + _REC_HEAD, length - 22, clocks))
    return out
