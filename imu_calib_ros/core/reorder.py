"""Put a stream back into header-stamp order within a bounded window (issue 17).

A message's *arrival clock* (a bag's log time, which rosbag2 sets to the receipt time; a
node's receipt time) is not its measurement time: at 2 kHz a receipt jitter of 1 ms moves
one IMU message in eight behind a newer one. The input guard rejects such a sample as
``out_of_order``, so the stream is put back in stamp order first, the way message_filters'
``Cache`` keeps messages sorted by stamp, here with a bounded wait.

The rule (one rule, two implementations that give the same output, tested):

- every message waits at most ``window`` of arrival clock; a message whose wait is over is
  *expired*, and ``e``, the newest stamp of an expired message, is the release mark: every
  held message with stamp ``<= e`` is released, in (stamp, arrival) order. Messages whose
  arrival jitter spans less than the window come out in stamp order, whatever the offset
  between the two clocks (a bag recorded at wall time with simulated stamps);
- a message with a stamp older than ``e`` came too late to be put in order (*late*): it is
  passed on at once, where it arrived, and the consumer's own ordering check rejects it;
- a message more than ``jump`` (default ``max(window, 1 s)``, the input guard's
  ``time_jump_backward_s``) older than the newest stamp is a *backward jump* (a looping
  bag, a reset simulation): everything held is released, and a new epoch starts with it,
  so that the jump reaches the consumer as it was recorded (the guard and the nodes
  handle it), never sorted away;
- equal stamps (duplicates) are kept, next to each other, for the consumer to count.

:class:`BatchReorder` applies the rule to arrays (the bag reader: numpy, no per-message
Python); :class:`ReorderBuffer` to one message at a time (the live nodes), with
:meth:`ReorderBuffer.release` to let messages out when the stream pauses. Both count in a
:class:`ReorderStats`. Memory: the messages of one window (plus one push).
"""
from __future__ import annotations

import heapq
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

__all__ = ['BatchReorder', 'DEFAULT_JUMP_S', 'ReorderBuffer', 'ReorderStats']

IntArray = NDArray[np.int64]
T = TypeVar('T')

#: Smallest backward step treated as a time jump (the input guard's time_jump_backward_s).
DEFAULT_JUMP_S = 1.0
_NONE = np.iinfo(np.int64).min  # "no stamp yet"


@dataclass
class ReorderStats:
    """What a reorder stage did to one stream (counts of messages)."""

    messages: int = 0  #: messages pushed
    reordered: int = 0  #: arrived after a newer stamp and were put back in order
    late: int = 0  #: arrived after the window had released a newer stamp: passed on as is
    backward_jumps: int = 0  #: stamps more than ``jump`` back: passed on, a new epoch began
    max_displacement_ns: int = 0  #: largest (newest stamp so far - stamp) of reordered/late

    def as_dict(self) -> dict[str, int]:
        """Plain counts (for YAML provenance and diagnostics)."""
        return {k: int(v) for k, v in asdict(self).items()}

    def describe(self, what: str = 'messages') -> str:
        """One human line, e.g. for the CLI."""
        text = (f'{self.reordered} of {self.messages} {what} arrived out of header-stamp '
                f'order (by up to {self.max_displacement_ns * 1e-6:.3g} ms) and were put back '
                'in order')
        if self.late:
            text += f'; {self.late} arrived later than the reorder window and stay out of order'
        if self.backward_jumps:
            text += f'; {self.backward_jumps} backward time jumps passed on'
        return text


def _window_ns(window_s: float, jump_s: float | None) -> tuple[int, int]:
    if not (np.isfinite(window_s) and window_s >= 0.0):
        raise ValueError(f'reorder window must be finite and >= 0 s, got {window_s}')
    jump = max(window_s, DEFAULT_JUMP_S) if jump_s is None else jump_s
    if not (np.isfinite(jump) and jump >= window_s):
        raise ValueError(f'jump threshold must be finite and >= the window, got {jump}')
    return int(round(window_s * 1e9)), int(round(jump * 1e9))


