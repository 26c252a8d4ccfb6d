"""The IMU sensor model of CONTRACT section 3, in both directions.

Gyroscopes, axis i::

    w_meas_i = omega_i + sum_j Kg[i][j] omega_j + ag_i |omega_i| + sum_j G[i][j] f_j + bg_i

Accelerometers, axis i (sensor i at the point r_i of the body, r_i[i] = 0)::

    f_i_at_ri = f_i + (omega_dot x r_i + omega x (omega x r_i))_i
    a_meas_i  = f_i_at_ri + sum_j Ka[i][j] f_j + aa_i |f_i| + qa_i f_i^2 + ba_i

The size-effect term is Kozlov & Kapralov, "Millimeter-level calibration of IMU size
effect", eq. 1; the gyro misalignment matrix Kg is symmetric by the definition of the body
frame (Savage, "Improved strapdown IMU calibration procedures", MARS frame:
kappa_ij = kappa_ji). :func:`measure` is the forward model (noise-free, instantaneous);
:func:`compensate` its exact inverse.

The fixed order of the 45 free parameters (:meth:`SensorErrors.as_vector`,
:data:`PARAMETER_NAMES`, :data:`PARAMETER_SLICES`; from the registry, :mod:`.parameters`)::

    0:3    gyroscope.bias                  bg (x, y, z)                 [rad/s]
    3:9    gyroscope.scale_misalignment    Kg xx, yy, zz, xy, xz, yz    (Kg[j][i] = Kg[i][j])
    9:12   gyroscope.scale_asymmetry       ag (x, y, z)
    12:21  gyroscope.g_sensitivity         G row-major                  [(rad/s)/(m/s^2)]
    21:24  accelerometer.bias              ba (x, y, z)                 [m/s^2]
    24:33  accelerometer.scale_misalignment Ka row-major
    33:36  accelerometer.scale_asymmetry   aa (x, y, z)
    36:39  accelerometer.quadratic         qa (x, y, z)                 [1/(m/s^2)]
    39:45  accelerometer.size_effect       r_xy, r_xz, r_yx, r_yz, r_zx, r_zy  [m]
"""
from __future__ import annotations

import dataclasses
import math
import weakref
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import parameters as registry
from .config import require_mapping
from .errors import ConfigError
from .types import GAP_PERIODS, sample_intervals_ns

FloatArray = NDArray[np.float64]

#: |Kg - Kg^T| above this is not symmetric (CONTRACT 3: symmetry is the definition).
SYMMETRY_TOLERANCE = 1e-12

#: Upper-triangle index pairs of Kg in vector order.
KG_PAIRS: tuple[tuple[int, ...], ...] = registry.parameter(
    'gyroscope.scale_misalignment').entries
#: Off-diagonal size-effect index pairs (row i = r_i, component j) in vector order.
SIZE_EFFECT_PAIRS: tuple[tuple[int, ...], ...] = registry.OFF_DIAGONAL

# (dotted CONTRACT 4 key, dataclass field, shape, index pairs or None for a vector): the
# registry's parameters (core/parameters.py), in its order
_LAYOUT: tuple[tuple[str, str, tuple[int, ...], tuple[tuple[int, ...], ...] | None], ...] = \
    tuple((p.key, p.field, p.shape, p.entries if p.is_matrix else None)
          for p in registry.PARAMETERS)

#: The CONTRACT section 4 keys (dotted, below ``imu_calibration``), in vector order.
PARAMETER_KEYS: tuple[str, ...] = registry.PARAMETER_KEYS
#: Dotted key -> dataclass field name.
FIELD_OF_KEY: dict[str, str] = {k: f for k, f, *_ in _LAYOUT}
#: SensorErrors field -> dotted CONTRACT 4 key (the inverse of FIELD_OF_KEY)
KEY_OF_FIELD: dict[str, str] = {f: k for k, f, *_ in _LAYOUT}


def _build_index() -> tuple[dict[str, slice], tuple[str, ...]]:
    slices: dict[str, slice] = {}
    names: list[str] = []
    for p in registry.PARAMETERS:
        slices[p.key] = slice(len(names), len(names) + len(p.entries))
        names += [p.entry_name(idx) for idx in p.entries]
    return slices, tuple(names)


#: Dotted key -> slice of :meth:`SensorErrors.as_vector`.
#: Names of the 45 vector entries, e.g. ``'gyroscope.scale_misalignment[xy]'``.
PARAMETER_SLICES, PARAMETER_NAMES = _build_index()
#: Length of :meth:`SensorErrors.as_vector`.
N_PARAMETERS = len(PARAMETER_NAMES)


class ImplausibleErrors(ArithmeticError):
    """:func:`compensate` did not converge: the sensor errors cannot describe a real unit
    (e.g. a scale factor near -100 %, where the output no longer depends on the input). The
    estimator treats it as a divergence of its working point."""


