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
#: scale/misalignment matrices the diagonal is in ppm and the off-diagonal in urad (both 1e-6).
ENGINEERING: dict[str, tuple[str, float, str]] = {
    'gyroscope.bias': ('gyro bias', DEG_H_RAD_S, 'deg/h'),
    'gyroscope.scale_misalignment': ('gyro Kg', PPM, 'ppm|urad'),
    'gyroscope.scale_asymmetry': ('gyro asym', PPM, 'ppm'),
    'gyroscope.g_sensitivity': ('gyro G', DEG_H_RAD_S / G0_M_S2, 'deg/h/g'),
    'accelerometer.bias': ('accel bias', UG_M_S2, 'ug'),
    'accelerometer.scale_misalignment': ('accel Ka', PPM, 'ppm|urad'),
    'accelerometer.scale_asymmetry': ('accel asym', PPM, 'ppm'),
    'accelerometer.quadratic': ('accel quad', UG_M_S2 / G0_M_S2 ** 2, 'ug/g^2'),
    'accelerometer.size_effect': ('size effect', MM, 'mm'),
}
