"""Complete fixture-joint samples from joint states that each carry only some of the joints.

ROS's ``sensor_msgs/JointState`` names the joints it carries, and a message may carry any
subset: a table whose axes have their own drivers publishes one message per axis on
``joint_states`` (robot_state_publisher and joint_state_publisher's ``source_list`` take
such partial messages). The estimator wants every fixture joint at one instant. Here each
joint keeps its own series; the output instants are the stamps of one *reference* joint
(the outermost fixture joint), and every other joint's position
there is interpolated in its own series by the quadratic through its two samples around the
instant and the one before them (exact where the stamps agree, as when one driver publishes
the axes as separate messages of one reading; a 1 rad/s^2 turn with axes read 5 ms apart at
100 Hz: ~1 urad, against 12 urad for the straight line). An instant waits until every joint
has a sample at or after it, at most until a stamp :data:`MERGE_WAIT_NS` later has come
(live, the axes' publishers arrive out of step); one that a joint's series does not bracket
within :data:`MAX_BRACKET_PERIODS` of its own intervals is dropped (a hole stays a hole).
Positions are unwrapped per joint (CONTRACT 1: wrapped to (-pi, pi] or continuous).
Hand-written: a streaming per-name resampler with holes is not what ``scipy.interpolate``
offers."""
from __future__ import annotations

import bisect
import math
from collections import deque
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: an output instant is dropped when a joint's samples around it are further apart than this
#: many of that joint's median interval (its driver paused: interpolating across would hide a
#: hole from the joint buffer, which bridges none)
MAX_BRACKET_PERIODS = 2.5
#: how far [ns] the newest stamp of any joint may run ahead of an instant before it is decided
#: without the joints that have nothing after it yet (a hole there): live, the axes'
#: publishers arrive out of step by their own delays; an axis that stopped, or never came,
#: holds nothing back for longer (and its series and the instants waiting stay bounded)
MERGE_WAIT_NS = 500_000_000
_HISTORY = 16  # intervals per joint for its median


