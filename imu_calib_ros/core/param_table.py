"""Calibration parameters for people: labelled blocks with per-element units (issue 12).

The one owner of how a calibration is laid out for reading: each CONTRACT 4 parameter as a
3-vector or a labelled 3x3 matrix, every entry in its engineering unit (the registry,
:mod:`.parameters`: ppm on the diagonal of Kg and Ka, urad off it), with its one-sigma value,
its significance ``|value| / sigma`` and whether it was estimated or held fixed. A fixed entry
is never shown as an estimate; a parameter held fixed at zero everywhere is folded into one
line. The ``replay`` terminal summary (:func:`format_text`), the HTML report
(:mod:`imu_calib_ros.report`) and the demo use these blocks.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import parameters as registry

FloatArray = NDArray[np.float64]
AXES = registry.AXES

#: what the rows and columns of each matrix parameter mean (shown under its title)
MATRIX_NOTES: dict[str, str] = {
    'gyroscope.scale_misalignment': 'row i = gyro i; scale (ppm) on the diagonal, '
                                    'misalignment (urad) off; symmetric',
    'gyroscope.g_sensitivity': 'row i = gyro i, column j = specific force along j',
    'accelerometer.scale_misalignment': 'row i = accelerometer i; scale (ppm) on the '
                                        'diagonal, misalignment (urad) off',
    'accelerometer.size_effect': 'row i = position r_i of accelerometer i; r_i[i] = 0 by '
                                 'definition',
}


def srt_not_estimated(res: Any) -> set[tuple[str, tuple[int, ...]]] | None:
    """Entry-level (field, index) pairs an SRT result held fixed, or None if not an SRT file.

    CONTRACT 4's ``fixed`` lists whole keys: one unexcited entry (e.g. ``ba_x``) puts all of
    ``accelerometer.bias`` there, while the SRT's ``extra.srt.not_estimated`` names entries.
    """
    names = (getattr(res, 'extra', None) or {}).get('srt', {}).get('not_estimated')
    if names is None:
        return None
    from .methods.srt import CONSIDER, PARAMS
    out = {(fld, tuple(idx)) for n, fld, idx in PARAMS if n in names}
    out |= {(fld, tuple(idx)) for _, fld, idx, _ in CONSIDER}
    for n, fld, idx in PARAMS:  # Kg is symmetric: both halves
        if n in names and registry.PARAMETER_OF_FIELD[fld].symmetric:
            out.add((fld, tuple(idx[::-1])))
    return out


def is_fixed(res: Any, fld: str, key: str, idx: tuple[int, ...]) -> bool:
    """True when ``res`` held this entry at its assumed value (not estimated from the data)."""
    entries = srt_not_estimated(res)
    if entries is not None and key not in ('gyroscope.bias',):
        return (fld, tuple(idx)) in entries
    return key in tuple(getattr(res, 'fixed', ()))


@dataclass(frozen=True)
class Block:
    """One CONTRACT 4 parameter in engineering units.

    ``value``, ``sigma``, ``units``, ``fixed`` and ``structural`` have the parameter's shape,
    (3,) or (3, 3); ``structural`` marks entries that are not parameters (the size effect's
    zero diagonal); for a symmetric Kg the lower triangle repeats the upper one.
    """

    key: str
    field: str
    label: str
    value: FloatArray
    sigma: FloatArray
    units: NDArray[Any]
    fixed: NDArray[np.bool_]
    structural: NDArray[np.bool_]

    @property
    def is_matrix(self) -> bool:
        """A 3x3 parameter."""
        return self.value.ndim == 2

    @property
    def unit_text(self) -> str:
        """The unit(s) for a heading: ``'deg/h'``, or ``'ppm (diagonal), urad (off)'``."""
        u = {str(x) for x in self.units.ravel()}
        if len(u) == 1:
            return u.pop()
        return f'{self.units[0, 0]} (diagonal), {self.units[0, 1]} (off-diagonal)'

    @property
    def all_fixed(self) -> bool:
        """No entry was estimated."""
        return bool(np.all(self.fixed | self.structural))

    @property
    def folded(self) -> bool:
        """Held fixed at zero everywhere: shown as one line, not a block of zeros."""
        return self.all_fixed and bool(np.all(self.value == 0.0))

    def significance(self) -> FloatArray:
        """``|value| / sigma`` of the estimated entries (NaN for fixed and zero sigma)."""
        with np.errstate(divide='ignore', invalid='ignore'):
            z = np.abs(self.value) / self.sigma
        return np.where(self.fixed | self.structural | ~(self.sigma > 0), np.nan, z)

    def entries(self) -> list[tuple[int, ...]]:
        """Indices of the parameter entries (no structural zeros, Kg's upper triangle)."""
        if not self.is_matrix:
            return [(i,) for i in range(3)]
        sym = registry.parameter(self.key).symmetric
        return [(i, j) for i in range(3) for j in range(3)
                if not self.structural[i, j] and not (sym and j < i)]

    @staticmethod
    def name_of(idx: tuple[int, ...]) -> str:
        """``'x'`` or ``'xy'``."""
        return ''.join(AXES[i] for i in idx)


def blocks(res: Any, errors: Any = None) -> list[Block]:
    """The CONTRACT 4 parameters of ``res`` (a CalibrationResult) as blocks; ``errors``
    (SensorErrors) replaces its values, e.g. a truth's tracked errors."""
    errs = errors if errors is not None else res.errors
    out = []
    for p in registry.PARAMETERS:
        fld, key = p.field, p.key
        si = registry.display_group(key).si_per_unit
        v = np.asarray(getattr(errs, fld), float) / si
        s = np.asarray(getattr(res.sigma, fld), float) / si
        units = np.empty(v.shape, object)
        fixed = np.zeros(v.shape, bool)
        structural = np.zeros(v.shape, bool)
        for idx in np.ndindex(v.shape):
            units[idx] = registry.element_unit(key, idx)
            fixed[idx] = is_fixed(res, fld, key, idx)
            structural[idx] = p.canonical(idx) is None  # the size effect's zero diagonal
        out.append(Block(key, fld, p.label, v, s, units, fixed, structural))
    return out


def fmt(x: float, digits: int = 4) -> str:
    """A number for people: ``digits`` significant digits, no exponent between 1e-3 and
    1e6, ``0`` for zero."""
    if x == 0.0 or not np.isfinite(x):
        return '0' if x == 0.0 else str(x)
    a = abs(x)
    if 1e-3 <= a < 1e6:
        decimals = max(digits - 1 - int(np.floor(np.log10(a))), 0)
        return f'{x:.{decimals}f}'
    return f'{x:.{digits - 1}e}'


def fmt_at_sigma(x: float, sigma: float, digits: int = 4) -> str:
    """A value no finer than its sigma's second digit (``0.0035 +- 0.082``, not
    ``0.003496``: digits under the noise widened a text table past 90 columns), else
    :func:`fmt`'s ``digits``; :func:`fmt` when either leaves the plain range."""
    plain = 1e-3 <= sigma < 1e6 and abs(x) < 1e6
    if not plain or not np.isfinite(x):
        return fmt(x, digits)
    d = max(1 - int(np.floor(np.log10(sigma))), 0)  # the decimals of fmt(sigma, 2)
    if abs(x) >= 1e-3:
        d = min(d, max(digits - 1 - int(np.floor(np.log10(abs(x)))), 0))
    return f'{round(x, d) + 0.0:.{d}f}'  # (+ 0.0: no '-0.000')


def cell_text(b: Block, idx: tuple[int, ...], pm: str = '+-') -> str:
    """One entry: ``'12.31 +- 0.32 ppm'``, ``'0 urad (fixed)'`` or ``'-'`` (structural)."""
    if b.structural[idx]:
        return '-'
    u = str(b.units[idx])
    if b.fixed[idx]:
        return f'{fmt(float(b.value[idx]))} {u} (fixed)'
    s = float(b.sigma[idx])
    return f'{fmt_at_sigma(float(b.value[idx]), s)} {pm} {fmt(s, 2)} {u}'


def matrix_title(b: Block) -> str:
    """``'gyro G [deg/h/g]'``; mixed units are named by the note instead."""
    return b.label if len({str(u) for u in b.units.ravel()}) > 1 else f'{b.label} [{b.unit_text}]'


def folded_line(folded: list[Block]) -> str:
    """One line for the parameters held fixed at zero (with their assumed sigma)."""
    parts = []
    for b in folded:
        k = np.unravel_index(int(np.argmax(b.sigma)), b.sigma.shape)
        s = float(b.sigma[k])
        parts.append(f'{b.label} (assumed sigma {fmt(s, 2)} {b.units[k]})' if s > 0
                     else f'{b.label} (assumed exactly zero)')
    return 'not estimated, held at zero: ' + ', '.join(parts)


def format_text(res: Any) -> str:
    """The calibration as text blocks (the ``replay`` summary): each vector as its label and
    one row under the matrices' x, y, z columns, each matrix as a labelled 3x3 block, every
    entry ``value +- sigma unit`` or ``fixed``; the parameters held at zero folded into one
    line at the end."""
    bl = blocks(res)
    lines = [f'calibration of {res.frame_id}: value +- one sigma; "fixed" = not estimated '
             '(assumed value)']
    width = 0
    for b in bl:
        if not b.folded:
            width = max(width, *(len(cell_text(b, idx)) for idx in np.ndindex(b.value.shape)))
    for b in bl:
        if b.folded:
            continue
        if b.is_matrix:
            lines.append(f'{matrix_title(b)}: {MATRIX_NOTES.get(b.key, "")}')
            lines.append('      ' + ''.join(f'{a:>{width + 2}s}' for a in AXES))
            for i in range(3):
                lines.append(f'    {AXES[i]} ' + ''.join(
                    f'{cell_text(b, (i, j)):>{width + 2}s}' for j in range(3)))
        else:  # the label, then x y z under the matrices' columns (90 columns, not 120)
            lines.append(f'{b.label} [{b.unit_text}]: x, y, z')
            lines.append('      ' + ''.join(f'{cell_text(b, (i,)):>{width + 2}s}'
                                            for i in range(3)))
    folded = [b for b in bl if b.folded]
    if folded:
        lines.append(folded_line(folded))
    return '\n'.join(lines)
