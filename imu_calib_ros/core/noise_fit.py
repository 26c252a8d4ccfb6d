"""IEEE Std 952 noise terms from an Allan deviation curve, with confidence intervals (issue 13).

The Allan variance of the five IEEE Std 952-1997 (annex C) processes adds up::

    avar(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2

| term | slope of adev | name                                       | unit (gyro)          |
|------|---------------|--------------------------------------------|----------------------|
| Q    | -1            | quantisation noise (angle/velocity)        | rad                  |
| N    | -1/2          | angle/velocity random walk (white noise)   | rad/s/sqrt(Hz)       |
| B    | 0             | bias instability (flicker floor 0.664 B)   | rad/s                |
| K    | +1/2          | rate random walk (bias Wiener process)     | rad/s/sqrt(s)        |
| R    | +1            | rate ramp (a drift: tilt, temperature)     | rad/s^2              |

:func:`fit_axis` fits the five variances by non-negative weighted least squares
(``scipy.optimize.nnls``), each tau weighted by its equivalent degrees of freedom
(Greenhall's, ``allantools.edf_greenhall``, for the noise type that dominates there:
the variance of an Allan variance estimate is ``2 avar^2 / edf``), reweighted from the model.
Then, as IEEE 952's slope-region reading: a term counts as *shown* only where it makes at
least half the variance at some tau and its interval excludes zero; its 95 % interval comes
from the chi-square interval of the Allan variance at the tau where it is best seen (largest
``share^2 * edf``), divided by its share there (the other terms held), combined with the
least-squares standard error widened for the correlation of neighbouring taus. A rate ramp
is kept only when significant (it is a drift, not a noise). A term the record does not show
gets no value, only a 95 % upper bound (the upper end of its interval when that reaches zero,
else the smallest ``avar_upper(tau) / f(tau)``) and a warning.

Never a line through a bump: taus where the measured curve stands out of the fitted model by
more than 4 of its standard errors *and* 15 % in variance (a vibration line, a tilt step)
are left out, the worst run of them at a time with its shoulders (the neighbours still 2
standard errors out on the same side), and the fit repeated; what was left out is
reported in one line.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls
from scipy.stats import chi2

from .allan import AllanCurve

FloatArray = NDArray[np.float64]

TERMS = ('Q', 'N', 'B', 'K', 'R')
#: power of tau of each term's Allan variance
POWERS = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
#: noise type (power-law alpha of the fractional-frequency PSD) for Greenhall's edf
_ALPHA = (2, 0, -1, -2, -2)
_FLICKER = 2.0 * math.log(2.0) / math.pi
#: a term is shown where its share of the Allan variance reaches this
SHOWN_SHARE = 0.5
CONFIDENCE = 0.95
BUMP_SIGMAS = 4.0
Z95 = 1.959964
#: the least-squares standard errors treat the taus as independent; neighbouring taus (4 per
#: octave) share most of their data: the errors are widened by sqrt(4)
CORRELATED = 2.0
BUMP_RELATIVE = 0.15


def coefficient_to_variance(term: str, value: float) -> float:
    """The term's Allan-variance coefficient ``c`` (``avar = c tau^p``) of its value."""
    return {'Q': 3.0 * value ** 2, 'N': value ** 2, 'B': _FLICKER * value ** 2,
            'K': value ** 2 / 3.0, 'R': value ** 2 / 2.0}[term]


def variance_to_coefficient(term: str, c: float) -> float:
    """Inverse of :func:`coefficient_to_variance` (``c >= 0``)."""
    c = max(c, 0.0)
    return {'Q': math.sqrt(c / 3.0), 'N': math.sqrt(c), 'B': math.sqrt(c / _FLICKER),
            'K': math.sqrt(3.0 * c), 'R': math.sqrt(2.0 * c)}[term]


@dataclass(frozen=True)
class TermFit:
    """One IEEE 952 term of one axis: value and 95 % interval, or only an upper bound."""

    term: str
    value: float | None  # None: the record does not show the term
    low: float | None
    high: float  # the interval's upper end, or the upper bound when not shown
    tau_s: float | None  # where it is best seen

    @property
    def shown(self) -> bool:
        return self.value is not None

    def as_dict(self) -> dict[str, Any]:
        if self.value is None:
            return {'shown': False, 'upper_bound_95': self.high}
        return {'shown': True, 'value': self.value, 'ci95': [self.low, self.high],
                'tau_s': self.tau_s}


@dataclass(frozen=True)
class AxisFit:
    """The fit of one axis: the terms, the model and what was left out."""

    terms: dict[str, TermFit]
    tau_s: FloatArray
    adev: FloatArray
    model_adev: FloatArray
    edf: FloatArray
    used: NDArray[np.bool_]
    bumps: tuple[tuple[float, float, float], ...] = field(default=())  # (tau lo, hi, ratio)


def edf_of(curve: AllanCurve, alpha: NDArray[np.int64]) -> FloatArray:
    """Equivalent degrees of freedom of each tau (summed over segments; Greenhall 2004)."""
    import allantools
    out = np.zeros(len(curve.tau_s))
    cache: dict[tuple[int, int, int], float] = {}
    for i, (k, pts) in enumerate(zip(curve.k, curve.segment_points)):
        tot = 0.0
        for n in pts:
            key = (int(alpha[i]), int(k), int(n))
            if key not in cache:
                cache[key] = float(allantools.edf_greenhall(key[0], 2, key[1], key[2],
                                                            overlapping=True))
            tot += cache[key]
        out[i] = tot
    return out


