"""Input buffers of the streaming estimator: IMU samples waiting for a chunk, joint states.

The input guard (:mod:`~imu_calib_ros.core.input_guard`) has already dropped bad samples;
what arrives here is finite and in strictly increasing stamp order. The IMU buffer holds
samples until a whole block of chunks is there; the joint buffer holds the unwrapped joint
positions (stamps already corrected by the measured joint latency) that the alignment, the
gap checks and the encoder attitude measurement read, trimmed as the filter advances.

Also here: point samples as interval means (CONTRACT 1 option) and the joint interpolation
at arbitrary instants (a cubic spline, issue 11).
"""
from __future__ import annotations

import bisect
import math

from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


#: a joint-state interval longer than this many median intervals is a hole: no encoder
#: measurement inside it (one lost state, twice the spacing, is still interpolated)
JOINT_HOLE_PERIODS = 2.5


class ImuBuffer:
    """Accepted IMU samples not yet processed, as a list of array pieces (joined on read)."""

    def __init__(self) -> None:
        self._t: list[IntArray] = []
        self._w: list[FloatArray] = []
        self._f: list[FloatArray] = []
        self.last_stamp_ns: int | None = None  # newest sample ever appended
        self.last_sample: tuple[FloatArray, FloatArray] | None = None  # its (gyro, accel)

    def append(self, t: IntArray, w: FloatArray, f: FloatArray) -> None:
        """Buffer samples the input guard accepted (finite, strictly increasing stamps)."""
        if not len(t):
            return
        self.last_stamp_ns = int(t[-1])
        self.last_sample = (w[-1].copy(), f[-1].copy())
        self._t.append(t)
        self._w.append(w)
        self._f.append(f)

    def take(self) -> tuple[IntArray, FloatArray, FloatArray]:
        """Every buffered sample as ``(stamps (N,), gyro (N, 3), accel (N, 3))`` (a view:
        the buffer keeps them until :meth:`keep_from`)."""
        if len(self._t) > 1:
            self._t = [np.concatenate(self._t)]
            self._w = [np.concatenate(self._w)]
            self._f = [np.concatenate(self._f)]
        if not self._t:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3))
        return self._t[0], self._w[0], self._f[0]

    def keep_from(self, k: int) -> None:
        """Drop the ``k`` oldest samples."""
        t, w, f = self.take()
        self._t, self._w, self._f = [t[k:]], [w[k:]], [f[k:]]

    def drop_all(self) -> int:
        """Drop every buffered sample; returns how many there were."""
        n = len(self.take()[0])
        if n:
            self.keep_from(n)
        return n


