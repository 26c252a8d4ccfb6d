"""Streaming overlapping Allan variance with bounded memory (issue 13).

The overlapping Allan variance of a rate record ``y`` (sample period ``tau0``) at
``tau = m tau0`` is, with the phase (integrated rate) ``x_j = tau0 sum_{i<j} y_i``::

    avar(tau) = < (x_{j+2m} - 2 x_{j+m} + x_j)^2 > / (2 tau^2)

(IEEE Std 952-1997 annex C; Riley, NIST SP 1065, eq. 11). ``allantools.oadev`` computes it
from the whole record in memory; a 4 h record at 2 kHz is 28.8 million samples per axis, so
here the sums are accumulated chunk by chunk:

- tau = m tau0 for ``m = 1..15`` uses every phase point (fully overlapping, as
  ``allantools.oadev``);
- longer taus use the phase on a grid of stride ``s = 2^L`` with ``m = k s``, ``k`` in
  ``8, 10, 12, 14``: the phase at every ``s``-th sample is exact (a cumulative sum), so this is
  the fully overlapping estimator of the record averaged over blocks of ``s`` samples,
  i.e. overlapping at a step of ``m / k`` samples. Its equivalent degrees of freedom are
  Greenhall's for ``k`` on ``N / s`` points (``allantools.edf_greenhall``), nearly those of
  the fully overlapping estimator (the overlap gains little beyond a step of ``m / 8``).

Memory per level is ``2 k_max + 1`` phase points and one sum per tau; a record is cut into
segments (gaps, separate stationary windows) and sums never cross a segment boundary.
Nothing is sub-sampled: every sample enters every tau (Allan deviations from sub-sampled
data overstate nothing at long tau but understate white noise; averaging keeps it).
The test compares with ``allantools.oadev`` on whole records (``test/test_noise.py``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: m at the finest level (every phase point)
_K_FINE = tuple(range(1, 16))
#: k at the coarser levels (m = k * 2^L, L >= 1): 4 taus per octave
_K_COARSE = (8, 10, 12, 14)
_MAX_LEVELS = 40  # strides up to 2^39 samples


@dataclass(frozen=True)
class AllanCurve:
    """Overlapping Allan deviation of each axis.

    ``tau_s (T,)``, ``adev (T, n_axes)`` [unit of the input], ``n_terms (T,)`` second
    differences summed, ``stride (T,)`` and ``k (T,)`` (``m = stride * k``), ``points (T,)``
    phase points (summed over segments) at that stride, for the degrees of freedom.
    """

    tau_s: FloatArray
    adev: FloatArray
    n_terms: NDArray[np.int64]
    stride: NDArray[np.int64]
    k: NDArray[np.int64]
    points: NDArray[np.int64]
    segment_points: tuple[NDArray[np.int64], ...]  # per tau: phase points of each segment
    tau0_s: float
    n_samples: int
    duration_s: float


class _Level:
    """One stride ``s``: the last phase points on the grid and the sums of its taus."""

    __slots__ = ('stride', 'ks', 'hist', 'sums', 'counts')

    def __init__(self, stride: int, ks: tuple[int, ...], n_axes: int) -> None:
        self.stride = stride
        self.ks = ks
        self.hist = np.zeros((1, n_axes))  # x_0 = 0: the segment's start
        self.sums = np.zeros((len(ks), n_axes))
        self.counts = np.zeros(len(ks), np.int64)

    def push(self, grid: FloatArray) -> None:
        if not len(grid):
            return
        g = np.concatenate([self.hist, grid]) if len(self.hist) else grid
        h, n = len(self.hist), len(g)
        for i, k in enumerate(self.ks):
            lo = max(2 * k, h)
            if lo >= n:
                continue
            d = g[lo:] - 2.0 * g[lo - k:n - k] + g[lo - 2 * k:n - 2 * k]
            self.sums[i] += np.einsum('ij,ij->j', d, d)
            self.counts[i] += n - lo
        keep = 2 * max(self.ks)
        self.hist = g[-keep:].copy() if n > keep else g.copy()


class AllanAccumulator:
    """Overlapping Allan variance of ``n_axes`` rate channels, fed chunk by chunk.

    Parameters
    ----------
    tau0_s : float
        Sample period [s].
    n_axes : int
        Channels (6: gyro x, y, z, accelerometer x, y, z).

    Use :meth:`add` with ``(n, n_axes)`` chunks in time order, :meth:`new_segment` at a gap
    or between stationary windows, :meth:`curve` at the end. The rate is centred on the first
    chunk's mean before it is integrated (the Allan variance ignores a constant; the phase
    then stays small and exact in float64).
    """

    def __init__(self, tau0_s: float, n_axes: int = 6) -> None:
        if not (tau0_s > 0 and math.isfinite(tau0_s)):
            raise ValueError(f'tau0_s must be a positive number, got {tau0_s}')
        self.tau0_s = float(tau0_s)
        self.n_axes = n_axes
        self._levels = [_Level(1 << j, _K_FINE if j == 0 else _K_COARSE, n_axes)
                        for j in range(_MAX_LEVELS)]
        self._ref: FloatArray | None = None
        self._segments: list[int] = []  # samples per finished segment
        self._n_seg = 0  # samples in the current segment
        self._phase = np.zeros(n_axes)
        self.n_samples = 0

    def new_segment(self) -> None:
        """End the current segment (a gap): no second difference spans the boundary."""
        if self._n_seg:
            self._segments.append(self._n_seg)
        self._n_seg = 0
        self._phase = np.zeros(self.n_axes)
        for lvl in self._levels:
            lvl.hist = np.zeros((1, self.n_axes))

    def add(self, y: ArrayLike) -> None:
        """Append ``(n, n_axes)`` rate samples to the current segment."""
        y = np.asarray(y, dtype=float)
        if y.ndim != 2 or y.shape[1] != self.n_axes:
            raise ValueError(f'expected (n, {self.n_axes}) samples, got {y.shape}')
        if not len(y):
            return
        if not np.all(np.isfinite(y)):
            raise ValueError('non-finite samples')
        if self._ref is None:
            self._ref = y.mean(axis=0)
        x = np.cumsum(y - self._ref, axis=0)
        x += self._phase
        self._phase = x[-1].copy()
        c = self._n_seg  # phase index of x[0] is c + 1; x_0 = 0 starts every level
        end = c + len(y)
        for lvl in self._levels:
            s = lvl.stride
            if s > end:
                break
            j0 = (c // s + 1) * s  # first grid index in this chunk
            if j0 <= end:
                lvl.push(x[j0 - c - 1::s])
        self._n_seg = end
        self.n_samples += len(y)

    def curve(self) -> AllanCurve:
        """The Allan deviation at every tau with at least one second difference."""
        segs = self._segments + ([self._n_seg] if self._n_seg else [])
        rows = []
        for lvl in self._levels:
            s = lvl.stride
            for i, k in enumerate(lvl.ks):
                if lvl.counts[i] == 0:
                    continue
                tau = k * s * self.tau0_s
                avar = lvl.sums[i] * self.tau0_s ** 2 / lvl.counts[i] / (2.0 * tau * tau)
                pts = np.array([n // s + 1 for n in segs if n // s >= 2 * k], np.int64)
                rows.append((tau, np.sqrt(avar), int(lvl.counts[i]), s, k, pts))
        rows.sort(key=lambda r: r[0])
        taus = np.array([r[0] for r in rows])
        return AllanCurve(taus, np.array([r[1] for r in rows]).reshape(len(rows), self.n_axes),
                          np.array([r[2] for r in rows], np.int64),
                          np.array([r[3] for r in rows], np.int64),
                          np.array([r[4] for r in rows], np.int64),
                          np.array([int(r[5].sum()) for r in rows], np.int64),
                          tuple(r[5] for r in rows), self.tau0_s, self.n_samples,
                          self.n_samples * self.tau0_s)


def allan_curve(y: ArrayLike, tau0_s: float) -> AllanCurve:
    """:class:`AllanAccumulator` over one in-memory record ``(n, n_axes)``."""
    y = np.asarray(y, dtype=float)
    acc = AllanAccumulator(tau0_s, y.shape[1])
    for a in range(0, len(y), 1 << 16):
        acc.add(y[a:a + (1 << 16)])
    return acc.curve()


def overlapping_avar(y: ArrayLike, m: ArrayLike) -> FloatArray:
    """Fully overlapping Allan variance of a whole in-memory record ``y (n, n_axes)`` at
    ``tau = m tau0`` for the given integers ``m``: ``(len(m), n_axes)`` [unit of y squared].

    The estimator of ``allantools.oadev(..., data_type='freq')`` (phase ``x_0 = 0``, ``x_j =
    sum_{i<j} y_i``, ``n + 1 - 2 m`` second differences), all axes at once (``tau0`` cancels).
    Written out because the estimator's start calls it on every stationary window: there
    ``oadev`` per axis and its import (``scipy.stats``) were a tenth of an hour's replay;
    ``test_noise`` holds it to ``allantools.oadev``. The record is referred to its first
    sample (exact for a constant record; the Allan variance ignores a constant)."""
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        y = y[:, None]
    x = np.zeros((len(y) + 1, y.shape[1]))
    np.cumsum(y - y[:1], axis=0, out=x[1:])
    ms = np.asarray(m, dtype=np.int64).reshape(-1)
    out = np.full((len(ms), y.shape[1]), np.nan)
    for i, k in enumerate(ms.tolist()):
        if k < 1 or 2 * k >= len(x):
            continue
        d = x[2 * k:] - 2.0 * x[k:-k] + x[:-2 * k]
        out[i] = np.einsum('ij,ij->j', d, d) / (2.0 * len(d) * k * k)
    return out


def windows_accumulator(gyro: FloatArray, accel: FloatArray, tau0_s: float,
                        windows: list[tuple[int, int]]) -> AllanAccumulator:
    """The six channels (gyro, accelerometer) of the sample ranges ``[(i0, i1), ...]`` (the
    stationary windows of a calibration run), one segment each: no difference spans two
    windows (their attitudes differ)."""
    acc = AllanAccumulator(tau0_s, 6)
    for i0, i1 in windows:
        acc.add(np.hstack([gyro[i0:i1], accel[i0:i1]]))
        acc.new_segment()
    return acc
