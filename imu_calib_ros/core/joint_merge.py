"""Complete fixture-joint samples from joint states that each carry only some of the joints.

ROS's ``sensor_msgs/JointState`` names the joints it carries, and a message may carry any
subset: a table whose axes have their own drivers publishes one message per axis on
``joint_states`` (robot_state_publisher and joint_state_publisher's ``source_list`` take
such partial messages). The estimator wants every fixture joint at one instant. Here each
joint keeps its own series; the output instants are the stamps of one *reference* joint
(the first fixture joint in the first partial message), and every other joint's position
there is interpolated in its own series by the quadratic through its two samples around the
instant and the one before them (exact where the stamps agree, as when one driver publishes
the axes as separate messages of one reading; a 1 rad/s^2 turn with axes read 5 ms apart at
100 Hz: ~1 urad, against 12 urad for the straight line). An instant waits until every joint
has a sample at or after it; one that a joint's series does not bracket within
:data:`MAX_BRACKET_PERIODS` of its own intervals is dropped (a hole stays a hole), and what
no later sample brackets is dropped at the end. Positions are unwrapped per joint (CONTRACT
1: wrapped to (-pi, pi] or continuous). Hand-written: a streaming per-name resampler with
holes is not what ``scipy.interpolate`` offers.
"""
from __future__ import annotations

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
_HISTORY = 16  # intervals per joint for its median


class JointMerger:
    """Streaming: :meth:`push` partial samples, take the complete ones it returns."""

    def __init__(self, joint_names: tuple[str, ...] | list[str]) -> None:
        self.joint_names = tuple(joint_names)
        self._index = {n: i for i, n in enumerate(self.joint_names)}
        self._series: list[deque[tuple[int, float]]] = [deque() for _ in self.joint_names]
        self._intervals: list[deque[int]] = [deque(maxlen=_HISTORY) for _ in self.joint_names]
        self.reference: int | None = None  # the joint whose stamps are the output instants
        self._instants: deque[int] = deque()
        self.seen: set[str] = set()  # fixture joints that came in partial samples
        self.partial_samples = 0
        self.dropped_instants = 0

    def push(self, stamps_ns: Any, names: tuple[str, ...] | list[str],
             positions_rad: Any) -> tuple[IntArray, FloatArray]:
        """Add samples of one name list (any subset of the fixture joints; others ignored);
        return the complete samples now ready: stamps (K,), positions (K, n) in fixture order."""
        t_all = np.asarray(stamps_ns, np.int64).reshape(-1)
        q_all = np.asarray(positions_rad, float).reshape(len(t_all), -1)
        cols = [(k, self._index[nm]) for k, nm in enumerate(names) if nm in self._index]
        self.partial_samples += len(t_all)
        if not cols:
            return np.zeros(0, np.int64), np.zeros((0, len(self.joint_names)))
        self.seen.update(self.joint_names[j] for _, j in cols)
        if self.reference is None:
            self.reference = min(j for _, j in cols)
        for row, t in enumerate(t_all.tolist()):
            for k, j in cols:
                self._add(j, t, float(q_all[row, k]))
                if j == self.reference and math.isfinite(q_all[row, k]):
                    if not self._instants or t > self._instants[-1]:
                        self._instants.append(t)
        return self._emit()

    def _add(self, j: int, t: int, q: float) -> None:
        s = self._series[j]
        if not math.isfinite(q) or (s and t <= s[-1][0]):
            return  # the guard counts what the complete samples carry; a repeat adds nothing
        if s:
            q0 = s[-1][1]
            q = q - 2.0 * math.pi * round((q - q0) / (2.0 * math.pi))  # unwrap on its own
            self._intervals[j].append(t - s[-1][0])
        s.append((t, q))

    def _emit(self) -> tuple[IntArray, FloatArray]:
        out_t: list[int] = []
        out_q: list[list[float]] = []
        while self._instants:
            t0 = self._instants[0]
            if any(not s or s[-1][0] < t0 for s in self._series):
                break  # a joint has nothing at or after this instant yet
            self._instants.popleft()
            row = [self._at(j, t0) for j in range(len(self.joint_names))]
            if any(v is None for v in row):
                self.dropped_instants += 1
                continue
            out_t.append(t0)
            out_q.append([float(v) for v in row if v is not None])
        self._prune()
        if not out_t:
            return np.zeros(0, np.int64), np.zeros((0, len(self.joint_names)))
        return np.array(out_t, np.int64), np.array(out_q)

    def _at(self, j: int, t0: int) -> float | None:
        """Joint ``j`` at ``t0``: its own sample there, or the quadratic through the two
        around it and the one before (the straight line when there is none before); None
        across a hole."""
        s = self._series[j]
        ts = [x[0] for x in s]
        i = int(np.searchsorted(ts, t0, side='left'))  # first sample at or after t0
        if ts[i] == t0:
            return s[i][1]
        if i == 0:
            return None  # nothing before the instant
        (ta, qa), (tb, qb) = s[i - 1], s[i]
        iv = self._intervals[j]
        if iv and tb - ta > MAX_BRACKET_PERIODS * float(np.median(iv)):
            return None
        la, lb = (tb - t0) / (tb - ta), (t0 - ta) / (tb - ta)
        q = la * qa + lb * qb
        if i >= 2:
            tp, qp = s[i - 2]
            # Newton's form: the line plus the second divided difference times (t0-ta)(t0-tb)
            d2 = ((qb - qa) / (tb - ta) - (qa - qp) / (ta - tp)) / (tb - tp)
            q += d2 * (t0 - ta) * (t0 - tb)
        return q

    def _prune(self) -> None:
        """Keep, per joint, the two samples before the oldest pending instant (or the newest
        two when none is pending) and everything after."""
        for s in self._series:
            keep_from = self._instants[0] if self._instants else (s[-1][0] if s else 0)
            while len(s) > 3 and s[2][0] < keep_from:
                s.popleft()
