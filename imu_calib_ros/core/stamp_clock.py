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

1. learns from the first :data:`LEARN_SAMPLES` stamps the period (median interval), each
   interval's count of periods (a dropped message: more than one) and the intervals' scatter
   about them; stamps whose scatter is below :data:`JITTER_FRACTION` of the period (a
   sender's own clock, a driver's steered clock, ns rounding) pass unchanged, and so do
   streams that are not periodic (more than :data:`IRREGULAR_SHARE` of the intervals beyond
   0.4 periods from a whole count: an event-driven publisher, delays beyond half a period,
   which cannot be told from a dropped message);
2. otherwise replaces each later stamp by the envelope line at its sample index, the line
   fitted again every :data:`REFIT_SAMPLES` over the last :data:`WINDOW` (the period follows
   the sender's crystal against the host's). What is left of the delays is their least value
   (a constant latency, which the estimator measures) and a wander of ``~ spread / WINDOW``.
   A stream whose intervals stop matching whole periods later passes unchanged from then on.

Hand-written: one-way clock synchronisation has no well-kept Python library; the line is
``scipy.optimize.minimize_scalar`` on the concave ``P -> min_i (s_i - P (k_i - c))``.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]

#: stamps learnt before the clock decides (5 s at 200 Hz, 10 s of 100 Hz joint states: the
#: start of a calibration, at rest, where a stamp's delay does no harm)
LEARN_SAMPLES = 1024
#: robust scatter of the intervals (a fraction of the period) above which stamps are taken
#: for receipt times
JITTER_FRACTION = 1e-3
#: share of intervals further than 0.4 periods from a whole number of periods beyond which a
#: stream is not periodic: its stamps pass as given
IRREGULAR_SHARE = 0.01
#: stamps the envelope line rests on (20 s at 200 Hz: a crystal's drift is far below a ns)
WINDOW = 4096
#: stamps between two fits of the line (each stamp is put on the last line fitted)
REFIT_SAMPLES = 256


def period_counts(d: FloatArray, period: float) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Intervals ``d`` [ns] as whole periods (a dropped message: more than one), and which
    lie further than 0.4 periods from their count (delays a count cannot be sure of)."""
    n = np.maximum(1.0, np.rint(d / period))
    return n, np.abs(d - n * period) > 0.4 * period


def envelope_line(k: FloatArray, s: FloatArray, period: float) -> tuple[float, float, float]:
    """The line ``a + P (k - c)`` under every point ``(k_i, s_i)`` that is highest at their
    centroid ``c`` (the supporting line of their lower convex hull there): ``(a, P, c)``.
    ``period``: a first guess of ``P`` within 1e-3 of it."""
    c = float(k.mean())
    dk = k - c

    def neg_floor(p: float) -> float:
        return -float(np.min(s - p * dk))
    res = minimize_scalar(neg_floor, bounds=(period * (1 - 1e-3), period * (1 + 1e-3)),
                          method='bounded', options={'xatol': 1e-9 * period})
    P = float(res.x)
    return -neg_floor(P), P, c


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

    def reset(self) -> None:
        """A backward time jump (a new time base: a looping bag): a new record from the next
        stamp; the decision and the period are kept (same sender)."""
        self._s_last = None
        self._last_out = np.iinfo(np.int64).min + 1

    def __call__(self, stamps_ns: IntArray) -> IntArray:
        t = np.asarray(stamps_ns, np.int64)
        if not len(t) or (self.decided and not self.smoothing):
            return t
        if not self.decided:
            need = self.learn_samples - self._learnt  # the stamps learnt pass as given
            self._learn.append(t[:need].copy())
            self._learnt += min(len(t), need)
            if self._learnt < self.learn_samples:
                return t
            self._decide(np.concatenate(self._learn))
            self._learn = []
            if len(t) <= need or not self.smoothing:
                return t
            return np.concatenate([t[:need], self._track(t[need:])])
        return self._track(t)

    def _decide(self, t: IntArray) -> None:
        self.decided = True
        d = np.diff(t).astype(float)
        if len(d) < 8 or np.median(d) <= 0:
            return
        p0 = float(np.median(d))
        n, bad = period_counts(d, p0)
        self.period_ns = p0
        self.jitter_ns = 1.4826 * float(np.median(np.abs(d - n * p0)))
        if bad.mean() > IRREGULAR_SHARE:
            self.irregular = True
            return
        if self.jitter_ns <= JITTER_FRACTION * p0:
            return
        self.smoothing = True
        self._base_s = int(t[0])
        k = np.concatenate([[0.0], np.cumsum(n)])
        s = (t - self._base_s).astype(float)
        self._hist_k, self._hist_s = k[-self.window:], s[-self.window:]
        self._k_last, self._s_last = float(k[-1]), int(t[-1])
        self._last_out = int(t[-1])  # the learnt stamps went out as given: never behind them
        self._bad = bad
        # the median interval is a coarse period (dropped messages move it by tens of us):
        # the least-squares slope over the counted periods first, then the envelope
        self.period_ns = float(np.polyfit(k, s, 1)[0])
        self._fit()

    def _fit(self) -> None:
        self._line = envelope_line(self._hist_k, self._hist_s, self.period_ns)
        self.period_ns = self._line[1]
        self._since_fit = 0

    def _track(self, t: IntArray) -> IntArray:
        if self._s_last is None:  # a new time base: a new record, the period kept
            self._base_s = int(t[0])
            self._k_last, self._s_last = -1.0, int(t[0]) - int(round(self.period_ns))
            self._hist_k, self._hist_s = np.zeros(0), np.zeros(0)
            self._line = (0.0, self.period_ns, 0.0)  # anchored on the first stamp
            self._since_fit = 0
        d = np.diff(np.concatenate([[self._s_last], t])).astype(float)
        n, bad = period_counts(d, self.period_ns)
        self._bad = np.concatenate([self._bad, bad])[-self.window:]
        if len(self._bad) >= 256 and self._bad.mean() > IRREGULAR_SHARE:
            self.irregular, self.smoothing = True, False  # no longer periodic: as given
            return t
        k = self._k_last + np.cumsum(n)
        s = (t - self._base_s).astype(float)
        out = np.empty(len(t))
        i = 0
        while i < len(t):  # each stamp on the last line fitted; a new fit every REFIT_SAMPLES
            j = min(len(t), i + max(1, self.refit - self._since_fit))
            a, P, c = self._line
            out[i:j] = a + P * (k[i:j] - c)
            self._hist_k = np.concatenate([self._hist_k, k[i:j]])[-self.window:]
            self._hist_s = np.concatenate([self._hist_s, s[i:j]])[-self.window:]
            self._since_fit += j - i
            if self._since_fit >= self.refit and len(self._hist_k) >= 64:
                self._fit()
            i = j
        self._k_last, self._s_last = float(k[-1]), int(t[-1])
        res = self._base_s + np.rint(out).astype(np.int64)
        # strictly increasing, as the input: at least 1 ns after the one before
        idx = np.arange(len(res), dtype=np.int64)
        res = np.maximum.accumulate(np.maximum(res, self._last_out + 1) - idx) + idx
        self._last_out = int(res[-1])
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
