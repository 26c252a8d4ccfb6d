"""The one registry of the calibration parameters (issue 14 item 5).

Two levels, both in fixed order:

- :data:`PARAMETERS`, the nine CONTRACT 4 parameters in the calibration file's order: key,
  :class:`~.sensor_model.SensorErrors` field, symbol (``Kg``, ``qa``...), short label, shape
  and the free entries in the order of the 45-vector (:meth:`SensorErrors.as_vector`).
- :data:`GROUPS`, the groups the filter estimates and a grade states a prior for: the
  entries of one parameter that share a unit and a prior (``gyro_scale`` is the diagonal of
  Kg, ``gyro_misalignment`` its upper triangle), then the auxiliary states (time offset,
  sampling kernel, lever arm, mounting). Each has its engineering unit (SI value and name),
  its side (gyro or accelerometer parameter vector of the filter,
  :mod:`.estimator.error_model`), the
  :class:`~.imu_grade.ErrorSigmas` field that gives its grade prior, and the raw and coarse
  priors of :mod:`.estimator.priors`. The filter's parameter vectors (theta) are the groups
  of each side in this order.

Every other ordering, unit table and grade-to-sigma map derives from these two tables:
``sensor_model`` (the 45-vector), ``units`` (display units), ``param_table`` and the report,
``estimator.error_model`` (theta and the state groups), ``estimator.priors`` and
``estimator.result``, the SRT's 24 parameters and its consider terms. The world oracle
(``testing.world_cases``) keeps its own tables, written from CONTRACT alone; a test checks
that they agree with these (test_parameters.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from .imu_grade import ErrorSigmas, ImuGrade

FloatArray = NDArray[np.float64]
Index = tuple[int, ...]

#: standard gravity: the "g" of ug and deg/h/g (a unit, not the site's gravity)
G0_M_S2 = 9.80665
DEG_H_RAD_S = math.pi / 180.0 / 3600.0  # rad/s per deg/h
PPM = 1e-6
URAD = 1e-6
UG_M_S2 = 1e-6 * G0_M_S2
MM = 1e-3
US = 1e-6

#: raw prior of a gyro's g-sensitivity: 0.1 (deg/s)/g, consumer MEMS parts' datasheet values
#: (0.01-0.1; the world's MEMS units draw from that range). Written as 1.8e-5 until session 14,
#: a tenth of this: a short plan that left G to its prior ended it 7-10 sigma off, silently
RAW_G_SENSITIVITY = 0.1 * math.pi / 180.0 / G0_M_S2

AXES = 'xyz'
VECTOR: tuple[Index, ...] = ((0,), (1,), (2,))
DIAGONAL: tuple[Index, ...] = ((0, 0), (1, 1), (2, 2))
#: the distinct off-diagonal pairs of a symmetric matrix (Kg[j][i] = Kg[i][j])
UPPER: tuple[Index, ...] = ((0, 1), (0, 2), (1, 2))
#: the six off-diagonal entries, row-major (Ka's misalignments, the size effect's r_i[j])
OFF_DIAGONAL: tuple[Index, ...] = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))
FULL: tuple[Index, ...] = tuple((i, j) for i in range(3) for j in range(3))


def axes_name(idx: Index) -> str:
    """``'x'`` or ``'xy'``."""
    return ''.join(AXES[i] for i in idx)


@dataclass(frozen=True)
class Parameter:
    """One CONTRACT 4 parameter.

    ``entries`` are its free entries in the 45-vector's order (a symmetric matrix lists its
    upper triangle only; the size effect's zero diagonal is no entry).
    """

    key: str  # dotted CONTRACT 4 key below imu_calibration
    field: str  # SensorErrors field
    symbol: str  # Savage/Kozlov symbol: entry names are f'{symbol}_{axes}'
    label: str  # short label for people
    shape: Index
    entries: tuple[Index, ...]
    symmetric: bool = False

    @property
    def section(self) -> str:
        """``'gyroscope'`` or ``'accelerometer'``."""
        return self.key.split('.')[0]

    @property
    def leaf(self) -> str:
        """The key below the section, e.g. ``'scale_misalignment'``."""
        return self.key.split('.')[1]

    @property
    def is_matrix(self) -> bool:
        """A 3x3 parameter."""
        return len(self.shape) == 2

    def symbol_name(self, idx: Index) -> str:
        """``'Kg_xy'``: the name of one entry in the methods' extras (SRT, consider terms)."""
        return f'{self.symbol}_{axes_name(idx)}'

    def entry_name(self, idx: Index) -> str:
        """``'gyroscope.scale_misalignment[xy]'`` (:data:`~.sensor_model.PARAMETER_NAMES`)."""
        return f'{self.key}[{axes_name(idx)}]'

    def canonical(self, idx: Index) -> Index | None:
        """The free entry that ``idx`` is (the mirror of a symmetric lower entry); None for a
        structural entry (the size effect's diagonal)."""
        idx = tuple(idx)
        if idx in self.entries:
            return idx
        if self.symmetric and idx[::-1] in self.entries:
            return idx[::-1]
        return None