class JointBuffer:
    """Accepted joint states in fixture joint order, unwrapped, stamps in nanoseconds.

    ``t_ns`` and ``q_rad`` are plain lists (appending and trimming a list is cheaper than
    re-allocating arrays; only the window a reader needs is converted). Only samples the
    input guard accepted come here (finite, stamps strictly increasing: it validates them,
    this buffer does not again); ``counters['joint_samples']`` (the estimator's counter
    dict) counts them. The range of every joint's positions (``joint_travel_rad``) is
    kept over the whole run, across :meth:`clear`.
    """

    def __init__(self, counters: dict[str, int]) -> None:
        self.counters = counters
        self.t_ns: list[int] = []
        self.q_rad: list[FloatArray] = []
        self._last_q: FloatArray | None = None
        self._q_min: FloatArray | None = None
        self._q_max: FloatArray | None = None
        #: states averaged per stored sample (:meth:`set_group`); the last incomplete group,
        #: the last group's mean (stored once the next is complete) and the one before it
        self.group = 1
        self._pend_t = np.zeros(0, np.int64)
        self._pend_q: FloatArray | None = None
        self._held: tuple[IntArray, FloatArray] | None = None
        self._before: tuple[IntArray, FloatArray] | None = None
        self._hole_ns = 0.0

    def __len__(self) -> int:
        return len(self.t_ns)

    def clear(self) -> None:
        """Forget the buffered samples, the groups not yet stored and the unwrap reference
        (the range is kept)."""
        self.t_ns, self.q_rad = [], []
        self._last_q = None
        self._pend_t, self._pend_q = np.zeros(0, np.int64), None
        self._held = self._before = None

    def set_group(self, k: int, period_ns: float = 0.0) -> None:
        """From the next state on, store the mean of each ``k`` consecutive states (stamps
        and unwrapped angles alike): joint stamps taken on receipt that the joint clock
        could not put back scatter by milliseconds, 1 ns apart where a host read several
        messages at once, and the cubic spline through them ran to 0.6 rad/s between two
        states of a table at rest (a motion bridge there tilted a navigation unit by 4.6
        mrad). A group's mean stamp scatters ``sqrt(k)`` times less
        (:func:`.coarse.timing_group_size`). The mean of ``k`` states ``dt`` apart is the
        angle at their mean instant plus ``qdd dt^2 (k^2 - 1) / 24``, one sign through an
        acceleration (130 urad at 2 rad/s^2 over 40 ms, against a MEMS unit's 100 urad of
        encoder attitude noise): each group is stored once the next is complete, less that
        term with ``qdd`` from its neighbours' means (:meth:`_box_corrected`). A group ends
        early before an interval longer than ``max(k / 2, JOINT_HOLE_PERIODS)`` periods
        ``period_ns`` (a hole in the record: a group across it put its mean inside the hole
        and hid it from :meth:`positions_at`)."""
        self.group = max(1, int(k))
        self._hole_ns = max(0.5 * self.group, JOINT_HOLE_PERIODS) * float(period_ns)

    @property
    def _grouping(self) -> bool:
        """States go through the groups (grouping on, or groups not yet stored)."""
        return self.group > 1 or bool(len(self._pend_t)) or self._held is not None

    def flush_group(self) -> None:
        """Store the groups not yet stored (the end of the data): the last complete one
        and the incomplete one's mean, uncorrected."""
        out_t, out_q = [], []
        if self._held is not None:
            out_t.append(self._held[0])
            out_q.append(self._held[1])
        if len(self._pend_t) and self._pend_q is not None:
            tb, qb = self._means(self._pend_t, self._pend_q, np.array([0]))
            out_t.append(tb)
            out_q.append(qb)
        self._pend_t, self._pend_q = np.zeros(0, np.int64), None
        self._held = self._before = None
        if out_t:
            self.t_ns.extend(np.concatenate(out_t).tolist())
            self.q_rad.extend(np.vstack(out_q))

    def _grouped(self, t: IntArray, q: FloatArray) -> tuple[IntArray, FloatArray]:
        """The groups that can be stored now: the complete groups' means of the incomplete
        group and ``t, q`` (the rest kept; a group also ends before a hole), each once the
        next is there (:meth:`_box_corrected`)."""
        if not self._grouping:
            return t, q
        if len(self._pend_t) and self._pend_q is not None:
            t, q = np.concatenate([self._pend_t, t]), np.vstack([self._pend_q, q])
        k = max(self.group, 1)
        holes = (np.flatnonzero(np.diff(t) > self._hole_ns) + 1).tolist() \
            if self._hole_ns > 0.0 else []
        starts: list[int] = []
        seg0 = done = 0
        for seg1 in holes + [len(t)]:
            rest = seg0 + (seg1 - seg0) // k * k
            starts.extend(range(seg0, rest, k))
            if seg1 < len(t):  # a hole follows: the states before it are a group
                if rest < seg1:
                    starts.append(rest)
                done = seg1
            else:
                done = rest  # (an incomplete last group stays pending)
            seg0 = seg1
        self._pend_t, self._pend_q = t[done:].copy(), q[done:].copy()
        idx = np.array(starts, dtype=np.intp)
        tb, qb = self._means(t[:done], q[:done], idx)
        if self._held is not None:
            tb = np.concatenate([self._held[0], tb])
            qb = np.vstack([self._held[1], qb])
        if not len(tb):
            return tb, qb
        before = self._before
        self._held = (tb[-1:].copy(), qb[-1:].copy())
        if len(tb) >= 2:
            self._before = (tb[-2:-1].copy(), qb[-2:-1].copy())
        return self._box_corrected(tb, qb, before, k)

    @staticmethod
    def _box_corrected(tb: IntArray, qb: FloatArray,
                       before: tuple[IntArray, FloatArray] | None, k: int
                       ) -> tuple[IntArray, FloatArray]:
        """Group means ``tb, qb`` but the last, each less ``qdd dt^2 (k^2 - 1) / 24`` (the
        mean of ``k`` states ``dt`` apart of a motion accelerating at ``qdd``), with
        ``k dt`` the neighbours' spacing and ``qdd`` the second divided difference of its
        own and its neighbours' means (``before``: the mean before the first, None at the
        start of the record: uncorrected). Not across a hole or a short group (spacings
        more than 1.5x apart)."""
        if before is not None:
            t_all = np.concatenate([before[0], tb]).astype(float) * 1e-9
            q_all = np.vstack([before[1], qb])
        else:
            t_all, q_all = tb.astype(float) * 1e-9, qb
        out = qb[:-1].copy()
        off = 1 if before is not None else 0  # index of tb[i] in t_all
        i = np.arange(len(tb) - 1) + off
        i = i[i >= 1]
        if len(i):
            h0, h1 = t_all[i] - t_all[i - 1], t_all[i + 1] - t_all[i]
            qdd = 2.0 * ((q_all[i + 1] - q_all[i]) / h1[:, None]
                         - (q_all[i] - q_all[i - 1]) / h0[:, None]) / (h0 + h1)[:, None]
            T = 0.5 * (h0 + h1)
            even = np.maximum(h0, h1) <= 1.5 * np.minimum(h0, h1)
            box = T ** 2 * (1.0 - 1.0 / k ** 2) / 24.0
            out[i - off] -= np.where(even[:, None], qdd * box[:, None], 0.0)
        return tb[:-1], out

    @staticmethod
    def _means(t: IntArray, q: FloatArray, starts: NDArray[np.intp]
               ) -> tuple[IntArray, FloatArray]:
        """Mean stamp (from each group's first, rounded) and angles of the groups of ``t, q``
        that begin at ``starts`` (the last one to the end)."""
        if not len(t) or not len(starts):
            return np.zeros(0, np.int64), np.zeros((0, q.shape[1]))
        n = np.diff(np.append(starts, len(t)))
        t0 = t[starts]
        dt = (t - np.repeat(t0, n)).astype(float)
        tb = np.round(np.add.reduceat(dt, starts) / n).astype(np.int64) + t0
        return tb, np.add.reduceat(q, starts, axis=0) / n[:, None]

    # ------------------------------------------------------------------ appending
    def append(self, stamp_ns: int, q: FloatArray) -> None:
        """Add one sample the guard accepted, unwrapped against the previous one."""
        if self._last_q is not None:  # unwrap against the previous sample
            q = q + 2 * np.pi * np.round((self._last_q - q) / (2 * np.pi))
        self._last_q = q
        if self._grouping:
            tg, qg = self._grouped(np.array([stamp_ns], np.int64), q[None, :])
            self.t_ns.extend(tg.tolist())
            self.q_rad.extend(qg)
        else:
            self.t_ns.append(stamp_ns)
            self.q_rad.append(q)
        if self._q_min is None or self._q_max is None:
            self._q_min, self._q_max = q.copy(), q.copy()
        else:
            self._q_min = np.minimum(self._q_min, q)
            self._q_max = np.maximum(self._q_max, q)
        self.counters['joint_samples'] += 1

    def extend(self, t: IntArray, q: FloatArray) -> None:
        """:meth:`append` for many samples the guard accepted (finite, stamps strictly
        increasing and above every earlier accepted stamp), vectorised."""
        two_pi = 2 * np.pi
        # unwrap: sample k moves by 2 pi m_k, m_k = m_(k-1) + round((q_(k-1) - q_k) / 2 pi);
        # np.unwrap's formula differs in the last bit, so the sequential rule is used and
        # checked below (a mismatch, only at exactly half turns, falls back to the loop)
        last = self._last_q
        if last is not None:
            ref_raw = np.vstack([last[None, :], q[:-1]])
            m = np.cumsum(np.round((ref_raw - q) / two_pi), axis=0)
        else:
            m = np.vstack([np.zeros((1, q.shape[1])),
                           np.cumsum(np.round((q[:-1] - q[1:]) / two_pi), axis=0)])
        qu = q + two_pi * m
        if last is None:
            qu[0] = q[0]  # the first sample is kept as it is (single push)
            ref, q_chk, qu_chk = qu[:-1], q[1:], qu[1:]
        else:
            ref, q_chk, qu_chk = np.vstack([last[None, :], qu[:-1]]), q, qu
        if not np.array_equal(q_chk + two_pi * np.round((ref - q_chk) / two_pi), qu_chk):
            for ti, qi in zip(t.tolist(), q, strict=True):
                self.append(ti, qi)
            return
        self._last_q = qu[-1]
        tg, qg = self._grouped(t, qu)
        self.t_ns.extend(tg.tolist())
        self.q_rad.extend(qg)
        lo, hi = qu.min(axis=0), qu.max(axis=0)
        if self._q_min is None or self._q_max is None:
            self._q_min, self._q_max = lo, hi
        else:
            self._q_min = np.minimum(self._q_min, lo)
            self._q_max = np.maximum(self._q_max, hi)
        self.counters['joint_samples'] += len(t)

    @property
    def travel_rad(self) -> float:
        """Largest range (max - min) of any joint's accepted, unwrapped positions [rad]."""
        if self._q_min is None or self._q_max is None:
            return 0.0
        return float(np.max(self._q_max - self._q_min))

    # ------------------------------------------------------------------ reading and trimming
    def arrays(self) -> tuple[IntArray, FloatArray]:
        """The whole buffer as ``(stamps (N,), positions (N, n_joints))``."""
        return np.array(self.t_ns, np.int64), np.array(self.q_rad)

    def keep_from(self, j: int) -> None:
        """Drop the ``j`` oldest samples."""
        self.t_ns, self.q_rad = self.t_ns[j:], self.q_rad[j:]

    def drop_before(self, t_ns: int) -> None:
        """Drop the samples stamped before ``t_ns``."""
        k = bisect.bisect_left(self.t_ns, t_ns)
        del self.t_ns[:k]
        del self.q_rad[:k]

    def trim(self, t_ns: int | None) -> None:
        """Keep two samples before ``t_ns`` (the newest processed IMU stamp) and all after:
        what the interpolation at later chunk ends needs."""
        if t_ns is None or len(self.t_ns) < 3:
            return
        k = bisect.bisect_left(self.t_ns, t_ns) - 2  # the list may hold a whole run
        if k > 0:
            del self.t_ns[:k]
            del self.q_rad[:k]

    def still_between(self, t0_ns: int, t1_ns: int, tol_rad: float) -> bool:
        """True if samples bracket ``[t0_ns, t1_ns]`` (one at or before ``t0_ns``, one at or
        after ``t1_ns``, at most 0.1 s beyond either end) and no joint moved by more than
        ``tol_rad`` over them. Joint states missing around the end (not there yet, or
        dropped) are not stillness: a gap inside a Kozlov oscillation whose joint states had
        been dropped too was taken for a gap at rest, and the turn lost in it sent every
        later update beyond the gate."""
        if not self.t_ns:
            return False
        jt, jq = self.arrays()
        i0 = int(np.searchsorted(jt, t0_ns, side='right')) - 1
        i1 = int(np.searchsorted(jt, t1_ns, side='left'))
        margin = int(0.1e9)
        if i0 < 0 or i1 >= len(jt) or jt[i0] < t0_ns - margin or jt[i1] > t1_ns + margin:
            return False
        travel = np.abs(jq[i0:i1 + 1] - jq[i0]).max()
        return bool(travel <= tol_rad)

    def positions_at(self, t_ns: IntArray, holes: bool = False
                     ) -> tuple[NDArray[np.bool_], FloatArray | None]:
        """Joint positions at the instants ``t_ns`` (increasing; the buffer not empty);
        ``holes``: also inside holes of the joint record (a motion bridge, which widens its
        covariance by :meth:`spline_error_at` there).

        Returns
        -------
        covered : (B,) bool
            Instants inside the span of the buffered samples and not inside a hole of the
            joint record (the two samples around the instant more than
            :data:`JOINT_HOLE_PERIODS` of its median spacing apart: joint states lost in a
            burst; the spline across 0.5 s of a move at 10 Hz was off by milliradians, and
            the encoder attitude updates there were gated).
        q : (B, n_joints) or None
            :func:`interp_joints` at every instant (clamped to the span), None when no
            instant is covered. Only the samples around the covered instants are read: the
            buffer may hold a whole run.
        """
        covered = (t_ns >= self.t_ns[0]) & (t_ns <= self.t_ns[-1])
        if not covered.any():
            return covered, None
        t_in = t_ns[covered]
        j0 = max(bisect.bisect_right(self.t_ns, int(t_in[0])) - 3, 0)
        j1 = bisect.bisect_left(self.t_ns, int(t_in[-1])) + 3
        jt = np.array(self.t_ns[j0:j1], np.int64)
        jq = np.array(self.q_rad[j0:j1])
        if len(jt) > 2 and not holes:
            spacing = np.diff(jt)
            k = np.clip(np.searchsorted(jt, t_ns, side='right'), 1, len(jt) - 1)
            covered &= spacing[k - 1] <= JOINT_HOLE_PERIODS * np.median(spacing)
            if not covered.any():
                return covered, None
        rel = (t_ns - jt[0]).astype(float) * 1e-9
        jrel = (jt - jt[0]).astype(float) * 1e-9
        return covered, interp_joints(rel, jrel, jq)


    def spline_error_at(self, t_ns: IntArray) -> FloatArray:
        """An estimate of the error of :meth:`positions_at` at the instants ``t_ns`` (covered
        ones), per joint [rad]: half the difference between the cubic spline through every
        sample and the one through every other sample (the error of a cubic spline falls
        with the spacing as h^2 at a kink of the acceleration, h^4 where the motion is
        smooth); inside a hole of the joint record (:data:`JOINT_HOLE_PERIODS`) twice the
        difference. On a trapezoidal move at 10-100 Hz, with and without a hole of 5 lost
        samples, the rms of the true error is 0.06-0.6 of the rms of this estimate (never
        above it: test_joint_buffer.py). Read from the 16 samples around each instant;
        with fewer than 8 there, the cubic's whole difference from the straight line."""
        from scipy.interpolate import CubicSpline
        err = np.zeros((len(t_ns), len(self.q_rad[0]) if self.q_rad else 0))
        for b, tb in enumerate(t_ns):
            k = bisect.bisect_left(self.t_ns, int(tb))
            lo, hi = max(k - 8, 0), min(k + 8, len(self.t_ns))
            ts = (np.array(self.t_ns[lo:hi], np.int64) - tb).astype(float) * 1e-9
            qs = np.array(self.q_rad[lo:hi])
            if hi - lo < 8:  # too few for the two splines: the cubic's whole correction
                if hi - lo >= 4:
                    lin = np.array([np.interp(0.0, ts, qs[:, i]) for i in range(qs.shape[1])])
                    err[b] = np.abs(CubicSpline(ts, qs, axis=0)(0.0) - lin)
                elif hi - lo >= 2:  # a quarter of the travel across the record
                    err[b] = 0.25 * np.abs(qs[-1] - qs[0])
                continue
            full = CubicSpline(ts, qs, axis=0)(0.0)
            half = [CubicSpline(ts[i::2], qs[i::2], axis=0)(0.0) for i in (0, 1)]
            spacing = np.diff(ts)
            j = min(max(int(np.searchsorted(ts, 0.0)), 1), len(ts) - 1)
            hole = spacing[j - 1] > JOINT_HOLE_PERIODS * np.median(spacing)
            err[b] = np.max(np.abs(np.array(half) - full), axis=0) * (2.0 if hole else 0.5)
        return err

    def bracket_spacing_ns(self, t_ns: IntArray) -> IntArray:
        """The interval between the joint states around each instant (the buffer's first or
        last interval outside it), read from those two samples only."""
        out = np.zeros(len(t_ns), np.int64)
        n = len(self.t_ns)
        for b, tb in enumerate(t_ns):
            k = min(max(bisect.bisect_left(self.t_ns, int(tb)), 1), n - 1)
            out[b] = self.t_ns[k] - self.t_ns[k - 1]
        return out

    def motion_at(self, t_ns: IntArray, still_tol_rad: float,
                  still_half_window_s: float = 0.0
                  ) -> tuple[NDArray[np.bool_], FloatArray | None, FloatArray | None]:
        """Joint positions and rates at the instants ``t_ns`` (a general chain's velocity,
        issue 15): the cubic spline of :meth:`positions_at` and its derivative; the rate of a
        joint that stays within ``still_tol_rad`` over the samples around an instant (+-3
        samples, and at least ``still_half_window_s`` either side) is exactly zero (encoder
        noise differentiated is not motion). The clamp is wrong by the rate of a joint that
        starts or stops moving within the window: up to ~``still_tol_rad`` over the window
        (a quintic move's first 0.1 s stays within 1e-4 rad over +-3 samples at 100 Hz while
        its rate reaches 3e-3 rad/s: 2-3 mm/s at the end of an arm, gated against a tactical
        unit's zero-velocity noise; see ESTIMATOR.md, "General chains")."""
        covered = (t_ns >= self.t_ns[0]) & (t_ns <= self.t_ns[-1])
        if not covered.any():
            return covered, None, None
        t_in = t_ns[covered]
        w_ns = int(round(still_half_window_s * 1e9))
        j0 = max(bisect.bisect_right(self.t_ns, int(t_in[0]) - w_ns) - 4, 0)
        j1 = bisect.bisect_left(self.t_ns, int(t_in[-1]) + w_ns) + 4
        jt = np.array(self.t_ns[j0:j1], np.int64)
        jq = np.array(self.q_rad[j0:j1])
        rel = (t_ns - jt[0]).astype(float) * 1e-9
        jrel = (jt - jt[0]).astype(float) * 1e-9
        q, qd = interp_joints(rel, jrel, jq, rates=True)
        k = np.clip(np.searchsorted(jrel, rel), 0, len(jt) - 1)
        lo = np.minimum(np.clip(k - 3, 0, len(jt) - 1),
                        np.searchsorted(jrel, rel - still_half_window_s, side='left'))
        hi = np.maximum(np.clip(k + 3, 0, len(jt) - 1),
                        np.searchsorted(jrel, rel + still_half_window_s, side='right') - 1)
        hi = np.clip(hi, 0, len(jt) - 1)
        for b in range(len(t_ns)):
            seg = jq[lo[b]:hi[b] + 1]
            still = (seg.max(axis=0) - seg.min(axis=0)) <= still_tol_rad
            qd[b, still] = 0.0
        return covered, q, qd


