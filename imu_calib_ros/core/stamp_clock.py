"""Stamps taken on receipt, put back on the sender's clock (IMU samples and joint states).

CONTRACT 1 stamps an IMU value at the end of its interval, and a joint state at its instant
plus at most a constant latency. Many drivers stamp a message instead when the host reads
it (``now()`` in a serial, USB or socket callback): the values still belong to the sender's
regular instants, but each stamp is late by its own receipt delay (0.1-2 ms, more on a loaded
host). A joint record stamped so has encoder rates 5 % off at 1 ms and 100 Hz (the plain
command blamed the fixture file's axes); an IMU stamped so turns the navigated attitude by
``omega d`` at every sample (a navigation unit's run refused at 2 ms).

A receipt delay is never negative: the sender's instants lie on the lower envelope of the
stamps. The line under the stamps that touches them below their centroid (the linear
programme of one-way clock synchronisation: A. Harrison and P. Newman, "TICSync: Knowing
when things happened", ICRA 2011) converges as ``spread / N^2`` in its slope, where a
least-squares line converges as ``spread / N^1.5`` (a uniform 2 ms delay over 1,024 stamps:
2 ns against 60 ns a period, 4 us against 120 us across 2,048 samples). :class:`StampClock`:

1. learns from the first :data:`LEARN_SAMPLES` stamps (at most :data:`LEARN_SPAN_NS` of them,
   at least :data:`MIN_LEARN_SAMPLES`) the period (median interval), each
   interval's count of periods (a dropped message: more than one) and the intervals' scatter
   about them; stamps whose scatter is below :data:`JITTER_FRACTION` of the period (a
   sender's own clock, a driver's steered clock, ns rounding) pass unchanged;
2. a stream whose intervals do not round to whole periods (more than
   :data:`IRREGULAR_SHARE` of them beyond 0.4 periods from a whole count) may still be one
   message per period with delays spread over up to a few periods (a 1 kHz IMU read over
   USB, a driver reading a FIFO in bursts): it is counted one period per message
   (:attr:`sequential`): by each stamp's phase on the period when the delays spread over
   less than :data:`FOLD_MIN_GAP` short of a period (:func:`fold_counts`: drops anywhere
   among the learnt stamps shift no count), else when a window of :data:`SEQ_LEARN` learnt
   stamps lies within :data:`SEQ_MAX_SPREAD` periods above one line with no step in its
   lower envelope. A
   dropped message is then found where a stamp lies further above the line than the learnt
   delays reach (a larger count), or at the next fit, where the lower envelope of the last
   :data:`REFIT_SAMPLES` stamps stands a half period or more above the line (the count
   lagged: those stamps are counted again from the step); a stamp is never given a count
   whose instant is after it (a delay is never negative). Frequent drops in a spread of
   more than a period cannot be counted (a slightly longer period fits a few hundred
   stamps): when the stamps leave the line the stream passes as given from there, and
   from the clock's decision when no learnt window holds on the other learnt stamps, or
   those over a period of delays find no other to agree on the period (drops hidden in
   every window);
3. either way, streams that are not periodic pass as given: an event-driven publisher,
   whose stamps wander about any line as the sum of its intervals where receipt delays are a
   new draw at each message (:func:`_fresh`), and delays no count explains;
4. otherwise replaces each later stamp by the envelope line at its sample index, the line
   fitted again every :data:`REFIT_SAMPLES` over the last :data:`WINDOW` (the period follows
   the sender's crystal against the host's). What is left of the delays is their least value
   (a constant latency, which the estimator measures) and a wander of ``~ spread / WINDOW``.
   A stream whose intervals stop matching whole periods later passes unchanged from then on.
   The learnt stamps went out as given (and the first replaced ones are held back behind
   them, to stay increasing): :meth:`StampClock.revise` gives their instants on the line
   to a consumer that still holds them (the estimator's coarse start holds its first
   minute, and the table may already turn), and a clock of a later pass over the same
   record applies them to what it gives out (:attr:`StampClock.hindsight`).
   :attr:`StampClock.timing_sigma_ns` bounds the error left in the stamps given out.

Hand-written: one-way clock synchronisation has no well-kept Python library; the line is
``scipy.optimize.minimize_scalar`` on the concave ``P -> min_i (s_i - P (k_i - c))``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]

#: stamps learnt before the clock decides (5 s at 200 Hz, 10 s of 100 Hz joint states), or
#: those of the first LEARN_SPAN_NS when that is fewer (40 s of 10-25 Hz joint states), but at
#: least MIN_LEARN_SAMPLES: the estimator's coarse start holds its first minute, and revises
#: the learnt stamps in it (:meth:`StampClock.revise`) only once the clock has decided
LEARN_SAMPLES = 1024
LEARN_SPAN_NS = 40_000_000_000
MIN_LEARN_SAMPLES = 257
#: robust scatter of the intervals (a fraction of the period) above which stamps are taken
#: for receipt times
JITTER_FRACTION = 1e-3
#: share of intervals further than 0.4 periods from a whole number of periods beyond which a
#: stream is not periodic: its stamps pass as given
IRREGULAR_SHARE = 0.01
#: largest spread of the learnt delays, in periods, that one-per-period counting accepts (a
#: driver that reads a sensor's FIFO in bursts of up to 16 samples; a wider spread: an
#: event-driven publisher, or drops among the learnt stamps)
SEQ_MAX_SPREAD = 16.0
#: the learnt stamps one-per-period counting is decided on, a window at a time (1 % of drops
#: leave 8 % of such windows without one, 27 % of learnings with one), and the learnings it
#: tries
SEQ_LEARN = 256
SEQ_TRIES = 16
#: folded on the period, the learnt stamps' phases must leave at least this share of a period
#: empty to be counted by phase (:func:`fold_counts`: delays spread over at most 0.9 of a
#: period, drops anywhere); the periods searched, within FOLD_RANGE of the median interval
FOLD_MIN_GAP = 0.1
FOLD_RANGE = 0.03
#: stamps the envelope line rests on (20 s at 200 Hz: a crystal's drift is far below a ns)
WINDOW = 4096
#: stamps between two fits of the line (each stamp is put on the last line fitted)
REFIT_SAMPLES = 256


def period_counts(d: FloatArray, period: float) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Intervals ``d`` [ns] as whole periods (a dropped message: more than one), and which
    lie further than 0.4 periods from their count (delays a count cannot be sure of)."""
    n = np.maximum(1.0, np.rint(d / period))
    return n, np.abs(d - n * period) > 0.4 * period


