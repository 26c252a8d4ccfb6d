"""The chi-square, binomial and normal tail quantiles of the gate and the self-check.

From :mod:`scipy.special` (the incomplete gamma and binomial functions :mod:`scipy.stats`
calls): importing
``scipy.stats`` costs about 0.35 s of every process start (the replay, each node), for four
functions (`test/test_quantiles.py` compares them with ``scipy.stats``).
"""
from __future__ import annotations

import numpy as np
from scipy import special


def chi2_ppf(p: float, dof: float) -> float:
    """``x`` with ``P(chi2(dof) <= x) = p`` (``scipy.stats.chi2.ppf``)."""
    return float(2.0 * special.gammaincinv(0.5 * dof, p))


def chi2_isf(q: float, dof: float) -> float:
    """``x`` with ``P(chi2(dof) > x) = q`` (``scipy.stats.chi2.isf``)."""
    return float(2.0 * special.gammainccinv(0.5 * dof, q))


def chi2_sf(x: float, dof: float) -> float:
    """``P(chi2(dof) > x)`` (``scipy.stats.chi2.sf``)."""
    return float(special.gammaincc(0.5 * dof, 0.5 * x))


def binom_isf(q: float, n: int, p: float) -> int:
    """The smallest count ``k`` with ``P(Binomial(n, p) > k) <= q`` (``scipy.stats.binom.isf``
    for ``0 < q < 1``)."""
    k = np.arange(n + 1, dtype=float)
    return int(np.argmax(special.bdtrc(k, n, p) <= q))


def norm_isf(q: float) -> float:
    """``x`` with ``P(N(0, 1) > x) = q`` (``scipy.stats.norm.isf``)."""
    return float(-special.ndtri(q))


def t_isf(q: float, dof: float) -> float:
    """``x`` with ``P(t(dof) > x) = q`` (``scipy.stats.t.isf``)."""
    return float(special.stdtrit(dof, 1.0 - q))