def interp_joints(t_s: FloatArray, tj_s: FloatArray, qj: FloatArray,
                  rates: bool = False) -> Any:
    """Joint angles at ``t_s`` by a cubic spline through the samples (linear interpolation
    through a 20 Hz record of an accelerating move biased the gyro scale by 44-77 ppm;
    issue 11), clamped to the record's ends."""
    if len(tj_s) < 4:
        q = np.stack([np.interp(t_s, tj_s, qj[:, i]) for i in range(qj.shape[1])], axis=1)
        if not rates:
            return q
        qd = np.zeros_like(q)
        if len(tj_s) >= 2:
            k = np.clip(np.searchsorted(tj_s, t_s) - 1, 0, len(tj_s) - 2)
            qd = (qj[k + 1] - qj[k]) / (tj_s[k + 1] - tj_s[k])[:, None]
        return q, qd
    from scipy.interpolate import CubicSpline
    spline = CubicSpline(tj_s, qj, axis=0)
    tc = np.clip(t_s, tj_s[0], tj_s[-1])
    if not rates:
        return spline(tc)
    return spline(tc), spline(tc, 1)


def point_to_mean(w: FloatArray, f: FloatArray,
                  prev: tuple[int, FloatArray, FloatArray] | None
                  ) -> tuple[FloatArray, FloatArray]:
    """Point samples as interval means (CONTRACT 1 option): the trapezoid of each sample and
    the one before it, exact for rates linear over the interval (the first sample, without a
    predecessor, stands for itself). ``prev`` is ``(stamp, gyro, accel)`` of the raw sample
    before ``w[0]``, ``f[0]``, or None."""
    w0 = w[:1] if prev is None else prev[1][None, :]
    f0 = f[:1] if prev is None else prev[2][None, :]
    return (0.5 * (w + np.vstack([w0, w[:-1]])), 0.5 * (f + np.vstack([f0, f[:-1]])))