def strictly_increasing(t: IntArray, floor: int) -> IntArray:
    """Stamps ``t`` moved just enough to be strictly increasing and above ``floor`` (each at
    least 1 ns after the one before, as stamps that went out must stay)."""
    idx = np.arange(len(t), dtype=np.int64)
    return np.maximum.accumulate(np.maximum(t, floor + 1) - idx) + idx


def count_messages(s: FloatArray, line: tuple[float, float, float], delay_hi: float,
                   k_prev: float, fitted: bool = True) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Counts of stamps ``s`` on ``line`` (``a + P (k - c)``): one period per message after
    count ``k_prev``, more where a stamp lies more than ``delay_hi`` above the line (a drop),
    never a count whose line instant is after its stamp (``fitted``: a spike read as a drop
    is undone at the next stamp). Also which stamps the line put before the count after
    the last (evidence against the line)."""
    a, P, c = line
    x = (s - a) / P + c  # the count whose instant is the stamp (a zero delay)
    lo = np.ceil(x - delay_hi / P)
    hi = np.floor(x + 0.1) if fitted else np.full(len(s), np.inf)  # 0.1: the line's error
    idx = np.arange(len(s), dtype=float)
    k = idx + np.maximum(k_prev + 1.0, np.maximum.accumulate(lo - idx))
    below = np.zeros(len(s), bool)
    if np.all(k <= hi):
        return k, below
    prev = k_prev  # rare (a delay beyond any learnt one): the same rule, stamp by stamp
    for m in range(len(s)):
        below[m] = hi[m] < max(prev + 1.0, lo[m])
        km = min(max(prev + 1.0, lo[m]), hi[m])
        if m and km <= k[m - 1] and k[m - 1] - 1.0 > (k[m - 2] if m > 1 else k_prev):
            k[m - 1] = km - 1.0  # the stamp before was the spike: its count back
        k[m] = prev = km
    return k, below


def _window_counts(s: FloatArray, k: FloatArray
                   ) -> tuple[FloatArray, FloatArray, float, float] | None:
    """Counts of a window of stamps ``s`` from first counts ``k``: the envelope line, the
    delays' robust top above it, the drops that top shows counted (:func:`count_messages`),
    three times or until the counts hold. ``(k, residuals, P, top)``, or None."""
    for _ in range(3):
        P = float(np.polyfit(k, s, 1)[0])
        if not P > 0.0:
            return None
        line = envelope_line(k, s, P, 1e-2)  # (a least-squares slope: 1e-3 at 2 P)
        a, P, c = line
        r = s - (a + P * (k - c))
        hi = 1.2 * float(np.quantile(r, 0.95)) + 0.1 * P  # a robust top of the delays
        k_new = count_messages(s, line, hi, -1.0)[0]
        k_new = k_new - k_new[0]
        if np.array_equal(k_new, k):
            break
        k = k_new
    return k, r, P, hi


def fold_counts(s: FloatArray, p0: float) -> tuple[FloatArray, float, float] | None:
    """Counts of stamps ``s`` [ns] of one message per period whose receipt delays spread over
    less than a period, with messages dropped anywhere: folded on the right period, the
    stamps' phases cover an arc as wide as the delays' spread and leave the rest of the
    circle empty; on any other period they smear round it within a cycle over the span
    (epoch folding: the Rayleigh power ``|sum exp(2 pi i s / P)|``, largest on a grid of
    ``1 / 20`` of a cycle over the span within :data:`FOLD_RANGE` of ``p0``, then refined).
    Each stamp's count is its own: a drop shifts no count after it, where counting one
    period per message needs a window free of drops. ``(k, P, spread)``, the counts from the
    first stamp's, the period and the spread of the delays [ns]; None when the phases leave
    less than :data:`FOLD_MIN_GAP` of the circle empty."""
    x = s - s[0]
    span = float(x[-1])
    if len(x) < 16 or not span > 0.0 or not p0 > 0.0:
        return None
    if span / p0 > 4.0 * len(x):
        # the median interval is not the period: a FIFO read in bursts (microseconds apart)
        # has no arc to find, and a grid over the span in its units took seconds per call
        return None
    f0, df = 1.0 / p0, 0.05 / span
    grid = np.arange(f0 * (1.0 - FOLD_RANGE), f0 * (1.0 + FOLD_RANGE), df)

    def power(f: FloatArray) -> FloatArray:
        ph = 2.0 * np.pi * np.outer(f, x)
        return np.hypot(np.cos(ph).sum(axis=1), np.sin(ph).sum(axis=1))
    best = max(range(0, len(grid), 256), key=lambda i: float(power(grid[i:i + 256]).max()))
    chunk = grid[best:best + 256]
    fb = float(chunk[int(np.argmax(power(chunk)))])
    f = float(minimize_scalar(lambda v: -float(power(np.array([v]))[0]),
                              bounds=(fb - df, fb + df), method='bounded',
                              options={'xatol': 1e-6 * df}).x)
    k_old = np.zeros(0)
    for _ in range(4):
        phase = np.mod(x * f, 1.0)
        srt = np.sort(phase)
        gaps = np.diff(np.concatenate([srt, [srt[0] + 1.0]]))
        g = int(np.argmax(gaps))  # (the power's period may still narrow it: tested below)
        start = srt[(g + 1) % len(srt)]  # the least delay: the arc begins after the empty one
        k = np.rint(x * f - np.mod(phase - start, 1.0))
        k -= k[0]
        if np.any(np.diff(k) < 1.0):  # two stamps of one count: not one message per period
            return None
        if np.array_equal(k, k_old):
            break
        # the power's peak is not the narrowest arc (a uniform arc's phases weigh unevenly:
        # 70 ppm off over 1,024 stamps at 0.85 of a period of delays, 0.07 of the circle
        # lost): the period whose delays span least on these counts (convex in P)
        P = float(minimize_scalar(lambda v: float(np.ptp(x - v * k)),
                                  bounds=((1.0 - 1e-3) / f, (1.0 + 1e-3) / f),
                                  method='bounded', options={'xatol': 1e-9 / f}).x)
        f, k_old = 1.0 / P, k
    spread = float(np.ptp(x - k / f))
    return (k, 1.0 / f, spread) if spread <= (1.0 - FOLD_MIN_GAP) / f else None


#: stamps per window over which :func:`delay_scatter` detrends
SCATTER_WINDOW = 64


def delay_scatter(s: FloatArray) -> float:
    """The scatter [ns] of receipt delays about their mean, from stamps ``s`` that could not
    be counted: the median over windows of :data:`SCATTER_WINDOW` stamps of their residuals'
    std about the window's own line (a drop in a window, a step, moves few of the medians;
    the windows' slopes follow the period). The intervals' std / sqrt 2 assumes independent
    delays: a host that reads in order holds a message behind a late one, and that was 0.8x
    the delays' scatter on 1 kHz stamps 0-4.8 ms late, 1.3x with 5 % dropped at 2 ms; this,
    0.95-1.04x on the same streams."""
    w = SCATTER_WINDOW
    m = len(s) // w
    if m < 1:
        return float(np.std(np.diff(s))) / np.sqrt(2.0) if len(s) > 2 else 0.0
    x = np.arange(w, dtype=float) - 0.5 * (w - 1)
    r = s[:m * w].reshape(m, w)
    r = r - r.mean(axis=1, keepdims=True)
    r = r - np.outer(r @ x / float(x @ x), x)
    return float(np.median(np.sqrt(np.sum(r ** 2, axis=1) / (w - 2))))


def _fresh(r: FloatArray) -> bool:
    """Residuals ``r`` about a line are receipt delays, a new draw at each message: their
    steps vary as much as they do (2x for independent delays, 1.3x for bursts of 8). The
    stamps of an event-driven publisher wander about any line (a sum of its intervals), with
    steps far smaller than that."""
    return float(np.var(np.diff(r))) > 0.5 * float(np.var(r))


def envelope_line(k: FloatArray, s: FloatArray, period: float, rel: float = 1e-3
                  ) -> tuple[float, float, float]:
    """The line ``a + P (k - c)`` under every point ``(k_i, s_i)`` that is highest at their
    centroid ``c`` (the supporting line of their lower convex hull there): ``(a, P, c)``.
    ``period``: a first guess of ``P`` within ``rel`` of it."""
    c = float(k.mean())
    dk = k - c

    def neg_floor(p: float) -> float:
        return -float(np.min(s - p * dk))
    res = minimize_scalar(neg_floor, bounds=(period * (1 - rel), period * (1 + rel)),
                          method='bounded', options={'xatol': 1e-9 * period})
    P = float(res.x)
    return -neg_floor(P), P, c


@dataclass(frozen=True, eq=False)
class StampRevisions:
    """Stamps a clock gave out before it could replace them (``given_ns``, increasing) and
    their instants on the sender's clock (``line_ns``): :meth:`StampClock.revise`, and the
    same map for a later pass over the same record (:attr:`StampClock.hindsight`)."""

    given_ns: IntArray
    line_ns: IntArray

    def __call__(self, stamps_ns: IntArray) -> IntArray:
        """``stamps_ns`` with each given stamp replaced by its instant; others unchanged."""
        t = np.asarray(stamps_ns, np.int64)
        if not len(self.given_ns) or not len(t):
            return t
        idx = np.minimum(np.searchsorted(self.given_ns, t), len(self.given_ns) - 1)
        hit = self.given_ns[idx] == t
        if not hit.any():
            return t
        out = t.copy()
        out[hit] = self.line_ns[idx[hit]]
        return out


class StampClock:
    """Streaming (see the module docstring): :meth:`__call__` maps a batch of increasing
    stamps [ns] to the sender's clock. ``smoothing``: stamps are being replaced; ``jitter_ns``
    the learnt robust scatter of the intervals; ``period_ns``; ``irregular``: the stream was
    found not periodic (stamps pass as given)."""

    def __init__(self, learn_samples: int = LEARN_SAMPLES, window: int = WINDOW,
                 refit: int = REFIT_SAMPLES) -> None:
        self.learn_samples = int(learn_samples)
        self.window = int(window)
        self.refit = int(refit)
        self._learn: list[IntArray] = []
        self._learnt = 0
        self.decided = False
        self.smoothing = False
        self.irregular = False
        self.jitter_ns = 0.0
        self.period_ns = 0.0
        self._base_s = 0  # int64 origin of the stamps; k and s below are relative to it
        self._k_last = 0.0  # sample index of the last stamp
        self._s_last: int | None = None  # the last stamp given (int64)
        self._hist_k = np.zeros(0)  # the last WINDOW stamps' indices and stamps (from base)
        self._hist_s = np.zeros(0)
        self._line = (0.0, 0.0, 0.0)  # a, P, c
        self._since_fit = 0
        self._last_out = np.iinfo(np.int64).min + 1
        self._bad = np.zeros(0, bool)  # the recent intervals' "not a whole count" flags
        self.sequential = False  # counted one period per message (delays beyond 0.4 periods)
        self._delay_hi = 0.0  # [ns] a delay above the line beyond which a count was dropped
        self._fitted = False
        self._period0 = 0.0  # the period learnt (the fits stay within 1e-3 of it)
        self._tries = 0  # learnings tried for one-per-period counting
        # stamps that went out as given while learning (and those held back behind them)
        # and their instants on the line: :meth:`revise`
        self._rev_from = np.zeros(0, np.int64)
        self._rev_to = np.zeros(0, np.int64)
        self._recording = False
        self._given_last = 0  # the last stamp given out as given while learning
        self._given: list[IntArray] = []  # stamps of earlier learnings (gone out as given)
        #: revisions were added since the flag was cleared (a consumer holding stamps clears it)
        self.revision_pending = False
        #: an earlier pass's revisions over the same record (:meth:`revisions`), applied to
        #: the stamps given out: a later pass sees the instants the first one's coarse start
        #: revised its held stamps to, where it holds nothing to revise (without it, a second
        #: pass navigated the first 40 s of 14 Hz joint states on stamps up to 36 ms late:
        #: 116 updates gated and a failed self-check on a tactical grid run)
        self.hindsight: StampRevisions | None = None
        #: the clock gave up on receipt delays it could not count (not an event-driven
        #: publisher's exact stamps): those passed as given scatter by ``delay_scatter_ns``
        self.scattered = False
        self.delay_scatter_ns = 0.0

    @property
    def timing_sigma_ns(self) -> float:
        """A bound of the error [ns] of the stamps given out now, beyond a constant latency:
        on the envelope line, the least of ``W`` delays spread over ``j`` (``~ j / W`` at the
        centroid) and the slope's error (``~ 4 j / W^2`` a stamp) carried half a window and
        a refit beyond it, ``(j / W) (3 + 4 R / W)``: 0.3 ms on 577 joint states at 14 Hz
        with 36 ms of delays, just after the clock decided, 20 us once it rests on 4,096;
        stamps passed as given after the clock gave up on receipt delays
        (:attr:`scattered`): their own scatter about the mean delay; 0 for a sender's clock,
        an event-driven publisher's exact stamps and before the clock decides (the learnt
        stamps are revised for the consumer that holds them)."""
        if not self.decided or self.period_ns <= 0.0:
            return 0.0
        if self.smoothing:
            j = self._delay_hi if self.sequential else 2.5 * self.jitter_ns  # (j / sqrt 6)
            w = max(len(self._hist_k), 1)
            # (never more than the delays' spread: just after a new time base the line rests
            # on a few stamps, and the bound above ran to seconds)
            return min(j / w * (3.0 + 4.0 * self.refit / w), j)
        if self.scattered:
            return self.delay_scatter_ns
        return 0.0

    def reset(self) -> None:
        """A backward time jump (a new time base: a looping bag): a new record from the next
        stamp; the decision and the period are kept (same sender)."""
        self._s_last = None
        self._last_out = np.iinfo(np.int64).min + 1
        self._recording = False

    def __call__(self, stamps_ns: IntArray) -> IntArray:
        out = self._call(stamps_ns)
        return out if self.hindsight is None else self.hindsight(out)

    def _call(self, stamps_ns: IntArray) -> IntArray:
        t = np.asarray(stamps_ns, np.int64)
        if not len(t) or (self.decided and not self.smoothing):
            return self._after_last(t)
        if not self.decided:  # the stamps learnt pass as given
            first = int(self._learn[0][0]) if self._learn else int(t[0])
            by_span = int(np.searchsorted(t, first + LEARN_SPAN_NS)) + 1
            need = min(self.learn_samples - self._learnt,
                       max(by_span, MIN_LEARN_SAMPLES - self._learnt))
            self._learn.append(t[:need].copy())
            self._learnt += min(len(t), need)
            if len(t) < need:
                return t
            t_learnt = np.concatenate(self._learn)
            self._learn = []
            self._decide(t_learnt)
            if not self.decided:  # learning again (a drop among the stamps learnt)
                self._given.append(t_learnt)
                return np.concatenate([t[:need], self._call(t[need:])])
            if len(t) <= need or not self.smoothing:
                return t
            return np.concatenate([t[:need], self._track(t[need:])])
        return self._track(t)

    def revise(self, stamps_ns: IntArray) -> IntArray:
        """Stamps this clock gave out before it could replace them (the learnt ones, passed
        as given, and the first replaced ones, held back to stay after them), as their
        instants on the sender's clock; other stamps unchanged. For a consumer that still
        holds them (the estimator's coarse start holds its first minute)."""
        return StampRevisions(self._rev_from, self._rev_to)(stamps_ns)

    def revisions(self) -> StampRevisions:
        """The revisions so far, as a map of their own (for a later pass: :attr:`hindsight`)."""
        return StampRevisions(self._rev_from.copy(), self._rev_to.copy())

    def _add_revisions(self, given: IntArray, line_ns: IntArray) -> None:
        moved = given != line_ns
        if moved.any():
            self._rev_from = np.concatenate([self._rev_from, given[moved]])
            # strictly increasing as the stamps they replace (a spike's count shared with
            # the stamp after it: 1 ns apart, as the replaced stamps went out)
            self._rev_to = strictly_increasing(
                np.concatenate([self._rev_to, line_ns[moved]]), np.iinfo(np.int64).min + 1)
            self.revision_pending = True

    def _revise_learnt(self, t: IntArray) -> None:
        """The learnt stamps ``t`` (gone out as given) on the line: those the line's counts
        reach (the last ones), and before them one period per stamp while each lies within
        the learnt spread of delays above the line."""
        a, P, c = self._line
        s = (t - self._base_s).astype(float)
        n_h = min(len(self._hist_k), len(t))
        k = np.full(len(t), np.nan)
        k[len(t) - n_h:] = self._hist_k[-n_h:]
        i0 = len(t) - n_h
        if i0 > 0:  # backwards: the largest count below the next that is not after its stamp
            kb = self._counts_before(s[:i0], float(k[i0]))
            r = s[:i0] - (a + P * (kb - c))
            spread = self._delay_hi if self.sequential else 0.5 * P
            bad = np.flatnonzero(r > spread + 0.1 * P)  # (a drop it cannot place)
            first = int(bad[-1]) + 1 if len(bad) else 0
            k[first:i0] = kb[first:]
        f = int(np.argmax(~np.isnan(k)))  # the counted stamps: t[f:]
        line_ns = self._base_s + np.rint(a + P * (k[f:] - c)).astype(np.int64)
        g = 0  # after stamps left as given: from the first whose instant is after the one before
        if f:
            after = line_ns > t[f - 1:len(t) - 1]
            g = int(np.argmax(after)) if after.any() else len(line_ns)
        self._add_revisions(t[f + g:], line_ns[g:])
        self._recording, self._given_last = True, int(t[-1])

    def _decide(self, t: IntArray) -> None:
        self.decided = True
        d = np.diff(t).astype(float)
        if len(d) < 8 or np.median(d) <= 0:
            return
        p0 = float(np.median(d))
        n, bad = period_counts(d, p0)
        self.period_ns = p0
        self.jitter_ns = 1.4826 * float(np.median(np.abs(d - n * p0)))
        # messages read in bursts (several at one receipt stamp, 1 ns apart once kept
        # increasing): the median interval is not the period, and every interval is a whole
        # number of 1 ns "periods" (such a stream passed as a regular one)
        bursts = p0 < 0.25 * float(t[-1] - t[0]) / (len(t) - 1)
        if bursts or bad.mean() > IRREGULAR_SHARE:
            counted = self._decide_sequential(t)
            self.irregular = self.irregular or not counted
        elif self.jitter_ns > JITTER_FRACTION * p0:
            self._start(t, np.concatenate([[0.0], np.cumsum(n)]), bad)
        if self.smoothing:
            self._revise_learnt(np.concatenate(self._given + [t]))
        self._given = []

    def _start(self, t: IntArray, k: FloatArray, bad: NDArray[np.bool_]) -> None:
        """Replace the stamps from now on: the learnt stamps ``t`` at counts ``k``."""
        self.smoothing = True
        self._base_s = int(t[0])
        s = (t - self._base_s).astype(float)
        self._hist_k, self._hist_s = k[-self.window:], s[-self.window:]
        self._k_last, self._s_last = float(k[-1]), int(t[-1])
        self._last_out = int(t[-1])  # the learnt stamps went out as given: never behind them
        self._bad = bad
        # the median interval is a coarse period (dropped messages move it by tens of us):
        # the least-squares slope over the counted periods first, then the envelope
        self.period_ns = self._period0 = float(np.polyfit(k, s, 1)[0])
        self._fit()
        a, P, c = self._line
        if not self.sequential and not _fresh(s - (a + P * (k - c))):
            self.smoothing, self.irregular = False, True  # not receipt delays: event-driven

    def _decide_sequential(self, t: IntArray) -> bool:
        """One message per period (module docstring, 2.). Each :data:`SEQ_LEARN` learnt
        stamps are counted (:func:`_window_counts`) and tried: within :data:`SEQ_MAX_SPREAD`
        periods above one line, the lower envelope of each quarter of them within half a
        period of it, the residuals fresh draws (:func:`_fresh`). A drop the counting could
        not see (a spread of delays over a period) lengthens a window's period by
        ``P / SEQ_LEARN`` (a crystal's error is below 1e-4): the shortest period of those
        that pass and hold wins (:meth:`_window_holds`; a window whose delays spread over
        more than a period only where another agrees with it). The learnt stamps after its
        window are counted as later ones are. With none that passes, the clock learns
        again, :data:`SEQ_TRIES` times in all before the stream is taken as not periodic;
        with some that pass but none that holds, the stamps pass as given, scattered."""
        self._tries += 1
        s = (t - t[0]).astype(float)
        folded = fold_counts(s, float(np.median(np.diff(t))))
        if folded is not None:
            k, P, spread = folded
            r = s - np.polyval(np.polyfit(k, s, 1), k)
            if _fresh(r):
                # a count a drop away from the arc's end: half way across the empty arc
                self._delay_hi = 0.5 * (spread + P)
                self.sequential = True
                self._start(t, k, np.zeros(0, bool))
                return True
        passing: list[tuple[float, int, FloatArray, float, float]] = []
        for w0 in range(0, len(t) - SEQ_LEARN + 1, SEQ_LEARN):
            tw = t[w0:w0 + SEQ_LEARN]
            s = (tw - tw[0]).astype(float)
            got = _window_counts(s, np.arange(len(tw), dtype=float))
            if got is None:
                continue
            k, r, P, hi = got
            mins = [float(x.min()) for x in np.array_split(r, 4)]
            if r.max() <= SEQ_MAX_SPREAD * P and max(mins) <= 0.5 * P and _fresh(r):
                passing.append((P, w0, k, hi, float(r.max())))
        if not passing:
            if self._tries < SEQ_TRIES:
                self.decided, self._learnt = False, 0  # learn again from the next stamp
            return self._tries < SEQ_TRIES
        before = dict(self.__dict__)
        periods = np.array([c[0] for c in passing])
        for P, w0, k, hi, spread in sorted(passing, key=lambda c: c[0]):
            # a window with a drop it could not see counts its span one period short: its
            # period is P / SEQ_LEARN long. Where its delays spread over more than a period
            # (a drop can hide in them), another window must agree within half of that: with
            # drops hidden in every window (5 % of 1 kHz joint states 0-4.8 ms late) the
            # windows disagree by thousands of ppm, and a line on any of them put stamps 6
            # ms off. Under a period every drop shows above the delays (the hold below)
            if spread > P and np.sum(np.abs(periods - P) <= 0.5 * P / SEQ_LEARN) < 2:
                continue
            if self._window_holds(t, w0, k, hi):
                return True
            self.__dict__.update(before)  # (every array the trial changed is its own)
        # windows that count their own stamps and no others: drops hidden in delays over
        # several periods (a period a few per cent long, stamps put up to 7 ms off over 1 kHz
        # joint states 0-4.8 ms late before the counts stopped holding): as given, scattered
        self.decided = True
        # (the median interval of stamps read in bursts is not the period: the mean is,
        # drops aside)
        self.period_ns = float(t[-1] - t[0]) / (len(t) - 1)
        self._give_up((t - t[0]).astype(float))
        return True

    def _window_holds(self, t: IntArray, w0: int, k: FloatArray, hi: float) -> bool:
        """Whether the line of the window at ``w0`` (counts ``k``, delays up to ``hi``)
        counts every other learnt stamp of ``t`` as well, unfitted: those after it one
        period per message (:func:`count_messages`) with at most :data:`IRREGULAR_SHARE`
        of them below the line (a drop that hides in delays over a period puts one stamp
        below it before the count catches up; a period too long, from drops hidden in the
        window, every stamp once the line has passed them), those before it backwards
        (:meth:`_counts_before`) with as few above the learnt delays. If so, the clock
        counts from that window on (the learnt stamps after it as later ones are)."""
        self._delay_hi = hi
        self.sequential = True
        self._start(t[w0:w0 + SEQ_LEARN], k, np.zeros(0, bool))
        a, P, c = self._line
        s = (t - self._base_s).astype(float)
        bad = 0
        if w0 + SEQ_LEARN < len(t):
            bad += int(count_messages(s[w0 + SEQ_LEARN:], self._line, hi, float(k[-1]))[1]
                       .sum())
        if w0 > 0:
            r = s[:w0] - (a + P * (self._counts_before(s[:w0], float(k[0])) - c))
            bad += int(np.sum(r > hi + 0.5 * P))
        if bad > IRREGULAR_SHARE * (len(t) - SEQ_LEARN):
            return False
        if w0 + SEQ_LEARN < len(t):  # the learnt stamps after it went out as given
            self._track(t[w0 + SEQ_LEARN:])
            if not self.smoothing:  # the counts stopped holding
                return False
            self._last_out = int(t[-1])
            # the line on every stamp counted (a window's slope is the least of a few,
            # ~j / 256^2 off: 0.1 period a few hundred stamps on at 2 periods of delays)
            self._fit()
        return True

    def _counts_before(self, s: FloatArray, k_next: float) -> FloatArray:
        """Counts of stamps ``s`` (from the base) before the one counted ``k_next``, on the
        line, backwards: for each the largest count below the next whose instant is not after
        it (a drop there is found where a later stamp's delay is small)."""
        a, P, c = self._line
        idx = np.arange(len(s), dtype=float)
        hi = np.floor((s - a) / P + c + 0.1)
        return idx + np.minimum(k_next - len(s),
                                np.minimum.accumulate((hi - idx)[::-1])[::-1])

    def _count(self, s: FloatArray, k_prev: float) -> FloatArray:
        """:func:`count_messages` on the last line fitted; its stamps below the line noted."""
        k, below = count_messages(s, self._line, self._delay_hi, k_prev, self._fitted)
        self._bad = np.concatenate([self._bad, below])[-self.window:]
        return k

    def _recount(self) -> None:
        """A drop the counting missed (delays spread over more than a period): the lower
        envelope of the last stamps stands a half period or more above the line from some
        stamp on (at least 64 stamps, which a spread of delays cannot all share by chance):
        those stamps are counted again from there."""
        a, P, c = self._line
        m = min(len(self._hist_k), self.refit + 64)
        r = self._hist_s[-m:] - (a + P * (self._hist_k[-m:] - c))
        low = np.minimum.accumulate(r[::-1])[::-1]  # the least delay from each stamp on
        for _ in range(8):  # a step at a time, the first one first
            step = np.flatnonzero(low - np.minimum.accumulate(r) > 0.5 * P)
            if len(step) < 64:
                return
            i0 = int(step[0])
            shift = np.floor((low[i0] - r[:i0].min()) / P + 0.5)
            self._hist_k[len(self._hist_k) - m + i0:] += shift
            r[i0:] -= shift * P
            low = np.minimum.accumulate(r[::-1])[::-1]

    def _counts_hold(self) -> bool:
        """One count per period still holds over the window: its stamps lie within the
        learnt spread of delays above the line fitted to them (frequent drops in a spread
        of more than a period make a slightly longer period look right over a few hundred
        stamps, and wander off it by the square root of their number over the window)."""
        a, P, c = self._line
        r = self._hist_s - (a + P * (self._hist_k - c))
        return float(np.mean((r < -0.25 * P) | (r > self._delay_hi + 0.5 * P))) \
            <= IRREGULAR_SHARE

    def _fit(self) -> None:
        self._line = envelope_line(self._hist_k, self._hist_s, self._period0)
        self.period_ns = self._line[1]
        self._since_fit = 0
        self._fitted = True

    def _track(self, t: IntArray) -> IntArray:
        if self._s_last is None:  # a new time base: a new record, the period kept
            self._base_s = int(t[0])
            self._k_last, self._s_last = -1.0, int(t[0]) - int(round(self.period_ns))
            self._hist_k, self._hist_s = np.zeros(0), np.zeros(0)
            self._line = (0.0, self.period_ns, 0.0)  # anchored on the first stamp
            self._since_fit = 0
            self._fitted = False  # (its delay unknown: no stamp is below it until a fit)
        k: FloatArray | None = None
        if not self.sequential:
            d = np.diff(np.concatenate([[self._s_last], t])).astype(float)
            n, bad = period_counts(d, self.period_ns)
            self._bad = np.concatenate([self._bad, bad])[-self.window:]
            if len(self._bad) >= 256 and self._bad.mean() > IRREGULAR_SHARE:
                self._give_up()  # no longer periodic: as given
                return self._after_last(t)
            k = self._k_last + np.cumsum(n)
        s = (t - self._base_s).astype(float)
        out = np.empty(len(t))
        k_prev = self._k_last
        i = 0
        while i < len(t):  # each stamp on the last line fitted; a new fit every REFIT_SAMPLES
            j = min(len(t), i + max(1, self.refit - self._since_fit))
            a, P, c = self._line
            kc = self._count(s[i:j], k_prev) if k is None else k[i:j]
            if k is None and len(self._bad) >= 256 and self._bad.mean() > IRREGULAR_SHARE:
                # one count per period does not hold (frequent drops in a wide spread of
                # delays): as given from here on
                self._give_up()
                head = self._finish(out[:i], t[:i])
                return np.concatenate([head, self._after_last(t[i:])])
            out[i:j] = a + P * (kc - c)
            self._hist_k = np.concatenate([self._hist_k, kc])[-self.window:]
            self._hist_s = np.concatenate([self._hist_s, s[i:j]])[-self.window:]
            self._since_fit += j - i
            if self._since_fit >= self.refit and len(self._hist_k) >= 64:
                if self.sequential:
                    self._recount()
                self._fit()
                if self.sequential and not self._counts_hold():
                    self._give_up()  # as given from here on
                    head = self._finish(out[:j], t[:j])
                    return np.concatenate([head, self._after_last(t[j:])])
            k_prev = float(self._hist_k[-1])
            i = j
        self._k_last, self._s_last = k_prev, int(t[-1])
        return self._finish(out, t)

    def _give_up(self, s: FloatArray | None = None) -> None:
        """The stream stopped fitting the line: stamps as given from here on, and no
        revision of earlier ones (they rest on that line). ``s``: the last stamps [ns] (by
        default those the line rested on)."""
        self.irregular, self.smoothing = True, False
        # receipt delays that could not be counted: the stamps pass as given, late by their
        # own delays; the intervals' scatter for the failure's line (two delays each, drops
        # included), the delays' own for what the stamps given out are off by
        self.scattered = True
        s = self._hist_s if s is None else s
        if len(s) > 8:
            self.jitter_ns = max(self.jitter_ns, float(np.std(np.diff(s))))
            self.delay_scatter_ns = delay_scatter(s)
        self._rev_from, self._rev_to = np.zeros(0, np.int64), np.zeros(0, np.int64)
        self._recording = self.revision_pending = False

    def _after_last(self, t: IntArray) -> IntArray:
        """Stamps passed as given, kept after the last one given out (a line's instants
        may lie after the first stamps passed as given once the clock gave up)."""
        if len(t) and t[0] <= self._last_out:
            t = strictly_increasing(t, self._last_out)
        if len(t):
            self._last_out = max(self._last_out, int(t[-1]))
        return t

    def _finish(self, out: FloatArray, t: IntArray) -> IntArray:
        """The line's instants ``out`` (from the base) as stamps, strictly increasing as the
        input (at least 1 ns after the one before)."""
        if not len(out):
            return t[:0]
        line_ns = self._base_s + np.rint(out).astype(np.int64)
        res = strictly_increasing(line_ns, self._last_out)
        self._last_out = int(res[-1])
        if self._recording:  # held back behind the learnt stamps: their revisions too
            held = line_ns <= self._given_last
            self._recording = bool(held[-1])
            self._add_revisions(res[held], line_ns[held])
        return res


def scatter_hint(clocks: dict[str, StampClock]) -> str:
    """A clause for a failure's one line when a stream's stamps scatter about its rate and
    could not be put back on the sender's clock (:attr:`StampClock.irregular`), or ''."""
    parts = [f'{name} stamps scatter by {c.jitter_ns * 1e-6:.2g} ms about a '
             f'{1e9 / c.period_ns:.4g} Hz rate' for name, c in clocks.items()
             if c.irregular and c.period_ns > 0 and c.jitter_ns > 0.05 * c.period_ns]
    if not parts:
        return ''
    return ('; the ' + ' and the '.join(parts) + ', too much to be put back on the '
            'sender\'s clock: stamped on receipt by the host? Stamp each message at its '
            'sample instant (CONTRACT 1)')
