"""A fleet of calibrations (issue 13 item 3): each parameter across units, outliers, failures.

For every CONTRACT 4 parameter (the 45 of :data:`~.sensor_model.PARAMETER_NAMES`) over the
units that calibrated: the median, the robust spread ``1.4826 MAD`` (the fleet's sigma, not
pulled by the outliers it is to find), min and max. A unit is *beyond k sigma of the fleet*
in a parameter when ``|x - median| > k sqrt(s_fleet^2 + sigma_unit^2)`` (its own one-sigma
uncertainty counted, so a spread smaller than the calibration's noise flags nobody).
Parameters a unit held fixed are left out of that unit's comparison.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .calibration import CalibrationResult
from .sensor_model import PARAMETER_NAMES, PARAMETER_SLICES

MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class UnitOutcome:
    """One bag's calibration: the result file, or the one-line reason it failed."""

    unit: str
    bag: str
    status: str  # 'ok' or 'failed'
    reason: str = ''
    calib_path: str = ''
    seconds: float = 0.0
    calib: CalibrationResult | None = field(default=None, compare=False)


@dataclass(frozen=True)
class ParameterSpread:
    name: str
    n: int
    median: float
    sigma: float  # 1.4826 MAD
    minimum: float
    maximum: float
    outliers: tuple[tuple[str, float], ...]  # (unit, z)


def _fixed_mask(calib: CalibrationResult) -> np.ndarray:
    m = np.zeros(len(PARAMETER_NAMES), bool)
    for k in calib.fixed:
        m[PARAMETER_SLICES[k]] = True
    return m


def spreads(outcomes: list[UnitOutcome], k_sigma: float = 3.0) -> list[ParameterSpread]:
    """The distribution of every parameter over the units that calibrated."""
    ok = [o for o in outcomes if o.status == 'ok' and o.calib is not None]
    if not ok:
        return []
    x = np.array([o.calib.errors.as_vector() for o in ok])  # type: ignore[union-attr]
    s = np.array([o.calib.sigma.as_vector() for o in ok])  # type: ignore[union-attr]
    fixed = np.array([_fixed_mask(o.calib) for o in ok])  # type: ignore[arg-type]
    out = []
    for j, name in enumerate(PARAMETER_NAMES):
        use = ~fixed[:, j]
        if not use.any():
            continue
        v = x[use, j]
        med = float(np.median(v))
        sig = MAD_TO_SIGMA * float(np.median(np.abs(v - med)))
        flagged = []
        for i in np.flatnonzero(use):
            den = math.sqrt(sig ** 2 + s[i, j] ** 2)
            z = (x[i, j] - med) / den if den > 0 else 0.0
            if abs(z) > k_sigma:
                flagged.append((ok[i].unit, float(z)))
        out.append(ParameterSpread(name, int(use.sum()), med, sig, float(v.min()),
                                   float(v.max()), tuple(flagged)))
    return out


def units_csv(outcomes: list[UnitOutcome]) -> str:
    """One row per unit: status, reason, file, and every parameter's value and sigma."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(['unit', 'bag', 'status', 'reason', 'calibration', 'seconds',
                *PARAMETER_NAMES, *[f'sigma {n}' for n in PARAMETER_NAMES]])
    for o in outcomes:
        vals: list[Any] = [''] * (2 * len(PARAMETER_NAMES))
        if o.calib is not None:
            vals = [repr(float(v)) for v in o.calib.errors.as_vector()] + \
                   [repr(float(v)) for v in o.calib.sigma.as_vector()]
        w.writerow([o.unit, o.bag, o.status, o.reason, o.calib_path, f'{o.seconds:.1f}', *vals])
    return buf.getvalue()


def spreads_csv(sp: list[ParameterSpread], k_sigma: float) -> str:
    """One row per parameter: n, median, robust sigma, min, max, the units beyond k sigma."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(['parameter', 'units', 'median', 'fleet_sigma_1.4826MAD', 'min', 'max',
                f'beyond_{k_sigma:g}_sigma'])
    for p in sp:
        w.writerow([p.name, p.n, repr(p.median), repr(p.sigma), repr(p.minimum),
                    repr(p.maximum), ' '.join(f'{u}({z:+.1f})' for u, z in p.outliers)])
    return buf.getvalue()