class ReorderBuffer(Generic[T]):
    """The reorder rule (module docstring) for one message at a time (live nodes).

    Parameters
    ----------
    window_s:
        Longest wait of a message [s of the arrival clock]; 0 passes every message on at
        once (the arrival order; the counts still say what was out of order).
    jump_s:
        Backward step in stamps that starts a new epoch; default ``max(window_s, 1 s)``.

    Not thread safe: push, release, flush and reset from one thread.
    """

    def __init__(self, window_s: float, jump_s: float | None = None) -> None:
        self.window_ns, self.jump_ns = _window_ns(window_s, jump_s)
        self.stats = ReorderStats()
        self._seq = 0
        self._clock = _NONE
        self.reset()

    def __len__(self) -> int:
        """Messages held."""
        return len(self._heap)

    def reset(self) -> None:
        """Forget the held messages and the stamps seen (a time jump the node handles)."""
        self._heap: list[tuple[int, int, T]] = []
        self._arrivals: deque[tuple[int, int]] = deque()  # (clock, stamp) of held-or-not
        self._mark = _NONE  # e: newest stamp of an expired message
        self._newest = _NONE  # newest stamp of this epoch

    def push(self, stamp_ns: int, item: T, clock_ns: int) -> list[tuple[int, T]]:
        """Add a message that arrived at ``clock_ns``; returns the released ``(stamp, item)``
        pairs in order (possibly none, possibly this one)."""
        st = self.stats
        st.messages += 1
        out: list[tuple[int, T]] = []
        newest = self._newest
        if newest != _NONE and newest - stamp_ns > self.jump_ns:
            st.backward_jumps += 1
            out = self.flush()
            self.reset()
            newest = _NONE
        self._expire(clock_ns)
        if stamp_ns < self._mark:  # too late to be put in order: pass it on where it is
            st.late += 1
            st.max_displacement_ns = max(st.max_displacement_ns, newest - stamp_ns)
            out += self._emit()
            out.append((stamp_ns, item))
            return out
        if newest != _NONE and stamp_ns < newest:
            st.reordered += 1
            st.max_displacement_ns = max(st.max_displacement_ns, newest - stamp_ns)
        self._newest = max(newest, stamp_ns)
        self._seq += 1
        heapq.heappush(self._heap, (stamp_ns, self._seq, item))
        self._arrivals.append((self._clock, stamp_ns))
        self._expire(clock_ns)  # itself, with a zero window
        out += self._emit()
        return out

    def release(self, clock_ns: int) -> list[tuple[int, T]]:
        """The messages whose wait is over at ``clock_ns`` (call when the stream pauses)."""
        self._expire(clock_ns)
        return self._emit()

    def due_ns(self) -> int | None:
        """The arrival clock at which :meth:`release` may let a message out (None: nothing
        held): when the stream pauses, call :meth:`release` then."""
        if not self._heap or not self._arrivals:
            return None
        return self._arrivals[0][0] + self.window_ns

    def flush(self) -> list[tuple[int, T]]:
        """Every held message, in order (end of the stream, a save)."""
        out = [(s, item) for s, _, item in sorted(self._heap, key=lambda h: h[:2])]
        self._heap = []
        if out:
            self._mark = max(self._mark, out[-1][0])
        return out

    def _expire(self, clock_ns: int) -> None:
        self._clock = clock = max(self._clock, int(clock_ns))
        arrivals, limit = self._arrivals, clock - self.window_ns
        mark = self._mark
        while arrivals and arrivals[0][0] <= limit:
            mark = max(mark, arrivals.popleft()[1])
        self._mark = mark

    def _emit(self) -> list[tuple[int, T]]:
        heap, mark = self._heap, self._mark
        out = []
        while heap and heap[0][0] <= mark:
            s, _, item = heapq.heappop(heap)
            out.append((s, item))
        return out