#: the spread of a second difference ``q[k+1] - 2 q[k] + q[k-1]`` of white noise: sqrt(6) sigma
_SECOND_DIFFERENCE_GAIN = math.sqrt(6.0)


#: the most encoder noise at rest and the coarsest encoder steps the plain command is
#: checked on for every plan tried, named by a refusal beyond them (:func:`encoder_clause`).
#: Session 22 (docs/WORLD.md): 0.4 mrad of noise passed under all four unit classes on
#: demo_short, savage_srt@savage_2axis and srt_then_kozlov (1 mrad passed 5 of 5, max z
#: 3.91); 14-bit steps (0.38 mrad) 4 of 4 and 13-bit 2 of 2, 12-bit (1.53 mrad) were refused
#: 2 of 2. Session 21 had 50 urad and 0.1 mrad (the latency then read milliseconds off).
ENCODER_NOISE_CHECKED_RAD = 4e-4
ENCODER_STEP_CHECKED_RAD = 4e-4


def encoder_clause(noise_rad: float, step_rad: float) -> str:
    """``'the joint encoders read ... , more than the ... this command is checked on'`` when
    their noise at rest or their steps are above :data:`ENCODER_NOISE_CHECKED_RAD` /
    :data:`ENCODER_STEP_CHECKED_RAD`, else ''. The one wording of the coarse start's rate-fit
    line and the self-check's refusal."""
    what = []
    if step_rad > ENCODER_STEP_CHECKED_RAD:
        what.append(f'{step_rad * 1e3:.2f} mrad steps')
    if noise_rad > ENCODER_NOISE_CHECKED_RAD:
        what.append(f'{noise_rad * 1e3:.2f} mrad of noise at rest')
    if not what:
        return ''
    return (f'the joint encoders read {" and ".join(what)}, more than the '
            f'{ENCODER_STEP_CHECKED_RAD * 1e3:.2f} mrad steps and '
            f'{ENCODER_NOISE_CHECKED_RAD * 1e3:.2f} mrad of noise this command is checked on')


