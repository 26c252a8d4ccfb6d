"""Error-state layout and the sensor-error Jacobians of CONTRACT 3.

The filter state (all "estimate minus truth") is, in this order::

    psi (3)   attitude error in ENU: R_hat = exp([psi x]) R_true (strapdown.py)  [urad]
    dv  (3)   velocity error in ENU: v_hat - v_true                         [um/s]
    then the enabled groups of :data:`GROUPS` (sensor errors, lever arm, mounting), and on a
    general chain the joint zero offsets (:data:`CHAIN_GROUP`, last)

Each group is kept in an engineering unit (:data:`GROUPS`), so that the covariance spans a
few orders of magnitude instead of ten (issue 3, item 4). ``scale`` converts a scaled state to
SI: ``x_si = scale * x_scaled``.

Sensor-error Jacobians ``M_g = d(gyro_meas)/d(theta_g)``, ``M_a = d(accel_meas)/d(theta_a)``
are taken from the forward model of CONTRACT 3 (Kozlov & Kapralov eq. 1 for the size effect;
Savage's MARS symmetric misalignment): with compensated rates ``omega_hat`` and the error
``x = theta_hat - theta``, ``omega_hat - omega = -M_g x`` to first order.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import parameters as registry
from ..rotation import skew  # noqa: F401  (re-exported for the filter maths)

FloatArray = NDArray[np.float64]

DEG_H = registry.DEG_H_RAD_S  # rad/s per deg/h
G0 = registry.G0_M_S2  # m/s^2 per g (the unit "ug" of the summary; not the site's gravity)
PPM = registry.PPM
URAD = registry.URAD
MM = registry.MM

# (group, size, SI per engineering unit, unit label, side) - side g: gyro Jacobian columns,
# a: accel Jacobian columns, '': measurement-only states (the registry's groups, its order)
#: the joint zero offsets of a general chain (issue 15, measurement-only states): one per
#: revolute joint before the last (:func:`joint_offset_joints`); the size is the chain's, given
#: to :meth:`StateLayout.build` (0 here). Not a registry group: no grade, no CONTRACT 4 key.
CHAIN_GROUP = 'joint_offset'
GROUPS: tuple[tuple[str, int, float, str, str], ...] = tuple(
    (g.name, g.size, g.si_per_unit, g.unit, g.side) for g in registry.GROUPS)
GROUP_INFO = {g[0]: g for g in GROUPS + ((CHAIN_GROUP, 0, URAD, 'urad', ''),)}
GYRO_GROUPS = tuple(g[0] for g in GROUPS if g[4] == 'g')
ACCEL_GROUPS = tuple(g[0] for g in GROUPS if g[4] == 'a')
N_GYRO = sum(g[1] for g in GROUPS if g[4] == 'g')  # 22 columns of the full M_g
N_ACCEL = sum(g[1] for g in GROUPS if g[4] == 'a')  # 26 columns of the full M_a

# index pairs of the off-diagonal parameters (row i, column j); row-major order
MIS_SYM = registry.group('gyro_misalignment').entries  # Kg[i][j] == Kg[j][i]
OFF6 = registry.OFF_DIAGONAL  # Ka and size effect r_i[j]


def _offsets(groups: tuple[str, ...]) -> dict[str, slice]:
    out, k = {}, 0
    for name in groups:
        n = GROUP_INFO[name][1]
        out[name] = slice(k, k + n)
        k += n
    return out


_GYRO_COLS = _offsets(GYRO_GROUPS)
_ACCEL_COLS = _offsets(ACCEL_GROUPS)


def gyro_jacobian(omega_rad_s: FloatArray, f_m_s2: FloatArray,
                  omega_curvature_rad_s: FloatArray | None = None) -> FloatArray:
    """``M_g = d(gyro_meas)/d(theta_g)`` of CONTRACT 3, shape ``(N, 3, 22)``, SI units.

    Columns: bg (3), diag Kg (3), ag (3), symmetric Kg_ij for (01, 02, 12), G row-major (9),
    the sampling kernel (column ``omega_curvature`` = ``omega'' dt^2``,
    :func:`sample_kernel_column`).
    """
    w = np.atleast_2d(omega_rad_s)
    f = np.atleast_2d(f_m_s2)
    n = w.shape[0]
    m = np.zeros((n, 3, N_GYRO))
    i3 = np.arange(3)
    m[:, i3, _GYRO_COLS['gyro_bias'].start + i3] = 1.0
    m[:, i3, _GYRO_COLS['gyro_scale'].start + i3] = w
    m[:, i3, _GYRO_COLS['gyro_asymmetry'].start + i3] = np.abs(w)
    c0 = _GYRO_COLS['gyro_misalignment'].start
    for k, (i, j) in enumerate(MIS_SYM):
        m[:, i, c0 + k] = w[:, j]
        m[:, j, c0 + k] = w[:, i]
    c0 = _GYRO_COLS['gyro_g_sensitivity'].start
    for i in range(3):
        m[:, i, c0 + 3 * i:c0 + 3 * i + 3] = f
    if omega_curvature_rad_s is not None:
        m[:, :, _GYRO_COLS['gyro_sample_kernel'].start] = sample_kernel_column(
            omega_curvature_rad_s)
    return m


def accel_jacobian(omega_rad_s: FloatArray, omega_dot_rad_s2: FloatArray, f_m_s2: FloatArray,
                   f_dot_m_s3: FloatArray | None = None,
                   f_curvature_m_s2: FloatArray | None = None) -> FloatArray:
    """``M_a = d(accel_meas)/d(theta_a)`` of CONTRACT 3, shape ``(N, 3, 26)``, SI units.

    Columns: ba (3), diag Ka (3), aa (3), Ka off-diagonal (01, 02, 10, 12, 20, 21), qa (3),
    size effect r_i[j] in the same order (Kozlov & Kapralov eq. 1:
    ``d/dr_i[j] (omega_dot x r_i + omega x (omega x r_i))_i = (e_i x omega_dot)_j +
    omega_i omega_j`` for j != i), the accel-minus-gyro time offset (column ``f_dot``:
    accelerometers sampled ``tau`` late read ``f(t + tau) = f + f_dot tau``) and the sampling
    kernel ``s`` (column ``f_curvature`` = ``f'' dt^2``, see :func:`sample_kernel_column`).
    """
    w = np.atleast_2d(omega_rad_s)
    wd = np.atleast_2d(omega_dot_rad_s2)
    f = np.atleast_2d(f_m_s2)
    n = f.shape[0]
    m = np.zeros((n, 3, N_ACCEL))
    i3 = np.arange(3)
    m[:, i3, _ACCEL_COLS['accel_bias'].start + i3] = 1.0
    m[:, i3, _ACCEL_COLS['accel_scale'].start + i3] = f
    m[:, i3, _ACCEL_COLS['accel_asymmetry'].start + i3] = np.abs(f)
    m[:, i3, _ACCEL_COLS['accel_quadratic'].start + i3] = f * f
    c_mis = _ACCEL_COLS['accel_misalignment'].start
    c_r = _ACCEL_COLS['size_effect'].start
    for k, (i, j) in enumerate(OFF6):
        m[:, i, c_mis + k] = f[:, j]
        # (e_i x wd)_j = eps_{j i l} wd_l = -eps_{i j l} wd_l, l the remaining axis
        l_ax = 3 - i - j
        sign = -1.0 if (i, j, l_ax) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else 1.0
        m[:, i, c_r + k] = sign * wd[:, l_ax] + w[:, i] * w[:, j]
    if f_dot_m_s3 is not None:
        m[:, :, _ACCEL_COLS['time_offset'].start] = np.atleast_2d(f_dot_m_s3)
    if f_curvature_m_s2 is not None:
        m[:, :, _ACCEL_COLS['accel_sample_kernel'].start] = sample_kernel_column(
            f_curvature_m_s2)
    return m


def sample_kernel_column(curvature: FloatArray) -> FloatArray:
    """``d(meas)/ds`` of a sampling kernel ``s`` from ``f'' dt^2`` (the second difference of
    the rate or specific force ``f`` over one sample period, ``(N, 3)``).

    A sample that averages ``f`` with a kernel of variance ``V`` about its centre reads
    ``f(t_c) + V f'' / 2``: an interval mean (``V = dt^2 / 12``) ``f(t_c) + f'' dt^2 / 24``, a
    point sample (``V = 0``) ``f(t_c)``. Taking CONTRACT 1's interval mean as the model, a
    kernel ``s = 1 - 12 V / dt^2`` (0: interval means, 1: point samples, below 0: a
    smoothing filter; the trapezoid of two point samples is ``-2``) reads
    ``mean + s (-f'' dt^2 / 24)``. The centre's offset from the interval's middle is common to
    gyros and accelerometers: the joint latency. Rotating gravity has ``f'' = -omega^2 f``:
    point samples read as means are ``(omega dt)^2 / 24`` too large, 4 ppm at 1 rad/s and
    100 Hz (session 23: 2.6-6.6 sigma of a navigation unit's accelerometer scales). A gyro's
    ``omega''`` is at the corners of a rate ramp: point samples read as means leave the
    attitude ``alpha dt^2 / 24`` off through a ramp of ``alpha``, and gravity turns that into
    velocity (40 um/s over a 1 s ramp of 1 rad/s^2 at 100 Hz)."""
    return -np.atleast_2d(curvature) / 24.0


@dataclass(frozen=True)
class StateLayout:
    """Index map of the filter state for a tuple of enabled groups.

    Attributes
    ----------
    groups:
        Enabled groups in state order (a subset of :data:`GROUPS`, that order).
    slices:
        Group name -> slice into the state vector (``'psi'`` and ``'dv'`` included).
    n:
        State dimension.
    scale:
        SI value of one scaled unit, per state ``(n,)``.
    gyro_cols, accel_cols:
        For the gyro/accel parameter states: their state indices and the matching columns of
        :func:`gyro_jacobian` / :func:`accel_jacobian`.
    """

    groups: tuple[str, ...]
    slices: dict[str, slice]
    n: int
    scale: FloatArray
    gyro_state_idx: NDArray[np.intp]
    gyro_cols: NDArray[np.intp]
    accel_state_idx: NDArray[np.intp]
    accel_cols: NDArray[np.intp]

    @classmethod
    def build(cls, groups: tuple[str, ...], n_joint_offsets: int = 0) -> 'StateLayout':
        """Layout for ``groups`` (order normalised to :data:`GROUPS`); ``n_joint_offsets``
        states of :data:`CHAIN_GROUP` at the end when it is > 0 (a general chain)."""
        unknown = set(groups) - set(GROUP_INFO)
        if unknown:
            raise ValueError(f'unknown state groups {sorted(unknown)}')
        if CHAIN_GROUP in groups:
            raise ValueError(f'{CHAIN_GROUP!r} is sized by the chain: pass n_joint_offsets')
        ordered = tuple(g[0] for g in GROUPS if g[0] in groups)
        if n_joint_offsets > 0:
            ordered = ordered + (CHAIN_GROUP,)
        slices = {'psi': slice(0, 3), 'dv': slice(3, 6)}
        scale = [np.full(3, URAD), np.full(3, 1e-6)]
        k = 6
        gi: list[int] = []
        gc: list[int] = []
        ai: list[int] = []
        ac: list[int] = []
        for name in ordered:
            _, size, unit, _, side = GROUP_INFO[name]
            if name == CHAIN_GROUP:
                size = n_joint_offsets
            slices[name] = slice(k, k + size)
            scale.append(np.full(size, unit))
            if side == 'g':
                gi.extend(range(k, k + size))
                gc.extend(range(_GYRO_COLS[name].start, _GYRO_COLS[name].stop))
            elif side == 'a':
                ai.extend(range(k, k + size))
                ac.extend(range(_ACCEL_COLS[name].start, _ACCEL_COLS[name].stop))
            k += size
        return cls(ordered, slices, k, np.concatenate(scale), np.array(gi, np.intp),
                   np.array(gc, np.intp), np.array(ai, np.intp), np.array(ac, np.intp))

    def labels(self) -> list[str]:
        """One readable label per state, e.g. ``'gyro_scale[1]'``."""
        return list(_labels(self._group_sizes()))

    def _group_sizes(self) -> tuple[tuple[str, int], ...]:
        return tuple((g, self.slices[g].stop - self.slices[g].start) for g in self.groups)

    @property
    def n_joint_offsets(self) -> int:
        """Number of joint zero-offset states (0 on a turntable)."""
        sl = self.slices.get(CHAIN_GROUP)
        return 0 if sl is None else sl.stop - sl.start

    @property
    def state_labels(self) -> tuple[str, ...]:
        """The labels of the calibration states (:meth:`labels` without psi and dv)."""
        return _labels(self._group_sizes())[6:]


@functools.lru_cache(maxsize=64)
def _labels(group_sizes: tuple[tuple[str, int], ...]) -> tuple[str, ...]:
    """:meth:`StateLayout.labels` of ``(group, size)`` pairs (read after every block: built
    once)."""
    out = ['psi[0]', 'psi[1]', 'psi[2]', 'dv[0]', 'dv[1]', 'dv[2]']
    for name, size in group_sizes:
        out.extend(f'{name}[{i}]' for i in range(size))
    return tuple(out)


def joint_offset_joints(fixture: Any, attitude_aiding: bool = False) -> tuple[int, ...]:
    """The joints whose zero offsets are states: the revolute joints before the last (the
    last one's *is* a mounting rotation about its axis, the mounting is the IMU's on the last
    link as its encoder reads it: docs/ESTIMATOR.md "General chains"). A general chain's
    always; a turntable's (concurrent axes) with encoder attitude aiding only, the one
    measurement an encoder zero enters there (with none, a table's zero errors only move the
    stationary windows' poses, which the self-check takes as nuisance)."""
    if getattr(fixture, 'concurrent', True) and not attitude_aiding:
        return ()
    return nuisance_offset_joints(fixture)


def nuisance_offset_joints(fixture: Any) -> tuple[int, ...]:
    """The revolute joints before the last: those whose zero offsets are not the mounting."""
    return tuple(j for j in range(fixture.n_joints - 1) if fixture.joints[j].revolute)


# --- SensorErrors <-> flat parameter vectors ---------------------------------------------

def _theta_entries(cols: dict[str, slice]) -> tuple[tuple[str, slice, tuple[NDArray[
        np.intp], ...], bool], ...]:
    """(SensorErrors field, columns, index arrays, symmetric) of each sensor group of one
    parameter vector, in the registry's order."""
    out = []
    for g in registry.SENSOR_GROUPS:
        if g.name in cols and g.key is not None:
            p = registry.parameter(g.key)
            idx = tuple(np.array(k, np.intp) for k in zip(*g.entries))
            out.append((p.field, cols[g.name], idx, p.symmetric))
    return tuple(out)


_GYRO_ENTRIES = _theta_entries(_GYRO_COLS)
_ACCEL_ENTRIES = _theta_entries(_ACCEL_COLS)


def theta_from_errors(errors: Any) -> tuple[FloatArray, FloatArray]:
    """The full gyro (22,) and accel (26,) parameter vectors of a ``SensorErrors`` (the
    registry's groups; Kg's pairs as the mean of both halves).

    The auxiliary states (the time offset, the sampling kernels) are not part of
    ``SensorErrors`` and are returned as 0.
    """
    out = []
    for n, entries in ((N_GYRO, _GYRO_ENTRIES), (N_ACCEL, _ACCEL_ENTRIES)):
        theta = np.zeros(n)
        for fld, cols, idx, sym in entries:
            a = np.asarray(getattr(errors, fld), float)
            theta[cols] = 0.5 * (a[idx] + a[idx[::-1]]) if sym else a[idx]
        out.append(theta)
    return out[0], out[1]


def errors_from_theta(theta_g: FloatArray, theta_a: FloatArray, cls: type) -> Any:
    """Build ``cls`` (``SensorErrors``) from the full parameter vectors (inverse of above)."""
    arrays = {p.field: np.zeros(p.shape) for p in registry.PARAMETERS}
    for theta, entries in ((theta_g, _GYRO_ENTRIES), (theta_a, _ACCEL_ENTRIES)):
        for fld, cols, idx, sym in entries:
            arrays[fld][idx] = theta[cols]
            if sym:
                arrays[fld][idx[::-1]] = theta[cols]
    return cls(**arrays)


def gyro_cols(name: str) -> slice:
    """Columns of group ``name`` in the full gyro parameter vector."""
    return _GYRO_COLS[name]


def accel_cols(name: str) -> slice:
    """Columns of group ``name`` in the full accel parameter vector."""
    return _ACCEL_COLS[name]


#: every sign pattern of a 3-vector (-1, 0, +1 per component), pattern ``k`` at
#: ``k = sum_i (sign_i + 1) 3^(2 - i)`` (:func:`compensation_inverses`)
_SIGN_PATTERNS = np.array([[a, b, c] for a in (-1., 0., 1.) for b in (-1., 0., 1.)
                           for c in (-1., 0., 1.)])
_PATTERN_WEIGHTS = np.array([9.0, 3.0, 1.0])


def compensation_inverses(errors: object, omega_hat: FloatArray, f_hat: FloatArray
                          ) -> tuple[FloatArray, FloatArray]:
    """``D_g^-1`` and ``D_a^-1`` of :func:`compensated_jacobians`, ``(N, 3, 3)`` each
    (``J = D^-1 M``).

    ``D_g = I + Kg + diag(ag sign omega)`` takes one of 27 values (the sign patterns): those
    are inverted (the same matrices and LAPACK calls as one per sample, so the same bits) and
    picked per sample. ``D_a = I + Ka + diag(aa sign f + 2 qa f)`` varies with ``f``: its
    adjugate over its determinant, with the constant off-diagonal entries as scalars (to
    rounding what ``numpy.linalg.inv`` gives, at a third of its cost on 200 samples).
    """
    kg = np.asarray(errors.gyro_scale_misalignment)  # type: ignore[attr-defined]
    ka = np.asarray(errors.accel_scale_misalignment)  # type: ignore[attr-defined]
    ag = np.asarray(errors.gyro_scale_asymmetry)  # type: ignore[attr-defined]
    aa = np.asarray(errors.accel_scale_asymmetry)  # type: ignore[attr-defined]
    qa = np.asarray(errors.accel_quadratic_per_m_s2)  # type: ignore[attr-defined]
    sg = np.sign(omega_hat)
    Dg = np.eye(3) + kg + np.einsum('ni,ij->nij', ag * _SIGN_PATTERNS, np.eye(3))
    Dg_inv = np.linalg.inv(Dg)[((sg + 1.0) @ _PATTERN_WEIGHTS).astype(np.intp)]
    A = np.eye(3) + ka
    d = (A.diagonal() + (aa * np.sign(f_hat) + 2 * qa * f_hat)).T  # (3, N) diagonal of D_a
    (_, a01, a02), (a10, _, a12), (a20, a21, _) = A.tolist()
    x0, x1, x2 = d
    Da_inv = np.empty((len(f_hat), 3, 3))
    c = Da_inv.reshape(-1, 9).T  # the nine entries, each (N,)
    c[0] = x1 * x2 - a12 * a21
    c[3] = a12 * a20 - a10 * x2
    c[6] = a10 * a21 - x1 * a20
    det = x0 * c[0] + a01 * c[3] + a02 * c[6]
    c[1] = a02 * a21 - a01 * x2
    c[2] = a01 * a12 - a02 * x1
    c[4] = x0 * x2 - a02 * a20
    c[5] = a02 * a10 - x0 * a12
    c[7] = a01 * a20 - x0 * a21
    c[8] = x0 * x1 - a01 * a10
    c /= det
    return Dg_inv, Da_inv


def compensated_jacobians(errors: object, omega_hat: FloatArray, omega_dot: FloatArray,
                          f_hat: FloatArray, f_dot: FloatArray | None = None,
                          omega_curvature: FloatArray | None = None,
                          f_curvature: FloatArray | None = None) -> tuple[
                              FloatArray, FloatArray]:
    """Jacobians of the *compensated* samples: ``omega_hat - omega = -Jg x_g``,
    ``f_hat - f = -Ja x_a`` (``x`` = estimate minus truth), to first order.

    Differentiating ``measure(theta, omega) = meas`` at fixed ``meas`` gives
    ``(I + Kg + diag(ag sign omega)) d omega = -M_g d theta_g`` (and likewise for the
    accelerometers with ``diag(aa sign f + 2 qa f)``), so ``Jg = D_g^-1 M_g``. With MEMS scale
    errors of 0.3 % this matters at the 0.3 % level of every Jacobian column. Neglected cross
    terms: ``G (f_hat - f)`` in the gyros (G ~ 1e-6 (rad/s)/(m/s^2)) and the change of the
    centripetal size-effect term with ``omega_hat - omega`` (~2 r omega |d omega|, 40 ng for a
    navigation-grade IMU with r = 10 mm at 1 rad/s and 20 ppm scale error).
    """
    Mg = gyro_jacobian(omega_hat, f_hat, omega_curvature)
    Ma = accel_jacobian(omega_hat, omega_dot, f_hat, f_dot, f_curvature)
    Dg_inv, Da_inv = compensation_inverses(errors, omega_hat, f_hat)
    return Dg_inv @ Mg, Da_inv @ Ma