def _nnls(A: FloatArray, avar: FloatArray, edf: FloatArray, use: NDArray[np.bool_],
          model: FloatArray, cols: NDArray[np.bool_]) -> tuple[FloatArray, FloatArray]:
    """Weighted NNLS over the columns ``cols``; the coefficients and their standard errors
    (the active set's ``(A^T W A)^-1``, as if the taus were independent)."""
    w = np.sqrt(edf / 2.0) / np.maximum(model, 1e-300)
    Aw = A[use][:, cols] * w[use, None]
    scale = np.max(np.abs(Aw), axis=0)
    scale[scale == 0] = 1.0
    cs, _ = nnls(Aw / scale, avar[use] * w[use])
    c = np.zeros(A.shape[1])
    c[cols] = cs / scale
    se = np.zeros(A.shape[1])
    act = cs > 0
    if act.any():
        M = (Aw / scale)[:, act]
        cov = np.linalg.pinv(M.T @ M)
        idx = np.flatnonzero(cols)[act]
        se[idx] = np.sqrt(np.maximum(np.diag(cov), 0.0)) / scale[act]
    return c, se


def fit_axis(curve: AllanCurve, axis: int, max_bumps: int = 4) -> AxisFit:
    """Fit the five terms to one axis of ``curve`` (module docstring)."""
    tau = curve.tau_s
    avar = curve.adev[:, axis] ** 2
    A = tau[:, None] ** POWERS
    use = (avar > 0) & np.array([len(p) > 0 for p in curve.segment_points])
    alpha = np.zeros(len(tau), np.int64)
    edf = edf_of(curve, alpha)
    use &= edf >= 1.0
    model = avar.copy()
    bumps: list[tuple[float, float, float]] = []
    cols = np.ones(len(TERMS), bool)
    for _ in range(max_bumps + 2):
        for _ in range(4):  # reweight from the model; edf for the dominant noise type
            c, se = _nnls(A, avar, edf, use, model, cols)
            parts = A * c
            model = np.maximum(parts.sum(axis=1), 1e-300)
            new_alpha = np.array(_ALPHA)[np.argmax(parts, axis=1)]
            if np.any(new_alpha != alpha):
                alpha = new_alpha
                edf = np.maximum(edf_of(curve, alpha), 1e-3)
        rel = avar / model - 1.0
        z = rel / np.sqrt(2.0 / edf)
        bad = use & (np.abs(z) > BUMP_SIGMAS) & (np.abs(rel) > BUMP_RELATIVE)
        if not bad.any() or len(bumps) >= max_bumps:
            # a rate ramp is a drift, not a noise: kept only when the data demand it
            if cols[4] and c[4] <= Z95 * CORRELATED * se[4]:
                cols[4] = False
                continue
            break
        worst = int(np.argmax(np.where(bad, np.abs(z), -1.0)))
        # the run, widened to its shoulders (same sign, still 2 standard errors out)
        side = (np.sign(z) == np.sign(z[worst])) & (np.abs(z) > 2.0) & use
        lo = hi = worst
        while lo > 0 and side[lo - 1]:
            lo -= 1
        while hi < len(tau) - 1 and side[hi + 1]:
            hi += 1
        use[lo:hi + 1] = False
        bumps.append((float(tau[lo]), float(tau[hi]),
                      float(np.sqrt(np.max(avar[lo:hi + 1] / model[lo:hi + 1])))))
        model = avar.copy()
    parts = A * c
    share = parts / model[:, None]
    terms: dict[str, TermFit] = {}
    a = (1.0 - CONFIDENCE) / 2.0
    for j, name in enumerate(TERMS):
        sh = np.where(use, share[:, j], 0.0)
        if c[j] > 0 and sh.max() >= SHOWN_SHARE:
            cand = use & (sh >= SHOWN_SHARE)
            i = int(np.argmax(np.where(cand, sh ** 2 * edf, -1.0)))
            lo_r = edf[i] / chi2.ppf(1.0 - a, edf[i])
            hi_r = edf[i] / chi2.ppf(a, edf[i])
            ls = Z95 * CORRELATED * se[j]
            c_lo = c[j] - math.hypot(c[j] * (1.0 - lo_r) / sh[i], ls)
            c_hi = c[j] + math.hypot(c[j] * (hi_r - 1.0) / sh[i], ls)
            if c_lo > 0:
                terms[name] = TermFit(name, variance_to_coefficient(name, c[j]),
                                      variance_to_coefficient(name, c_lo),
                                      variance_to_coefficient(name, c_hi), float(tau[i]))
            else:  # its interval reaches zero: not shown, its upper end is the bound
                terms[name] = TermFit(name, None, None, variance_to_coefficient(name, c_hi),
                                      None)
        else:
            hi_var = avar * edf / chi2.ppf(a, np.maximum(edf, 1e-3))
            bound = float(np.min((hi_var / A[:, j])[use])) if use.any() else math.inf
            terms[name] = TermFit(name, None, None, variance_to_coefficient(name, bound), None)
    return AxisFit(terms, tau, np.sqrt(avar), np.sqrt(model), edf, use, tuple(bumps))