@dataclass(frozen=True, eq=False)
class SensorErrors:
    """Constant IMU errors (CONTRACT 3); all fields numpy arrays, read-only after creation.

    Raises ``ValueError`` on a wrong shape, a non-finite value, an asymmetric ``Kg``
    (beyond :data:`SYMMETRY_TOLERANCE`) or a non-zero size-effect diagonal.
    """

    gyro_bias_rad_s: FloatArray  # (3,) bg
    gyro_scale_misalignment: FloatArray  # (3, 3) Kg, symmetric
    gyro_scale_asymmetry: FloatArray  # (3,) ag
    gyro_g_sensitivity_rad_s_per_m_s2: FloatArray  # (3, 3) G
    accel_bias_m_s2: FloatArray  # (3,) ba
    accel_scale_misalignment: FloatArray  # (3, 3) Ka
    accel_scale_asymmetry: FloatArray  # (3,) aa
    accel_quadratic_per_m_s2: FloatArray  # (3,) qa
    size_effect_m: FloatArray  # (3, 3) row i = r_i, zero diagonal

    def __post_init__(self) -> None:
        arrays = []
        for key, name, shape, _ in _LAYOUT:
            a = np.array(getattr(self, name), dtype=float)
            if a.shape != shape:
                raise ValueError(f'{name} ({key}) must have shape {shape}, got {a.shape}')
            arrays.append(a)
        # one test for all (the estimator builds an instance after every block), then which
        finite = np.isfinite(np.concatenate([a.ravel() for a in arrays])).all()
        for (key, name, _, _), a in zip(_LAYOUT, arrays, strict=True):
            if not finite and not np.isfinite(a).all():
                raise ValueError(f'{name} ({key}) has non-finite values')
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        kg = self.gyro_scale_misalignment
        if abs(kg - kg.T).max() > SYMMETRY_TOLERANCE:
            raise ValueError('gyro_scale_misalignment (Kg) must be symmetric (CONTRACT 3)')
        if self.size_effect_m.diagonal().any():
            raise ValueError('size_effect_m must have a zero diagonal (r_i[i] = 0)')

    # ------------------------------------------------------------------ construction
    @classmethod
    def zeros(cls) -> 'SensorErrors':
        """An error-free IMU."""
        return cls.from_vector(np.zeros(N_PARAMETERS))

    @classmethod
    def from_vector(cls, x: ArrayLike) -> 'SensorErrors':
        """Inverse of :meth:`as_vector` (order in the module docstring)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (N_PARAMETERS,):
            raise ValueError(f'expected a vector of {N_PARAMETERS}, got shape {x.shape}')
        kwargs: dict[str, FloatArray] = {}
        for key, name, shape, pairs in _LAYOUT:
            seg = x[PARAMETER_SLICES[key]]
            if pairs is None:
                kwargs[name] = seg.copy()
                continue
            m = np.zeros(shape)
            for v, idx in zip(seg, pairs):
                m[idx] = v
            if registry.parameter(key).symmetric:
                m = np.triu(m) + np.triu(m, 1).T
            kwargs[name] = m
        return cls(**kwargs)

    def as_vector(self) -> FloatArray:
        """All 45 free parameters in the fixed order of the module docstring."""
        out = np.empty(N_PARAMETERS)
        for key, name, _, pairs in _LAYOUT:
            a = getattr(self, name)
            sl = PARAMETER_SLICES[key]
            out[sl] = a if pairs is None else [a[idx] for idx in pairs]
        return out

    def get(self, key: str) -> FloatArray:
        """The array of a dotted CONTRACT 4 key, e.g. ``'gyroscope.bias'``."""
        return getattr(self, FIELD_OF_KEY[key])  # type: ignore[no-any-return]

    def replace(self, **changes: Any) -> 'SensorErrors':
        """A copy with some fields changed (by field name)."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ CONTRACT 4 mapping
    def to_dict(self) -> dict[str, dict[str, Any]]:
        """``{'gyroscope': {...}, 'accelerometer': {...}}`` with plain Python floats/lists."""
        out: dict[str, dict[str, Any]] = {'gyroscope': {}, 'accelerometer': {}}
        for key, name, _, _ in _LAYOUT:
            group, leaf = key.split('.')
            out[group][leaf] = getattr(self, name).tolist()
        return out

    @classmethod
    def from_dict(cls, data: Any, source: str | None = None, prefix: str = '',
                  nonnegative: bool = False) -> 'SensorErrors':
        """Validate a ``{'gyroscope': {...}, 'accelerometer': {...}}`` mapping (CONTRACT 4).

        Parameters
        ----------
        data : mapping
        source : str, optional
            File name for messages.
        prefix : str
            Dotted key of ``data`` inside the file (e.g. ``'imu_calibration.sigma'``).
        nonnegative : bool
            Refuse negative values (for one-sigma uncertainties).

        Raises
        ------
        ConfigError
            Unknown or missing key, wrong shape, non-number, NaN/inf, asymmetric Kg,
            non-zero size-effect diagonal, negative sigma; names ``source`` and the key.
        """
        def full(k: str) -> str:
            return f'{prefix}.{k}' if prefix else k

        d = require_mapping(data, source, prefix or None)
        groups = ('gyroscope', 'accelerometer')
        for g in d:
            if g not in groups:
                raise ConfigError(f'unknown key (known keys: {", ".join(groups)})', source,
                                  full(str(g)))
        kwargs: dict[str, FloatArray] = {}
        for g in groups:
            if g not in d:
                raise ConfigError('missing required key', source, full(g))
            gd = require_mapping(d[g], source, full(g))
            leaves = [k.split('.')[1] for k in PARAMETER_KEYS if k.startswith(g + '.')]
            for leaf in gd:
                if leaf not in leaves:
                    raise ConfigError(f'unknown key (known keys: {", ".join(leaves)})', source,
                                      full(f'{g}.{leaf}'))
            for leaf in leaves:
                key = f'{g}.{leaf}'
                if leaf not in gd:
                    raise ConfigError('missing required key', source, full(key))
                _, name, shape, _ = _LAYOUT[PARAMETER_KEYS.index(key)]
                kwargs[name] = _array(gd[leaf], shape, source, full(key), nonnegative)
        kg = kwargs['gyro_scale_misalignment']
        asym = float(np.max(np.abs(kg - kg.T)))
        if asym > SYMMETRY_TOLERANCE:
            raise ConfigError(f'must be symmetric (CONTRACT 3), |Kg - Kg^T| = {asym:.3g}',
                              source, full('gyroscope.scale_misalignment'))
        if np.any(np.diag(kwargs['size_effect_m']) != 0.0):
            raise ConfigError('the diagonal must be zero (r_i[i] = 0, CONTRACT 3)', source,
                              full('accelerometer.size_effect'))
        return cls(**kwargs)