@dataclass(frozen=True)
class Group:
    """One group of filter states and grade priors (module docstring).

    ``entries`` index the parameter ``key`` (in theta order); an auxiliary state (no ``key``)
    lists its components. ``si_per_unit`` is the SI value of one ``unit``; ``side`` is ``'g'``
    (gyro parameter vector), ``'a'`` (accelerometer vector) or ``''`` (measurement-only).
    """

    name: str
    key: str | None
    entries: tuple[Index, ...]
    si_per_unit: float
    unit: str
    side: str
    grade_field: str | None = None  # ErrorSigmas field of the grade prior
    raw_prior: float | None = None  # SI sigma of an uncalibrated unit (estimator.priors)
    coarse_floor: float | None = None  # least SI sigma around a coarse value

    @property
    def size(self) -> int:
        """Number of states."""
        return len(self.entries)

    def entry_name(self, k: int) -> str:
        """``'x'`` or ``'xy'``: entry ``k`` of the group for people (vectors and scale
        factors, the diagonal groups: one axis letter; other matrix entries: row, column)."""
        idx = self.entries[k]
        if self.entries == DIAGONAL:
            return AXES[idx[0]]
        return axes_name(idx)


PARAMETERS: tuple[Parameter, ...] = (
    Parameter('gyroscope.bias', 'gyro_bias_rad_s', 'bg', 'gyro bias', (3,), VECTOR),
    Parameter('gyroscope.scale_misalignment', 'gyro_scale_misalignment', 'Kg', 'gyro Kg',
              (3, 3), DIAGONAL + UPPER, symmetric=True),
    Parameter('gyroscope.scale_asymmetry', 'gyro_scale_asymmetry', 'ag', 'gyro asym', (3,),
              VECTOR),
    Parameter('gyroscope.g_sensitivity', 'gyro_g_sensitivity_rad_s_per_m_s2', 'G', 'gyro G',
              (3, 3), FULL),
    Parameter('accelerometer.bias', 'accel_bias_m_s2', 'ba', 'accel bias', (3,), VECTOR),
    Parameter('accelerometer.scale_misalignment', 'accel_scale_misalignment', 'Ka', 'accel Ka',
              (3, 3), FULL),
    Parameter('accelerometer.scale_asymmetry', 'accel_scale_asymmetry', 'aa', 'accel asym',
              (3,), VECTOR),
    Parameter('accelerometer.quadratic', 'accel_quadratic_per_m_s2', 'qa', 'accel quad', (3,),
              VECTOR),
    Parameter('accelerometer.size_effect', 'size_effect_m', 'r', 'size effect', (3, 3),
              OFF_DIAGONAL),
)

_KG, _KA = 'gyroscope.scale_misalignment', 'accelerometer.scale_misalignment'
GROUPS: tuple[Group, ...] = (
    Group('gyro_bias', 'gyroscope.bias', VECTOR, DEG_H_RAD_S, 'deg/h', 'g',
          'gyro_bias_rad_s', 1.75e-2, 4.8e-9),
    Group('gyro_scale', _KG, DIAGONAL, PPM, 'ppm', 'g', 'gyro_scale', 3e-2, 1e-5),
    Group('gyro_asymmetry', 'gyroscope.scale_asymmetry', VECTOR, PPM, 'ppm', 'g',
          'gyro_asymmetry', 3e-3, 1e-5),
    Group('gyro_misalignment', _KG, UPPER, URAD, 'urad', 'g', 'gyro_misalignment_rad', 3e-2,
          1e-5),
    Group('gyro_g_sensitivity', 'gyroscope.g_sensitivity', FULL, DEG_H_RAD_S / G0_M_S2,
          'deg/h/g', 'g', 'gyro_g_sensitivity', RAW_G_SENSITIVITY, 1e-8),
    Group('accel_bias', 'accelerometer.bias', VECTOR, UG_M_S2, 'ug', 'a', 'accel_bias_m_s2',
          1.0, 1e-3),
    Group('accel_scale', _KA, DIAGONAL, PPM, 'ppm', 'a', 'accel_scale', 3e-2, 2e-4),
    Group('accel_asymmetry', 'accelerometer.scale_asymmetry', VECTOR, PPM, 'ppm', 'a',
          'accel_asymmetry', 3e-3, 3e-3),
    Group('accel_misalignment', _KA, OFF_DIAGONAL, URAD, 'urad', 'a',
          'accel_misalignment_rad', 3e-2, 2e-4),
    # ug/g^2 = ppm/g: 1e-6 / g0 per m/s^2
    Group('accel_quadratic', 'accelerometer.quadratic', VECTOR, PPM / G0_M_S2, 'ug/g^2', 'a',
          'accel_quadratic', 1e-4, 1e-4),
    Group('size_effect', 'accelerometer.size_effect', OFF_DIAGONAL, MM, 'mm', 'a',
          'size_effect_m', 2e-2, 2e-2),
    # auxiliary states: accel-minus-gyro time offset, the gyros' and the accelerometers'
    # sampling kernels (0: interval means, 1: point samples;
    # estimator.error_model.sample_kernel_column), fixture lever arm, IMU mounting
    Group('time_offset', None, ((0,),), US, 'us', 'a'),
    Group('gyro_sample_kernel', None, ((0,),), 1.0, '1', 'g'),
    Group('accel_sample_kernel', None, ((0,),), 1.0, '1', 'a'),
    Group('lever_arm', None, VECTOR, MM, 'mm', ''),
    Group('mounting', None, VECTOR, URAD, 'urad', ''),
)