def encoder_noise_rad(q_rad: FloatArray) -> FloatArray:
    """Each joint's encoder noise [rad] from samples ``q_rad`` (n, joints): the scatter of the
    second differences (a constant rate cancels, and a constant acceleration with the median
    taken off), 1.4826 MAD over sqrt(6), of the angles unwrapped (a continuous joint reported
    in +-pi). The one estimate behind the alignment's motion bridges and the encoder-rate
    weight."""
    d2 = np.diff(np.unwrap(np.asarray(q_rad, float), axis=0), n=2, axis=0)
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return 1.4826 * mad / _SECOND_DIFFERENCE_GAIN


def window_noise_rad(jq: FloatArray, m: int) -> FloatArray:
    """Each joint's encoder noise over every window of ``m`` samples (``n - m + 1`` rows):
    the rms of its ``m - 2`` second differences over sqrt(6) (cumulative sums); zero for
    windows of fewer than four samples."""
    if m < 4:
        return np.zeros((max(len(jq) - m + 1, 0), jq.shape[1]))
    d2 = np.diff(jq, n=2, axis=0)
    c = np.concatenate([np.zeros((1, jq.shape[1])), np.cumsum(d2 ** 2, axis=0)])
    return np.sqrt((c[m - 2:] - c[:-(m - 2)]) / (m - 2)) / _SECOND_DIFFERENCE_GAIN


