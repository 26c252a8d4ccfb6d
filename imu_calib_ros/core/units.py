"""Engineering units for people (tables, reports, summaries); SI everywhere else.

The one place that says how each CONTRACT 4 parameter is shown: deg/h, ppm, urad, ug, mm.
"""
from __future__ import annotations

import math

#: standard gravity: the "g" of ug and deg/h/g (a unit, not the site's gravity)
G0_M_S2 = 9.80665
DEG_H_RAD_S = math.pi / 180.0 / 3600.0  # rad/s per deg/h
PPM = 1e-6
URAD = 1e-6
UG_M_S2 = 1e-6 * G0_M_S2
MM = 1e-3

#: CONTRACT 4 key -> (short label, SI value of one engineering unit, unit name). For the
#: scale/misalignment matrices the unit named is the diagonal's (scale factor, ppm) and
#: :data:`OFF_DIAGONAL_UNIT` names the off-diagonal's (misalignment, urad; the same 1e-6).
ENGINEERING: dict[str, tuple[str, float, str]] = {
    'gyroscope.bias': ('gyro bias', DEG_H_RAD_S, 'deg/h'),
    'gyroscope.scale_misalignment': ('gyro Kg', PPM, 'ppm'),
    'gyroscope.scale_asymmetry': ('gyro asym', PPM, 'ppm'),
    'gyroscope.g_sensitivity': ('gyro G', DEG_H_RAD_S / G0_M_S2, 'deg/h/g'),
    'accelerometer.bias': ('accel bias', UG_M_S2, 'ug'),
    'accelerometer.scale_misalignment': ('accel Ka', PPM, 'ppm'),
    'accelerometer.scale_asymmetry': ('accel asym', PPM, 'ppm'),
    'accelerometer.quadratic': ('accel quad', UG_M_S2 / G0_M_S2 ** 2, 'ug/g^2'),
    'accelerometer.size_effect': ('size effect', MM, 'mm'),
}

#: CONTRACT 4 key -> unit of the off-diagonal entries, where it differs from the diagonal's
OFF_DIAGONAL_UNIT: dict[str, str] = {
    'gyroscope.scale_misalignment': 'urad',
    'accelerometer.scale_misalignment': 'urad',
}


def element_unit(key: str, idx: tuple[int, ...]) -> str:
    """The engineering unit of one entry ``idx`` of the parameter ``key`` (e.g. ``'ppm'``
    on the diagonal of Kg, ``'urad'`` off it)."""
    if len(idx) == 2 and idx[0] != idx[1] and key in OFF_DIAGONAL_UNIT:
        return OFF_DIAGONAL_UNIT[key]
    return ENGINEERING[key][2]