def _array(value: Any, shape: tuple[int, ...], source: str | None, key: str,
           nonnegative: bool) -> FloatArray:
    """A nested list of finite numbers of exactly ``shape``."""
    def bad(what: str) -> ConfigError:
        want = 'a list of 3 numbers' if len(shape) == 1 else 'a 3x3 matrix (list of 3 rows)'
        return ConfigError(f'expected {want}, {what}', source, key)

    rows = [value] if len(shape) == 1 else value
    if not isinstance(rows, list) or len(rows) != (1 if len(shape) == 1 else shape[0]):
        raise bad(f'got {value!r}')
    for r in rows:
        if not isinstance(r, list) or len(r) != shape[-1]:
            raise bad(f'got {value!r}')
        for v in r:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise bad(f'got {v!r}')
            if not math.isfinite(v):
                raise ConfigError(f'value {v!r} is not finite', source, key)
            if nonnegative and v < 0:
                raise ConfigError(f'a standard deviation cannot be negative ({v!r})', source,
                                  key)
    return np.array(value, dtype=float)


# ----------------------------------------------------------------------------- the model
def size_effect_term(size_effect_m: ArrayLike, omega_rad_s: ArrayLike,
                     omega_dot_rad_s2: ArrayLike) -> FloatArray:
    """``(omega_dot x r_i + omega x (omega x r_i))_i`` for i = x, y, z (Kozlov eq. 1).

    Parameters
    ----------
    size_effect_m : (3, 3)
        Row i = r_i, the position of accelerometer i relative to the reference point.
    omega_rad_s, omega_dot_rad_s2 : (..., 3)
        Body rate relative to inertial space and its time derivative, body frame.

    Returns
    -------
    ndarray, shape (..., 3)
        What accelerometer i senses beyond the specific force at the reference point.
    """
    r = np.asarray(size_effect_m, dtype=float)
    w = np.asarray(omega_rad_s, dtype=float)
    wd = np.asarray(omega_dot_rad_s2, dtype=float)
    w2 = np.einsum('...j,...j->...', w, w)
    out = np.empty(np.broadcast_shapes(w.shape, wd.shape))
    for i in range(3):
        # omega x (omega x r) = omega (omega . r) - r |omega|^2
        centripetal = w[..., i] * (w @ r[i]) - r[i, i] * w2
        out[..., i] = np.cross(wd, r[i])[..., i] + centripetal
    return out