def encoder_quantum_rad(q_rad: FloatArray) -> FloatArray:
    """Each joint's encoder step [rad] from samples ``q_rad`` (n, joints), 0 where the angles
    are not on a lattice. A quantised encoder reads whole steps, so its angle at rest is off
    by up to half a step, an error that no average over a window removes (``step /
    sqrt(12)`` rms over poses). The step is the largest whole fraction of the least spacing
    (above rounding) between the distinct angles read of which at least
    :data:`LATTICE_SHARE` of all the spacings are whole multiples (continuous noise: a few
    per cent are, at any of the fractions tried); the angles as given (a multi-turn count),
    else wrapped to (-pi, pi] (a wrapped encoder's record unwrapped by whole turns that are
    no whole number of steps)."""
    q = np.asarray(q_rad, float)
    q = q[:, None] if q.ndim == 1 else q
    out = np.zeros(q.shape[1])
    head = q[:LATTICE_PROBE_SAMPLES]
    for j in range(q.shape[1]):
        if len(q) > len(head) and not encoder_quantum_rad(head[:, j])[0]:
            continue  # no lattice in the first samples: none (an hour of 200 Hz: 1 s saved)
        for x in (q[:, j], np.mod(q[:, j] + np.pi, 2.0 * np.pi) - np.pi):
            d = np.diff(np.unique(x))
            d = d[d > 1e-12]
            if not len(d):
                break
            c = _lattice_step(d)
            if c > 0.0:
                out[j] = c
                break
    return out


#: share of an encoder record's angle spacings that must be whole multiples of its step for
#: it to count as quantised (:func:`encoder_quantum_rad`)
LATTICE_SHARE = 0.9
#: the first joint samples that decide whether a record is on a lattice at all
LATTICE_PROBE_SAMPLES = 20_000


def _lattice_step(d: FloatArray, most: int = 64) -> float:
    """The largest ``min(d) / n`` (``n`` <= ``most``) of which :data:`LATTICE_SHARE` of the
    spacings ``d`` are whole multiples (to 1e-3 of it), or 0."""
    for n in range(1, most + 1):
        k = d * (n / d.min())
        if np.mean(np.abs(k - np.round(k)) < 1e-3) >= LATTICE_SHARE:
            return float(d.min()) / n
    return 0.0