class BatchReorder:
    """The reorder rule (module docstring) on arrays: ids in, ids out (the bag reader).

    Messages get consecutive ids from 0 in the order they are pushed; :meth:`push` returns
    the ids released, in release order, which is exactly the order :class:`ReorderBuffer`
    gives for the same stamps and clocks, however the stream is cut into pushes. The
    caller keeps the payload of :attr:`pending_ids` (the messages held back).
    """

    def __init__(self, window_s: float, jump_s: float | None = None) -> None:
        self.window_ns, self.jump_ns = _window_ns(window_s, jump_s)
        self.stats = ReorderStats()
        self._next_id = 0
        self._clock = _NONE
        self._new_epoch()

    def _new_epoch(self) -> None:
        self._mark = _NONE
        self._newest = _NONE
        # not-late messages of this epoch that may still expire later: stamp, clock, id,
        # and whether they are still held (every held message is among them)
        self._s = np.zeros(0, np.int64)
        self._c = np.zeros(0, np.int64)
        self._id = np.zeros(0, np.int64)
        self._held = np.zeros(0, bool)

    @property
    def mark(self) -> int | None:
        """The release mark: every later message is either stamped at or after it, or late
        (None before the first message expired; reset by a backward jump)."""
        return None if self._mark == _NONE else self._mark

    @property
    def pending_ids(self) -> IntArray:
        """Ids of the messages held back (increasing)."""
        return self._id[self._held]

    def push(self, stamps_ns: Any, clocks_ns: Any) -> IntArray:
        """Add messages (arrival order, clocks non-decreasing); the ids released, in order."""
        s = np.asarray(stamps_ns, np.int64).reshape(-1)
        c = np.asarray(clocks_ns, np.int64).reshape(-1)
        if s.shape != c.shape:
            raise ValueError(f'{len(s)} stamps but {len(c)} clocks')
        n = len(s)
        if n == 0:
            return np.zeros(0, np.int64)
        c = np.maximum.accumulate(np.maximum(c, self._clock))
        self._clock = int(c[-1])
        ids = self._next_id + np.arange(n, dtype=np.int64)
        self._next_id += n
        self.stats.messages += n
        out = []
        k = 0
        while k < n:
            seg = s[k:]
            before = np.maximum.accumulate(np.concatenate([[self._newest], seg[:-1]]))
            # newest - stamp in float: newest may be the 'none' sentinel (int64 min)
            jump = (before != _NONE) & (before.astype(float) - seg > self.jump_ns)
            j = int(np.argmax(jump)) if jump.any() else len(seg)
            if j:
                out.append(self._push_epoch(seg[:j], c[k:k + j], ids[k:k + j], before[:j]))
            if j == len(seg):
                break
            self.stats.backward_jumps += 1
            out.append(self.flush())
            self._new_epoch()
            k += j
        return np.concatenate(out) if len(out) != 1 else out[0]

    def flush(self) -> IntArray:
        """Release every held message, in (stamp, id) order."""
        held = self._held
        if not held.any():
            return np.zeros(0, np.int64)
        s, i = self._s[held], self._id[held]
        order = np.lexsort((i, s))
        self._mark = max(self._mark, int(s.max()))
        self._held = np.zeros_like(held)
        return i[order]

    def _push_epoch(self, s: IntArray, c: IntArray, ids: IntArray,
                    newest_before: IntArray) -> IntArray:
        """One stretch without a backward jump (``newest_before``: newest stamp before each)."""
        st = self.stats
        n, m0 = len(s), len(self._s)
        S = np.concatenate([self._s, s])
        C = np.concatenate([self._c, c])
        # the release mark at each arrival: newest stamp of the messages expired by then
        # (arrived by then: with a zero window, itself but none of equal clock after it)
        expired = np.minimum(np.searchsorted(C, c - self.window_ns, side='right'),
                             m0 + 1 + np.arange(n))
        newest_all = np.maximum.accumulate(S)
        mark = np.where(expired > 0, newest_all[np.maximum(expired - 1, 0)], _NONE)
        mark = np.maximum(mark, self._mark)
        late = s < mark
        back = (s < newest_before) & (newest_before != _NONE)
        st.late += int(late.sum())
        st.reordered += int((back & ~late).sum())
        if back.any():
            st.max_displacement_ns = max(st.max_displacement_ns,
                                         int((newest_before - s)[back].max()))
        # the arrival (0..n-1; n = not yet) at which each held message is released
        arrive = np.arange(n)
        at_old = np.searchsorted(mark, self._s[self._held], side='left')
        at_new = np.maximum(arrive, np.searchsorted(mark, s, side='left'))
        at_new[late] = arrive[late]
        rel_old = at_old < n
        rel_new = at_new < n
        # the released messages that are on time come out in (stamp, id) order (a stable
        # sort of id-ordered arrays; their release arrivals are then non-decreasing), each
        # late one right after those released by its own arrival
        on_time = rel_new & ~late
        stamp = np.concatenate([self._s[self._held][rel_old], s[on_time]])
        order = np.argsort(stamp, kind='stable')
        released = np.concatenate([self._id[self._held][rel_old], ids[on_time]])[order]
        if late.any():
            at = np.concatenate([at_old[rel_old], at_new[on_time]])[order]
            released = np.insert(released, np.searchsorted(at, np.flatnonzero(late), 'right'),
                                 ids[late])
        # keep the not-late messages that may expire later, and every held one
        held_old = self._held.copy()
        held_old[np.flatnonzero(self._held)[rel_old]] = False
        held = np.concatenate([held_old, ~late & ~rel_new])
        keep = np.concatenate([np.ones(m0, bool), ~late]) & (
            (C > C[-1] - self.window_ns) | held)
        self._s, self._c = S[keep], C[keep]
        self._id = np.concatenate([self._id, ids])[keep]
        self._held = held[keep]
        self._mark = int(mark[-1])
        self._newest = max(self._newest, int(s.max()))
        return released