def measure(errors: SensorErrors, omega_ib_imu_rad_s: ArrayLike,
            omega_dot_ib_imu_rad_s2: ArrayLike,
            f_imu_m_s2: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Instantaneous noise-free sensor outputs from the true motion (CONTRACT 3).

    Parameters
    ----------
    errors : SensorErrors
    omega_ib_imu_rad_s, omega_dot_ib_imu_rad_s2, f_imu_m_s2 : (..., 3)
        True body rate, its derivative, and specific force at the reference point.

    Returns
    -------
    gyro_rad_s, accel_m_s2 : ndarray, shape (..., 3)
    """
    w = np.asarray(omega_ib_imu_rad_s, dtype=float)
    f = np.asarray(f_imu_m_s2, dtype=float)
    e = errors
    gyro = (w + w @ e.gyro_scale_misalignment.T + e.gyro_scale_asymmetry * np.abs(w)
            + f @ e.gyro_g_sensitivity_rad_s_per_m_s2.T + e.gyro_bias_rad_s)
    accel = (f + size_effect_term(e.size_effect_m, w, omega_dot_ib_imu_rad_s2)
             + f @ e.accel_scale_misalignment.T + e.accel_scale_asymmetry * np.abs(f)
             + e.accel_quadratic_per_m_s2 * f * f + e.accel_bias_m_s2)
    return gyro, accel


def mean_rate_derivative(stamps_ns: ArrayLike, gyro_rad_s: ArrayLike,
                         causal: bool = False,
                         nominal_period_s: float | None = None) -> FloatArray:
    """Angular acceleration estimated from mean-over-interval rates (CONTRACT 1 samples).

    Sample k is the mean rate over (t_{k-1}, t_k]; the mean of omega_dot over that
    interval is (omega(t_k) - omega(t_{k-1})) / dt, which the difference of neighbouring
    mean rates estimates. ``causal=False``: second-order central differences on the
    (possibly uneven) stamps, second-order one-sided at both ends (:func:`numpy.gradient`).
    ``causal=True``: backward difference (mean rate k minus mean rate k-1, over
    ``(t_k - t_{k-1})`` from the int64 stamps), which refers to the time half a sample
    earlier, and zero at the first sample of each stretch: only past samples, what a live
    node can compute (``core.stream_compensation.StreamCompensation`` does this per sample,
    same bits).
    Never across a gap (CONTRACT 1, :func:`~.types.sample_intervals_ns`, gaps judged
    against ``nominal_period_s`` or, if None, the median interval): each stretch between
    gaps is differentiated on its own (central: one-sided at its ends, zero for a lone
    sample).

    Parameters
    ----------
    stamps_ns : (N,) int
        Strictly increasing stamps [ns].
    gyro_rad_s : (N, 3)
        Mean rates (already compensated, for the size effect).

    Returns
    -------
    ndarray, shape (N, 3) [rad/s^2]
    """
    stamps = np.asarray(stamps_ns)
    w = np.asarray(gyro_rad_s, dtype=float)
    if stamps.ndim != 1 or w.shape != (stamps.shape[0], 3):
        raise ValueError(f'stamps (N,) and rates (N, 3) expected, got {stamps.shape} '
                         f'and {w.shape}')
    n = stamps.shape[0]
    if n < 2:
        return np.zeros_like(w)
    t_s = (stamps - stamps[0]).astype(float) * 1e-9
    dt = np.diff(t_s)
    if np.any(dt <= 0):
        raise ValueError('stamps must be strictly increasing')
    if causal:
        # the live node's comparison, in seconds (core.stream_compensation.StreamCompensation):
        # the same decision at an interval of exactly GAP_PERIODS periods
        d = np.zeros_like(w)
        dt_s = np.diff(stamps.astype(np.int64)).astype(np.float64) * 1e-9
        period_s = (float(np.median(dt_s)) if nominal_period_s is None
                    else float(nominal_period_s))
        ok = dt_s <= GAP_PERIODS * period_s
        d[1:][ok] = (w[1:][ok] - w[:-1][ok]) / dt_s[ok, None]
        return d
    is_gap = sample_intervals_ns(
        stamps, None if nominal_period_s is None else nominal_period_s * 1e9)[1]
    out = np.empty_like(w)
    # stretches between gaps; a Python loop over them (gaps are rare in a recording)
    for seg in np.split(np.arange(n), np.flatnonzero(is_gap)):
        if seg.size < 2:
            out[seg] = 0.0
        else:
            out[seg] = np.gradient(w[seg], t_s[seg], axis=0,
                                   edge_order=2 if seg.size > 2 else 1)
    return out


# ----------------------------------------------------------------------------- compensation
@dataclass(frozen=True)
class _Inverse:
    """Per-``SensorErrors`` constants of :func:`compensate` as Python floats (row-major)."""

    inv_g: tuple[float, ...]  # (I + Kg)^-1, 9
    inv_a: tuple[float, ...]  # (I + Ka)^-1, 9
    bg: tuple[float, ...]
    ba: tuple[float, ...]
    G: tuple[float, ...]  # 9
    ag: tuple[float, ...]
    aa: tuple[float, ...]
    qa: tuple[float, ...]
    r: tuple[float, ...]  # 9, row i = r_i
    has_size: bool

    def columns(self) -> '_Columns':
        """The same constants as (3, 1) columns for :func:`_step_rows` (cached)."""
        cols = _COLUMNS.get(self)
        if cols is None:
            def col(x: tuple[float, ...], *idx: int) -> FloatArray:
                return np.array([x[i] for i in idx], float)[:, None]
            G, ig, ia, r = self.G, self.inv_g, self.inv_a, self.r
            cols = _COLUMNS[self] = _Columns(
                bg=col(self.bg, 0, 1, 2), ba=col(self.ba, 0, 1, 2),
                G=(col(G, 0, 3, 6), col(G, 1, 4, 7), col(G, 2, 5, 8)),
                ig=(col(ig, 0, 3, 6), col(ig, 1, 4, 7), col(ig, 2, 5, 8)),
                ia=(col(ia, 0, 3, 6), col(ia, 1, 4, 7), col(ia, 2, 5, 8)),
                ag=col(self.ag, 0, 1, 2), aa=col(self.aa, 0, 1, 2), qa=col(self.qa, 0, 1, 2),
                r=(col(r, 0, 3, 6), col(r, 1, 4, 7), col(r, 2, 5, 8)),
                r_plus=col(r, 2, 3, 7), r_minus=col(r, 1, 5, 6))
        return cols


@dataclass(frozen=True)
class _Columns:
    """:class:`_Inverse` as (3, 1) columns: row ``i`` holds what :func:`_step` uses for
    component ``i`` (``G[k]``: the coefficients of ``f_k``, ``r_plus``/``r_minus``: those of
    the size effect's ``omega_dot`` terms)."""

    bg: FloatArray
    ba: FloatArray
    G: tuple[FloatArray, FloatArray, FloatArray]
    ig: tuple[FloatArray, FloatArray, FloatArray]
    ia: tuple[FloatArray, FloatArray, FloatArray]
    ag: FloatArray
    aa: FloatArray
    qa: FloatArray
    r: tuple[FloatArray, FloatArray, FloatArray]
    r_plus: FloatArray
    r_minus: FloatArray


_INVERSES: 'weakref.WeakKeyDictionary[SensorErrors, _Inverse]' = weakref.WeakKeyDictionary()
_COLUMNS: 'weakref.WeakKeyDictionary[_Inverse, _Columns]' = weakref.WeakKeyDictionary()


def _inverse(e: SensorErrors) -> _Inverse:
    """The constants of ``e`` for :func:`compensate`, computed once per (immutable) object."""
    c = _INVERSES.get(e)
    if c is None:
        def t(a: ArrayLike) -> tuple[float, ...]:
            return tuple(float(x) for x in np.ravel(a))
        c = _Inverse(t(np.linalg.inv(np.eye(3) + e.gyro_scale_misalignment)),
                     t(np.linalg.inv(np.eye(3) + e.accel_scale_misalignment)),
                     t(e.gyro_bias_rad_s), t(e.accel_bias_m_s2),
                     t(e.gyro_g_sensitivity_rad_s_per_m_s2), t(e.gyro_scale_asymmetry),
                     t(e.accel_scale_asymmetry), t(e.accel_quadratic_per_m_s2),
                     t(e.size_effect_m), bool(np.any(e.size_effect_m != 0.0)))
        _INVERSES[e] = c
    return c


def _step(c: _Inverse, wm: tuple[Any, Any, Any], am: tuple[Any, Any, Any],
          w: tuple[Any, Any, Any], f: tuple[Any, Any, Any],
          wd: tuple[Any, Any, Any] | None) -> tuple[tuple[Any, Any, Any], tuple[Any, Any, Any]]:
    """One fixed-point step of :func:`compensate` on components (floats or equal-shape arrays).

    Written with explicit component arithmetic (no matmul/cross): each output element then
    depends only on its own row, with the same IEEE operations for a Python float and for a
    numpy column, so one sample alone and the same sample inside a batch give the same bits.
    ``wm``/``am`` are the raw outputs minus the biases; ``wd`` is omega_dot (None: no size
    effect term).
    """
    G, ig, ia = c.G, c.inv_g, c.inv_a
    fx, fy, fz = f
    # omega <- (I + Kg)^-1 (w_meas - bg - G f - ag |omega|)        (CONTRACT 3, gyro)
    ux = wm[0] - (G[0] * fx + G[1] * fy + G[2] * fz) - c.ag[0] * abs(w[0])
    uy = wm[1] - (G[3] * fx + G[4] * fy + G[5] * fz) - c.ag[1] * abs(w[1])
    uz = wm[2] - (G[6] * fx + G[7] * fy + G[8] * fz) - c.ag[2] * abs(w[2])
    wx = ig[0] * ux + ig[1] * uy + ig[2] * uz
    wy = ig[3] * ux + ig[4] * uy + ig[5] * uz
    wz = ig[6] * ux + ig[7] * uy + ig[8] * uz
    vx, vy, vz = am
    if wd is not None:
        # size effect (Kozlov & Kapralov eq. 1): s_i = (wd x r_i)_i + w_i (w . r_i), r_ii = 0
        r = c.r
        vx = vx - ((wd[1] * r[2] - wd[2] * r[1]) + wx * (wx * r[0] + wy * r[1] + wz * r[2]))
        vy = vy - ((wd[2] * r[3] - wd[0] * r[5]) + wy * (wx * r[3] + wy * r[4] + wz * r[5]))
        vz = vz - ((wd[0] * r[7] - wd[1] * r[6]) + wz * (wx * r[6] + wy * r[7] + wz * r[8]))
    # f <- (I + Ka)^-1 (a_meas - ba - s - aa |f| - qa f^2)          (CONTRACT 3, accel)
    vx = vx - c.aa[0] * abs(fx) - c.qa[0] * fx * fx
    vy = vy - c.aa[1] * abs(fy) - c.qa[1] * fy * fy
    vz = vz - c.aa[2] * abs(fz) - c.qa[2] * fz * fz
    return ((wx, wy, wz),
            (ia[0] * vx + ia[1] * vy + ia[2] * vz, ia[3] * vx + ia[4] * vy + ia[5] * vz,
             ia[6] * vx + ia[7] * vy + ia[8] * vz))


def _size_omega_dot(k: _Columns, wd: FloatArray) -> FloatArray:
    """The ``omega_dot`` part of the size effect, ``(wd x r_i)_i`` per component, of (3, N)
    rows: :func:`_step`'s ``wd[1] r[2] - wd[2] r[1]``, ``wd[2] r[3] - wd[0] r[5]``,
    ``wd[0] r[7] - wd[1] r[6]`` (the same operations)."""
    return wd[[1, 2, 0]] * k.r_plus - wd[[2, 0, 1]] * k.r_minus


def _step_rows(k: _Columns, wm: FloatArray, am: FloatArray, w: FloatArray, f: FloatArray,
               size_wd: FloatArray | None) -> tuple[FloatArray, FloatArray]:
    """:func:`_step` on (3, N) arrays (row = component): each element sees the same IEEE
    operations in the same order as :func:`_step` on its components, so the same bits, in a
    third of the numpy calls. ``size_wd``: :func:`_size_omega_dot` of omega_dot, or None (no
    size effect term)."""
    G, ig, ia = k.G, k.ig, k.ia
    u = wm - (G[0] * f[0] + G[1] * f[1] + G[2] * f[2]) - k.ag * abs(w)
    w_new = ig[0] * u[0] + ig[1] * u[1] + ig[2] * u[2]
    v = am
    if size_wd is not None:
        r = k.r
        v = v - (size_wd + w_new * (w_new[0] * r[0] + w_new[1] * r[1] + w_new[2] * r[2]))
    v = v - k.aa * abs(f) - k.qa * f * f
    return w_new, ia[0] * v[0] + ia[1] * v[1] + ia[2] * v[2]


def _start(c: _Inverse, wm: tuple[Any, Any, Any],
           am: tuple[Any, Any, Any]) -> tuple[tuple[Any, Any, Any], tuple[Any, Any, Any]]:
    """Linear first guess ``(I + Kg)^-1 wm``, ``(I + Ka)^-1 am`` (component arithmetic)."""
    ig, ia = c.inv_g, c.inv_a
    return ((ig[0] * wm[0] + ig[1] * wm[1] + ig[2] * wm[2],
             ig[3] * wm[0] + ig[4] * wm[1] + ig[5] * wm[2],
             ig[6] * wm[0] + ig[7] * wm[1] + ig[8] * wm[2]),
            (ia[0] * am[0] + ia[1] * am[1] + ia[2] * am[2],
             ia[3] * am[0] + ia[4] * am[1] + ia[5] * am[2],
             ia[6] * am[0] + ia[7] * am[1] + ia[8] * am[2]))


#: Relative change at which the iteration has converged (a few ulps).
_TINY = 4.0 * float(np.finfo(float).eps)


def _compensate_one(c: _Inverse, wm_raw: Sequence[float], am_raw: Sequence[float],
                    wd: Sequence[float] | None,
                    max_iterations: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """One sample in pure Python floats (~20x faster than numpy on (1, 3) arrays).

    Same operations and per-row stopping rule as :func:`_compensate_rows`, hence the same
    bits. Non-finite input gives non-finite output (no exception).
    """
    wm = (wm_raw[0] - c.bg[0], wm_raw[1] - c.bg[1], wm_raw[2] - c.bg[2])
    am = (am_raw[0] - c.ba[0], am_raw[1] - c.ba[1], am_raw[2] - c.ba[2])
    w, f = _start(c, wm, am)
    w_scale = max(abs(w[0]), abs(w[1]), abs(w[2]), 1e-12)
    f_scale = max(abs(f[0]), abs(f[1]), abs(f[2]), 1e-9)
    if not (math.isfinite(w_scale) and math.isfinite(f_scale)
            and (wd is None or math.isfinite(wd[0] + wd[1] + wd[2]))):
        return (math.nan,) * 3, (math.nan,) * 3
    last = math.inf
    stalled = 0
    for _ in range(max_iterations):
        w_new, f_new = _step(c, wm, am, w, f, wd)  # type: ignore[arg-type] # wd: 3 floats
        change = max(max(abs(w_new[0] - w[0]), abs(w_new[1] - w[1]), abs(w_new[2] - w[2]))
                     / w_scale,
                     max(abs(f_new[0] - f[0]), abs(f_new[1] - f[1]), abs(f_new[2] - f[2]))
                     / f_scale)
        w, f = w_new, f_new
        if change <= _TINY:
            return w, f
        # rounding can keep the last bit flickering: stop once the change no longer shrinks
        stalled = stalled + 1 if change >= last else 0
        if stalled >= 3 and change < 1e-12:
            return w, f
        last = change
    raise ImplausibleErrors(f'compensate did not converge in {max_iterations} iterations '
                            f'(last relative change {change:.3g}): implausible sensor errors')


def _compensate_rows(c: _Inverse, wm_raw: FloatArray, am_raw: FloatArray,
                     wd: FloatArray | None, stamps_ns: NDArray[np.int64] | None,
                     max_iterations: int) -> tuple[FloatArray, FloatArray]:
    """``(N, 3)`` rows with numpy columns; each row stops on its own criterion.

    ``stamps_ns`` given (and ``wd`` None): omega_dot is re-estimated from the current rates
    each step with :func:`mean_rate_derivative` (couples neighbouring rows).
    """
    bad = ~(np.all(np.isfinite(wm_raw), axis=1) & np.all(np.isfinite(am_raw), axis=1))
    if wd is not None:
        bad |= ~np.all(np.isfinite(wd), axis=1)
    if bad.any():  # iterate on zeros there (no warnings), NaN out at the end
        wm_raw, am_raw = (np.where(bad[:, None], 0.0, x) for x in (wm_raw, am_raw))
        wd = None if wd is None else np.where(bad[:, None], 0.0, wd)
    # (3, N): row i is component i, the arithmetic of _step/_start on whole rows
    k = c.columns()
    wm = wm_raw.T - k.bg
    am = am_raw.T - k.ba
    w = k.ig[0] * wm[0] + k.ig[1] * wm[1] + k.ig[2] * wm[2]
    f = k.ia[0] * am[0] + k.ia[1] * am[1] + k.ia[2] * am[2]
    w_scale = np.maximum(abs(w).max(axis=0), 1e-12)
    f_scale = np.maximum(abs(f).max(axis=0), 1e-9)
    active = ~bad
    last = np.full(w_scale.shape, np.inf)
    stalled = np.zeros(w_scale.shape, np.int64)
    size_wd = None if wd is None else _size_omega_dot(k, wd.T)
    for _ in range(max_iterations):
        if not active.any():
            break
        if stamps_ns is not None:
            size_wd = _size_omega_dot(
                k, mean_rate_derivative(stamps_ns, np.ascontiguousarray(w.T)).T)
        w_new, f_new = _step_rows(k, wm, am, w, f, size_wd)
        change = np.maximum(abs(w_new - w).max(axis=0) / w_scale,
                            abs(f_new - f).max(axis=0) / f_scale)
        w = np.where(active, w_new, w)
        f = np.where(active, f_new, f)
        stalled = np.where(change >= last, stalled + 1, 0)
        done = (change <= _TINY) | ((stalled >= 3) & (change < 1e-12))
        last = np.where(active, change, last)
        active &= ~done
    else:
        if active.any():
            worst = float(np.max(last[active]))
            raise ImplausibleErrors(f'compensate did not converge in {max_iterations} '
                                    f'iterations (last relative change {worst:.3g}): '
                                    'implausible sensor errors')
    omega = w.T.copy()
    force = f.T.copy()
    omega[bad] = np.nan
    force[bad] = np.nan
    return omega, force


#: Up to this many rows :func:`compensate` loops over samples in Python floats.
SCALAR_ROWS = 8


def compensate(errors: SensorErrors, gyro_meas_rad_s: ArrayLike, accel_meas_m_s2: ArrayLike,
               omega_dot_imu_rad_s2: ArrayLike | None = None,
               stamps_ns: ArrayLike | None = None,
               max_iterations: int = 100) -> tuple[FloatArray, FloatArray]:
    """Exact inverse of :func:`measure`: body rate and specific force from raw outputs.

    Solves the CONTRACT 3 equations for ``(omega, f)`` by fixed-point iteration::

        omega <- (I + Kg)^-1 (w_meas - bg - G f - ag |omega|)
        f     <- (I + Ka)^-1 (a_meas - ba - s(omega, omega_dot) - aa |f| - qa f^2)

    with ``s`` the size-effect term (Kozlov eq. 1), until neither changes any more (to
    machine precision: the contraction factor is of the order of the asymmetry, quadratic
    and g-sensitivity terms, ~1e-3, so a handful of iterations suffice). Each sample stops
    on its own criterion (change relative to its own magnitude), and the arithmetic is
    written per component, so a sample gives the same bits alone or inside any batch
    (the compensator node relies on this). Up to :data:`SCALAR_ROWS` samples run in plain
    Python floats (microseconds each; numpy's per-call overhead dominates tiny arrays).
    A sample with a non-finite input comes out as NaN.

    Parameters
    ----------
    errors : SensorErrors
    gyro_meas_rad_s, accel_meas_m_s2 : (..., 3)
        Raw outputs.
    omega_dot_imu_rad_s2 : (..., 3), optional
        Angular-acceleration estimate used for the size effect.
    stamps_ns : (N,), optional
        Sample stamps: without ``omega_dot_imu_rad_s2``, omega_dot is estimated from the
        compensated rates with :func:`mean_rate_derivative` (samples (N, 3) in order).
        If neither is given, omega_dot is taken as zero: only the centripetal part
        ``omega x (omega x r_i)`` of the size effect is removed (right for stationary or
        constant-rate data; the caller's choice otherwise).
    max_iterations : int
        :class:`ImplausibleErrors` if the iteration has not converged by then (absurd
        errors).

    Returns
    -------
    omega_rad_s, f_m_s2 : ndarray, shape (..., 3)
    """
    c = _inverse(errors)
    wm = np.asarray(gyro_meas_rad_s, dtype=float)
    am = np.asarray(accel_meas_m_s2, dtype=float)
    shape = wm.shape if wm.shape == am.shape else np.broadcast_shapes(wm.shape, am.shape)
    wm2 = (wm if wm.shape == shape else np.broadcast_to(wm, shape)).reshape(-1, 3)
    am2 = (am if am.shape == shape else np.broadcast_to(am, shape)).reshape(-1, 3)
    n = wm2.shape[0]
    stamps = None
    wd: FloatArray | None = None
    if c.has_size:
        if omega_dot_imu_rad_s2 is not None:
            wd = np.broadcast_to(np.asarray(omega_dot_imu_rad_s2, dtype=float),
                                 shape).reshape(-1, 3)
        elif stamps_ns is not None:
            stamps = np.asarray(stamps_ns)
        else:
            wd = np.zeros((n, 3))
    if stamps is None and n <= SCALAR_ROWS:
        omega = np.empty((n, 3))
        force = np.empty((n, 3))
        wl, al = wm2.tolist(), am2.tolist()
        wdl = None if wd is None else wd.tolist()
        for k in range(n):
            omega[k], force[k] = _compensate_one(
                c, wl[k], al[k], None if wdl is None else wdl[k], max_iterations)
    else:
        # a runaway iteration (implausible errors) overflows before _compensate_rows refuses
        # it (ImplausibleErrors): the refusal names it, numpy's warnings would only add noise
        with np.errstate(over='ignore', invalid='ignore'):
            omega, force = _compensate_rows(c, wm2, am2, wd, stamps, max_iterations)
    return omega.reshape(shape), force.reshape(shape)


def compensate_one(errors: SensorErrors, gyro_meas_rad_s: Any, accel_meas_m_s2: Any,
                   omega_dot_imu_rad_s2: Any | None = None,
                   max_iterations: int = 100) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """:func:`compensate` of one sample, as Python floats, without any numpy call.

    The live-stream path (a few microseconds): the same operations and stopping rule as
    :func:`compensate`, so ``compensate(errors, g[None], a[None], wd[None])`` holds the
    same bits. ``omega_dot_imu_rad_s2=None`` means zero (only the centripetal part of the
    size effect is removed). Non-finite input gives NaN output.

    Parameters
    ----------
    errors : SensorErrors
    gyro_meas_rad_s, accel_meas_m_s2, omega_dot_imu_rad_s2 : sequence of 3 floats

    Returns
    -------
    omega_rad_s, f_m_s2 : tuple of 3 floats
    """
    c = _inverse(errors)
    wd = None
    if c.has_size:
        wd = (0.0, 0.0, 0.0) if omega_dot_imu_rad_s2 is None else \
            (float(omega_dot_imu_rad_s2[0]), float(omega_dot_imu_rad_s2[1]),
             float(omega_dot_imu_rad_s2[2]))
    g = (float(gyro_meas_rad_s[0]), float(gyro_meas_rad_s[1]), float(gyro_meas_rad_s[2]))
    a = (float(accel_meas_m_s2[0]), float(accel_meas_m_s2[1]), float(accel_meas_m_s2[2]))
    return _compensate_one(c, g, a, wd, max_iterations)
