"""A compact history of the estimate: values, one-sigma and NIS of the run against time.

The streaming estimator records one point per ``period_s`` of data (issue 12: the report's
convergence and NIS plots); replay and the live node therefore write the same history. Memory
and the file stay small: when ``max_points`` points are held, every other one is dropped and
the period doubles (a run of any length keeps between ``max_points / 2`` and ``max_points``
evenly spaced points), and values are kept to ``DIGITS`` significant digits.

Each point holds the calibration states' values and sigmas (SI, the labels of
:meth:`~.error_model.StateLayout.labels` without psi and dv) and, per measurement kind, the
NIS sum and the count of accepted and gated updates since the previous point: the mean NIS
per degree of freedom of an interval with ``n`` updates of dimension 3 is
``chi2(3 n) / (3 n)``-distributed for a consistent filter (Bar-Shalom, Li & Kirubarajan,
sect. 5.4), which gives the report its band. Per component (ENU) also the sums of the
normalised innovations ``y_i / sqrt(S_ii)`` and of their squares: the interval mean of a
consistent filter's (white, unit-variance) innovations is within ``3 / sqrt(n)`` of zero and
their rms near 1 (a bias shows in the mean, a wrong noise level in the rms).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: significant digits kept of every value (the plots need three; the sigma ratio four)
DIGITS = 4
KINDS = ('velocity', 'attitude')
ROW = 9  # NIS sum, accepted, gated, 3 innovation sums, 3 innovation square sums


def _round(x: FloatArray) -> list[float]:
    return [float(f'{v:.{DIGITS}g}') for v in np.asarray(x, float).ravel()]


@dataclass
class EstimateHistory:
    """Decimated history (see the module docstring).

    Parameters
    ----------
    period_s : float
        Smallest spacing of two points [s of data]; doubles at every thinning.
    max_points : int
        Points kept at most (even, >= 4).
    """

    period_s: float = 1.0
    max_points: int = 64
    labels: tuple[str, ...] = ()
    t_ns: list[int] = field(default_factory=list)
    value: list[list[float]] = field(default_factory=list)
    sigma: list[list[float]] = field(default_factory=list)
    # [NIS sum, accepted, gated, innovation sums (3), innovation square sums (3)]
    nis: dict[str, list[list[float]]] = field(default_factory=dict)
    _t0_ns: int | None = None
    _counters: Any = None  # the filter's GateCounters the baselines below belong to
    _base: dict[str, list[float]] = field(default_factory=dict)
    _pending: dict[str, list[float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.period_s <= 0 or self.max_points < 4 or self.max_points % 2:
            raise ValueError(f'period_s > 0 and an even max_points >= 4 wanted, got '
                             f'{self.period_s}, {self.max_points}')

    def record(self, t_ns: int, labels: tuple[str, ...], values: FloatArray,
               sigmas: FloatArray, counters: Any, force: bool = False) -> None:
        """Offer the state at ``t_ns`` (after a block's feedback); kept when due (or
        ``force``: the end of the data, unless a point at ``t_ns`` exists).

        ``counters`` is the current filter's :class:`~.ekf.GateCounters` (cumulative per
        filter: a new filter after a restart or re-alignment starts new baselines).
        """
        if self._t0_ns is None:
            self._t0_ns = int(t_ns)
        if labels != self.labels:  # a new layout (never within one run): start over
            self.labels = tuple(labels)
            self.t_ns, self.value, self.sigma, self.nis = [], [], [], {}
        self._accumulate(counters)
        if self.t_ns and (t_ns <= self.t_ns[-1] or (
                not force and (t_ns - self.t_ns[-1]) * 1e-9 < self.period_s)):
            return
        self.t_ns.append(int(t_ns))
        self.value.append(_round(values))
        self.sigma.append(_round(sigmas))
        for k in KINDS:
            self.nis.setdefault(k, [[0.0] * ROW for _ in self.t_ns[:-1]])
            self.nis[k].append(self._pending.pop(k, [0.0] * ROW))
        if len(self.t_ns) >= self.max_points:
            self._thin()

    def _accumulate(self, counters: Any) -> None:
        """Add the NIS and gate counts since the previous call to the pending interval."""
        if counters is None:
            return
        if counters is not self._counters:
            self._counters = counters
            self._base = {}
        for k in KINDS:
            e = counters.innov_sum.get(k)
            q = counters.innov_sq.get(k)
            now = [float(counters.nis_sum.get(k, 0.0)), int(counters.accepted.get(k, 0)),
                   int(counters.rejected.get(k, 0)),
                   *([0.0] * 3 if e is None else [float(v) for v in e]),
                   *([0.0] * 3 if q is None else [float(v) for v in q])]
            base = self._base.get(k, [0.0] * ROW)
            p = self._pending.setdefault(k, [0.0] * ROW)
            for i in range(ROW):
                p[i] += now[i] - base[i]
            self._base[k] = now

    def _thin(self) -> None:
        """Keep every other point (the last one always); merge the NIS of dropped points
        into the kept point after them; double the period."""
        n = len(self.t_ns)
        keep = list(range(n - 1, -1, -2))[::-1]
        for k, rows in self.nis.items():
            merged, acc = [], [0.0] * ROW
            for i, r in enumerate(rows):
                acc = [a + b for a, b in zip(acc, r)]
                if i in keep:
                    merged.append(acc)
                    acc = [0.0] * ROW
            self.nis[k] = merged
        self.t_ns = [self.t_ns[i] for i in keep]
        self.value = [self.value[i] for i in keep]
        self.sigma = [self.sigma[i] for i in keep]
        self.period_s *= 2.0

    def as_dict(self) -> dict[str, Any] | None:
        """Plain YAML data (``extra.history``), or None before the first point.

        Keys: ``t_s`` (from the first recorded block), ``names`` (state labels), ``value``
        and ``sigma`` (one row per point, SI), ``nis`` {kind: {sum, accepted, gated,
        innovation_mean, innovation_rms (per ENU component, normalised)}: one entry per
        point, the accepted updates since the previous point}, ``period_s``.
        """
        if not self.t_ns or self._t0_ns is None:
            return None
        t0 = self._t0_ns
        return {
            't_s': [round((t - t0) * 1e-9, 3) for t in self.t_ns],
            'names': list(self.labels),
            'value': [list(r) for r in self.value],
            'sigma': [list(r) for r in self.sigma],
            'nis': {k: {'sum': [float(f'{r[0]:.{DIGITS}g}') for r in rows],
                        'accepted': [int(r[1]) for r in rows],
                        'gated': [int(r[2]) for r in rows],
                        'innovation_mean': [_round(np.asarray(r[3:6]) / max(r[1], 1))
                                            for r in rows],
                        'innovation_rms': [_round(np.sqrt(np.asarray(r[6:9]) / max(r[1], 1)))
                                           for r in rows]}
                    for k, rows in self.nis.items() if any(r[1] or r[2] for r in rows)},
            'period_s': self.period_s,
        }