class JointMerger:
    """Streaming: :meth:`push` partial samples, take the complete ones it returns."""

    def __init__(self, joint_names: tuple[str, ...] | list[str], reference: int | None = None,
                 hole: float | None = None) -> None:
        """``reference``: the joint (index) whose stamps are the output instants (default 0,
        the outermost fixture joint: the same whatever order the axes arrive in); ``hole``:
        the value of a joint its series does not bracket at an instant (default None: the
        instant is dropped)."""
        self.joint_names = tuple(joint_names)
        self._index = {n: i for i, n in enumerate(self.joint_names)}
        n = len(self.joint_names)
        self._t: list[list[int]] = [[] for _ in range(n)]  # each joint's stamps
        self._q: list[list[float]] = [[] for _ in range(n)]  # and unwrapped positions
        self._intervals: list[deque[int]] = [deque(maxlen=_HISTORY) for _ in range(n)]
        self.reference = 0 if reference is None else reference  # whose stamps are instants
        self.hole = hole
        self._instants: deque[int] = deque()
        self._newest = -(2 ** 63)  # newest stamp of any joint
        self.seen: set[str] = set()  # the merged joints that came
        self.dropped_instants = 0
        #: samples of a joint left out, by the input guard's reasons (the guard never sees them)
        self.rejected = {'joint_non_finite': 0, 'joint_duplicate_stamp': 0,
                         'joint_out_of_order': 0}

    def push(self, stamps_ns: Any, names: tuple[str, ...] | list[str],
             positions_rad: Any) -> tuple[IntArray, FloatArray]:
        """Add samples of one name list (any subset of the joints; others ignored); return the
        complete samples now ready: stamps (K,), positions (K, n) in ``joint_names`` order."""
        t_all = np.asarray(stamps_ns, np.int64).reshape(-1)
        q_all = np.asarray(positions_rad, float).reshape(len(t_all), -1)
        cols = [(k, self._index[nm]) for k, nm in enumerate(names) if nm in self._index]
        if not cols:
            return np.zeros(0, np.int64), np.zeros((0, len(self.joint_names)))
        self.seen.update(self.joint_names[j] for _, j in cols)
        for row, t in enumerate(t_all.tolist()):
            for k, j in cols:
                if self._add(j, t, float(q_all[row, k])) and j == self.reference:
                    self._instants.append(t)
        return self._emit()

    def _add(self, j: int, t: int, q: float) -> bool:
        """Append to joint ``j``'s series (False: not finite, or not after its last; counted)."""
        ts, qs = self._t[j], self._q[j]
        if not math.isfinite(q) or (ts and t <= ts[-1]):
            why = ('joint_non_finite' if not math.isfinite(q) else
                   'joint_duplicate_stamp' if t == ts[-1] else 'joint_out_of_order')
            self.rejected[why] += 1
            return False
        if ts:
            q = q - 2.0 * math.pi * round((q - qs[-1]) / (2.0 * math.pi))  # unwrap on its own
            self._intervals[j].append(t - ts[-1])
        ts.append(t)
        qs.append(q)
        self._newest = max(self._newest, t)
        return True

    def finish(self) -> tuple[IntArray, FloatArray]:
        """The instants still waiting (end of the input): a joint with nothing after one is
        a hole there."""
        return self._emit(final=True)

    def _limit(self, j: int) -> float:
        """The longest interval joint ``j``'s samples may bracket an instant over [ns]."""
        iv = self._intervals[j]
        return MAX_BRACKET_PERIODS * float(np.median(iv)) if iv else math.inf

    def _waits(self, t0: int) -> bool:
        """Some joint has nothing at or after ``t0`` yet, and the newest stamp is within
        :data:`MERGE_WAIT_NS` of it."""
        return self._newest - t0 <= MERGE_WAIT_NS and any(not ts or ts[-1] < t0
                                                            for ts in self._t)

    def _emit(self, final: bool = False) -> tuple[IntArray, FloatArray]:
        out_t: list[int] = []
        out_q: list[list[float]] = []
        while self._instants:
            t0 = self._instants[0]
            if not final and self._waits(t0):
                break
            self._instants.popleft()
            row = [self._at(j, t0) for j in range(len(self.joint_names))]
            if self.hole is None and any(v is None for v in row):
                self.dropped_instants += 1
                continue
            out_t.append(t0)
            fill = math.nan if self.hole is None else self.hole  # (None: dropped above)
            out_q.append([fill if v is None else v for v in row])
        self._prune()
        if not out_t:
            return np.zeros(0, np.int64), np.zeros((0, len(self.joint_names)))
        return np.array(out_t, np.int64), np.array(out_q)

    def _at(self, j: int, t0: int) -> float | None:
        """Joint ``j`` at ``t0``: its own sample there, or the quadratic through the two
        around it and the one before (the straight line when there is none before); None
        across a hole."""
        ts, qs = self._t[j], self._q[j]
        i = bisect.bisect_left(ts, t0)  # first sample at or after t0
        if i < len(ts) and ts[i] == t0:
            return qs[i]
        if i == 0 or i == len(ts):
            return None  # nothing before the instant, or nothing after it
        ta, tb, qa, qb = ts[i - 1], ts[i], qs[i - 1], qs[i]
        if tb - ta > self._limit(j):
            return None
        q = ((tb - t0) * qa + (t0 - ta) * qb) / (tb - ta)
        if i >= 2:
            tp, qp = ts[i - 2], qs[i - 2]
            # Newton's form: the line plus the second divided difference times (t0-ta)(t0-tb)
            d2 = ((qb - qa) / (tb - ta) - (qa - qp) / (ta - tp)) / (tb - tp)
            q += d2 * (t0 - ta) * (t0 - tb)
        return q

    def _prune(self) -> None:
        """Keep, per joint, the two samples before the oldest pending instant or
        :data:`MERGE_WAIT_NS` before the newest stamp (an instant still to come, the
        reference's publisher behind the others'), whichever is earlier, and all after."""
        keep_from = self._newest - MERGE_WAIT_NS
        if self._instants:
            keep_from = min(keep_from, self._instants[0])
        for ts, qs in zip(self._t, self._q, strict=True):
            cut = max(0, min(bisect.bisect_left(ts, keep_from) - 2, len(ts) - 3))
            if cut > 64:  # in steps: a list's front is deleted at the cost of its length
                del ts[:cut]
                del qs[:cut]