#: the CONTRACT 4 keys in the calibration file's order
PARAMETER_KEYS: tuple[str, ...] = tuple(p.key for p in PARAMETERS)
PARAMETER_OF_KEY: dict[str, Parameter] = {p.key: p for p in PARAMETERS}
PARAMETER_OF_FIELD: dict[str, Parameter] = {p.field: p for p in PARAMETERS}
GROUP_OF_NAME: dict[str, Group] = {g.name: g for g in GROUPS}
#: the groups of sensor errors (those of a CONTRACT 4 parameter), in state order
SENSOR_GROUPS: tuple[Group, ...] = tuple(g for g in GROUPS if g.key is not None)
#: CONTRACT 4 key -> the names of the groups that make it up, in state order
GROUPS_OF_KEY: dict[str, tuple[str, ...]] = {
    p.key: tuple(g.name for g in GROUPS if g.key == p.key) for p in PARAMETERS}


def parameter(key: str) -> Parameter:
    """The parameter of a CONTRACT 4 key (KeyError for an unknown one)."""
    return PARAMETER_OF_KEY[key]


def group(name: str) -> Group:
    """The group of that name (KeyError for an unknown one)."""
    return GROUP_OF_NAME[name]


def group_of_entry(key: str, idx: Index) -> Group | None:
    """The group that holds entry ``idx`` of parameter ``key`` (a symmetric lower entry: its
    mirror's); None for a structural entry."""
    free = parameter(key).canonical(idx)
    for g in SENSOR_GROUPS:
        if g.key == key and free in g.entries:
            return g
    return None


def display_group(key: str) -> Group:
    """The group whose unit names the whole parameter (the diagonal's for Kg and Ka)."""
    return GROUP_OF_NAME[GROUPS_OF_KEY[key][0]]


def element_unit(key: str, idx: Index) -> str:
    """The engineering unit of one entry ``idx`` of parameter ``key``: ``'ppm'`` on the
    diagonal of Kg, ``'urad'`` off it; a structural entry has the parameter's unit."""
    g = group_of_entry(key, idx)
    return (g if g is not None else display_group(key)).unit


def grade_group_sigmas(sigma: ErrorSigmas) -> dict[str, float]:
    """Group name -> one-sigma of an :class:`~.imu_grade.ErrorSigmas` (SI), for the sensor
    groups in state order."""
    return {g.name: float(getattr(sigma, g.grade_field)) for g in SENSOR_GROUPS
            if g.grade_field is not None}


def grade_sigmas(grade: ImuGrade | None) -> dict[str, FloatArray]:
    """Assumed one-sigma of every SensorErrors field from an ImuGrade, by field in CONTRACT 4
    order (zeros without a grade or without its ``sigma:`` block); a symmetric matrix has
    both halves, a structural entry 0."""
    s = getattr(grade, 'sigma', None)
    out: dict[str, FloatArray] = {}
    for p in PARAMETERS:
        a = np.zeros(p.shape)
        for g in SENSOR_GROUPS:
            if g.key != p.key:
                continue
            v = float(getattr(s, g.grade_field, 0.0)) if s is not None and g.grade_field else 0.0
            for idx in g.entries:
                a[idx] = v
                if p.symmetric:
                    a[idx[::-1]] = v
        out[p.field] = a
    return out


def entries_of(*keys: str) -> tuple[tuple[str, str, Index], ...]:
    """(symbol name, SensorErrors field, index) of the free entries of ``keys``, in that key
    order and each in 45-vector order (e.g. the SRT's 24 parameters)."""
    return tuple((p.symbol_name(idx), p.field, idx) for p in map(parameter, keys)
                 for idx in p.entries)
