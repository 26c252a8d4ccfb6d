"""Engineering units for people (tables, reports, summaries); SI everywhere else.

How each CONTRACT 4 parameter is shown (deg/h, ppm, urad, ug, mm), derived from the
parameter registry (:mod:`.parameters`, which owns the units of every group).
"""
from __future__ import annotations

from . import parameters as registry
from .parameters import DEG_H_RAD_S, G0_M_S2, MM, PPM, UG_M_S2, URAD  # noqa: F401

#: CONTRACT 4 key -> (short label, SI value of one engineering unit, unit name). For the
#: scale/misalignment matrices the unit named is the diagonal's (scale factor, ppm) and
#: :data:`OFF_DIAGONAL_UNIT` names the off-diagonal's (misalignment, urad; the same 1e-6).
ENGINEERING: dict[str, tuple[str, float, str]] = {
    p.key: (p.label, registry.display_group(p.key).si_per_unit,
            registry.display_group(p.key).unit) for p in registry.PARAMETERS}

#: CONTRACT 4 key -> unit of the off-diagonal entries, where it differs from the diagonal's
OFF_DIAGONAL_UNIT: dict[str, str] = {
    p.key: registry.element_unit(p.key, (0, 1)) for p in registry.PARAMETERS
    if p.is_matrix and registry.element_unit(p.key, (0, 1)) != ENGINEERING[p.key][2]}

#: the engineering unit of one entry (``'ppm'`` on the diagonal of Kg, ``'urad'`` off it)
element_unit = registry.element_unit
