"""Vectorised strapdown navigator for a fixed site (attitude, velocity, position in ENU).

Inputs are integrating-IMU samples (CONTRACT section 1): the mean angular rate relative to
inertial space and the mean specific force over each interval, in the IMU frame, so the
increments are ``dtheta_k = gyro_k dt_k`` and ``dv_k = accel_k dt_k``. The navigation frame
is the site's local-level ENU frame, which is earth-fixed and therefore turns relative to
inertial space at ``omega_ie_enu``. Equations of motion (the fixture kinematics of
docs/DESIGN.md use the same ones, so an error-free IMU navigates to the truth)::

    dR_enu_imu/dt = R_enu_imu [omega_ib_imu x] - [omega_ie_enu x] R_enu_imu
    dv_enu/dt     = R_enu_imu f_imu + g_enu - 2 omega_ie_enu x v_enu
    dp_enu/dt     = v_enu

Algorithms (Savage, "Strapdown inertial navigation integration algorithm design", parts 1
and 2, J. Guid. Control Dyn. 21 (1998) 19-28 and 208-221):

- attitude: rotation vector with the two-sample coning term,
  ``phi_k = dtheta_k + 1/12 dtheta_{k-1} x dtheta_k`` (Savage part 1, eq. 29 with the rates
  linear in time), written for unequal intervals as ``dt_k^3 / (6 (dt_k + dt_{k-1}))
  w_{k-1} x w_k`` (mean rates ``w``), which reduces to the 1/12 form for equal ones; the ENU
  frame's own rotation is ``exp(-omega_ie_enu t)`` on the left, exact because its axis is
  fixed, and the body increments are chained by a parallel prefix product;
- velocity: ``dv_k + a1 dtheta_k x dv_k + a2 dtheta_k x (dtheta_k x dv_k)`` with Savage's
  exact coefficients ``a1 = (1 - cos t)/t^2``, ``a2 = (1 - sin t / t)/t^2`` (``t = |dtheta|``;
  rotation compensation, Savage part 2, eqs. 9-11)
  plus sculling ``1/12 (dtheta_{k-1} x dv_k + dv_{k-1} x dtheta_k)`` (part 2, eq. 39; same
  unequal-interval generalisation as coning), mapped to ENU with the attitude at the start
  of the interval; the rotation and sculling terms use the rate relative to ENU,
  ``w - (R_{k-1} + R_k)^T omega_ie_enu / 2``, which takes the ENU frame's turn during the
  interval into account (to O(omega_ie (w dt)^2)); Coriolis as the exact rotation
  ``exp(-2 omega_ie_enu dt)`` of the velocity (a linear recursion, solved in closed form over
  the batch), with the interval's force increment applied at mid-interval;
- position: trapezoid on the velocities.

Why the exact coefficients: for a spin at rate w about a horizontal axis (gravity turning in
the IMU frame) the truncated ``1/2, 0`` form leaves a velocity drift ``g (w dt)^2 / 12``
(1.6e-5 m/s^2 at 0.6 rad/s, 200 Hz) and ``1/2, 1/6`` still ``g (w dt)^3 / 24`` (0.28 mm/s
after 300 s at 150 deg/s); with ``a1, a2`` and the sculling term the (w dt)^3 terms cancel.

Error-state convention (used by :meth:`Strapdown.correct` and the estimator)
-----------------------------------------------------------------------------
All errors are *estimate minus truth*, expressed in ENU::

    R_est = exp([dtheta_enu x]) R_true   (~ (I + skew(dtheta_enu)) R_true)
    v_est = v_true + dv_enu,   p_est = p_true + dp_enu

so ``correct(dtheta, dv, dp)`` sets ``R <- exp(-[dtheta x]) R``, ``v <- v - dv``,
``p <- p - dp``. To first order the errors obey (``dw``, ``df`` the gyro and accelerometer
errors in the IMU frame, estimate minus truth)::

    d(dtheta)/dt = -omega_ie_enu x dtheta + R dw
    d(dv)/dt     = -(R f) x dtheta + R df - 2 omega_ie_enu x dv
    d(dp)/dt     = dv
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from .errors import InputError

FloatArray = NDArray[np.float64]

__all__ = ['NavBatch', 'Strapdown']


@dataclass(frozen=True)
class NavBatch:
    """Navigation solution at the end of each propagated interval.

    Attributes
    ----------
    R_enu_imu : ndarray, shape (N, 3, 3)
        Attitude (maps IMU-frame vectors to ENU).
    q_enu_imu : ndarray, shape (N, 4)
        The same attitude as unit quaternions, scalar last (x, y, z, w).
    v_enu_m_s : ndarray, shape (N, 3)
        Velocity relative to the earth, in ENU [m/s].
    p_enu_m : ndarray, shape (N, 3)
        Position relative to the start point's frame origin, in ENU [m].
    f_enu_m_s2 : ndarray, shape (N, 3)
        Mean specific force over each interval in ENU [m/s^2] (coning/sculling-corrected
        velocity increment divided by ``dt``).
    """

    R_enu_imu: FloatArray
    q_enu_imu: FloatArray
    v_enu_m_s: FloatArray
    p_enu_m: FloatArray
    f_enu_m_s2: FloatArray

    def __len__(self) -> int:
        return int(self.v_enu_m_s.shape[0])


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise cross product of (N,3) arrays (either may be (3,)).

    Written out (``a1 b2 - a2 b1``, ...) on the components taken in cyclic order: np.cross
    costs ~70 us of axis handling per call, which dominates small batches.
    """
    return (a.take(_NEXT, axis=-1) * b.take(_PREV, axis=-1)  # type: ignore[no-any-return]
            - a.take(_PREV, axis=-1) * b.take(_NEXT, axis=-1))


#: the next and the previous component of each (cyclic order), for :func:`_cross`
_NEXT = np.array([1, 2, 0])
_PREV = np.array([2, 0, 1])


#: ``p * q = L(p) q``: the entries of ``L(p)`` (row-major 4 x 4) as components of ``p`` and
#: their signs (x, y, z, w order)
_QMUL_INDEX = np.array([3, 2, 1, 0, 2, 3, 0, 1, 1, 0, 3, 2, 0, 1, 2, 3])
_QMUL_SIGN = np.array([1., -1., 1., 1., 1., 1., -1., 1., -1., 1., 1., 1., -1., -1., -1., 1.])


def _qmul(p: FloatArray, q: FloatArray) -> FloatArray:
    """Hamilton product of (N,4) or (4,) quaternions (x, y, z, w), broadcast.

    As the matrix ``L(p)`` times ``q``: three numpy calls instead of thirty component ones
    (the hot loop of the prefix product; rotation.quat_multiply has moveaxis overhead too).
    """
    L = (p[..., _QMUL_INDEX] * _QMUL_SIGN).reshape(p.shape[:-1] + (4, 4))
    return (L @ q[..., None])[..., 0]  # type: ignore[no-any-return]


def _rotation_coefficients(theta2: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Savage's velocity rotation coefficients ``(1 - cos t) / t^2`` and ``(1 - sin t / t) / t^2``.

    Savage part 2, eq. 11 (``t = |dtheta|``, from ``theta2 = t^2``). Series below 0.1 rad
    (next terms < 3e-16), where the closed forms lose digits to cancellation.
    """
    a1 = 0.5 - theta2 / 24.0 * (1.0 - theta2 / 30.0 * (1.0 - theta2 / 56.0))
    a2 = (1.0 - theta2 / 20.0 * (1.0 - theta2 / 42.0 * (1.0 - theta2 / 72.0))) / 6.0
    if theta2.size and theta2.max() < 0.01:  # all below 0.1 rad (any rate below 20 rad/s
        return a1, a2                       # at 200 Hz): the series alone
    t = np.sqrt(theta2)
    small = t < 0.1
    ts = np.where(small, 1.0, t)
    a1 = np.where(small, a1, 2.0 * np.sin(0.5 * ts) ** 2 / ts ** 2)
    a2 = np.where(small, a2, (ts - np.sin(ts)) / ts ** 3)
    return a1, a2


def _quat_prefix_product(q: FloatArray) -> FloatArray:
    """Cumulative Hamilton product ``out[k] = q[0] * q[1] * ... * q[k]`` along axis 0.

    Hillis-Steele parallel prefix: ceil(log2 N) vectorised passes (rotation.py's
    ``quat_prefix_product`` is a per-sample Python loop, too slow for the estimator's rate).
    Rounding grows with log2(N) instead of N. Not re-normalised here.
    """
    out = q.copy()
    n = out.shape[0]
    step = 1
    while step < n:
        out[step:] = _qmul(out[:-step], out[step:])
        step *= 2
    return out


def _rotate_about_axis(axis: FloatArray, angle_rad: FloatArray, x: FloatArray) -> FloatArray:
    """Rotate vectors ``x (N,3)`` by ``angle_rad (N,)`` about one fixed unit ``axis`` (Rodrigues).

    Closed form for a single fixed axis: cheaper than building N scipy rotations.
    """
    c = np.cos(angle_rad)[:, None]
    s = np.sin(angle_rad)[:, None]
    return x * c + _cross(axis, x) * s + axis * (x @ axis)[:, None] * (1.0 - c)


def _quat_to_matrix(q: FloatArray) -> FloatArray:
    """The rotation matrix of one quaternion (x, y, z, w), normalised first (scipy's
    ``Rotation.from_quat(q).as_matrix()`` in Python floats: a tenth of its time)."""
    x, y, z, w = (float(c) for c in q)
    r = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / r, y / r, z / r, w / r
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.array([[x2 - y2 - z2 + w2, 2.0 * (xy - zw), 2.0 * (xz + yw)],
                     [2.0 * (xy + zw), -x2 + y2 - z2 + w2, 2.0 * (yz - xw)],
                     [2.0 * (xz - yw), 2.0 * (yz + xw), -x2 - y2 + z2 + w2]])


def _rotvec_to_quat(v: FloatArray) -> tuple[float, float, float, float]:
    """The quaternion (x, y, z, w) of one rotation vector (scipy's ``from_rotvec``: series
    of ``sin(a / 2) / a`` below 1e-3 rad), in Python floats."""
    x, y, z = (float(c) for c in v)
    a = math.sqrt(x * x + y * y + z * z)
    if a <= 1e-3:
        a2 = a * a
        k = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        k = math.sin(0.5 * a) / a
    return k * x, k * y, k * z, math.cos(0.5 * a)


def _quat_mul_normalised(p: tuple[float, float, float, float], q: FloatArray) -> FloatArray:
    """``p * q`` (Hamilton, x, y, z, w), normalised to unit length."""
    px, py, pz, pw = p
    qx, qy, qz, qw = (float(c) for c in q)
    out = (pw * qx + px * qw + py * qz - pz * qy, pw * qy - px * qz + py * qw + pz * qx,
           pw * qz + px * qy - py * qx + pz * qw, pw * qw - px * qx - py * qy - pz * qz)
    r = math.sqrt(sum(c * c for c in out))
    return np.array([c / r for c in out])


class Strapdown:
    """Strapdown navigator for a fixed site; see the module docstring for the algorithms.

    Parameters
    ----------
    site : Site
        Anything with ``g_enu (3,)`` [m/s^2] and ``omega_ie_enu (3,)`` [rad/s]
        (:class:`imu_calib_ros.core.earth.Site`).
    R_enu_imu : array_like, shape (3, 3)
        Initial attitude (orthonormal to 1e-6; re-orthonormalised).
    v_enu_m_s, p_enu_m : array_like, shape (3,)
        Initial velocity [m/s] and position [m] in ENU (zero by default).

    Notes
    -----
    :meth:`propagate` gives the same result (to rounding, ~1e-13) whether it is called once
    with N samples or N times with one, because the coning and sculling memory (the previous
    sample's mean rate, specific force and interval) is carried between calls. Call
    :meth:`reset_memory` after a gap in the data: the next sample then gets no coning or
    sculling correction (its predecessor is not adjacent).
    """

    def __init__(self, site, R_enu_imu: ArrayLike, v_enu_m_s: ArrayLike = (0.0, 0.0, 0.0),
                 p_enu_m: ArrayLike = (0.0, 0.0, 0.0)) -> None:
        self._g_enu = np.asarray(site.g_enu, dtype=float).reshape(3)
        self._omega_ie_enu = np.asarray(site.omega_ie_enu, dtype=float).reshape(3)
        rate = float(np.linalg.norm(self._omega_ie_enu))
        self._earth_rate = rate
        self._earth_axis = self._omega_ie_enu / rate if rate > 0.0 else np.array([0., 0., 1.])
        self.set_state(R_enu_imu, v_enu_m_s, p_enu_m)
        self.reset_memory()

    # ------------------------------------------------------------------ state
    def set_state(self, R_enu_imu: ArrayLike, v_enu_m_s: ArrayLike, p_enu_m: ArrayLike) -> None:
        """Replace attitude, velocity and position (keeps the coning/sculling memory).

        Raises
        ------
        InputError
            If an argument has the wrong shape, is not finite, or ``R_enu_imu`` is not a
            rotation matrix to 1e-6.
        """
        R = np.asarray(R_enu_imu, dtype=float)
        v = np.asarray(v_enu_m_s, dtype=float)
        p = np.asarray(p_enu_m, dtype=float)
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise InputError(f'R_enu_imu: expected a finite 3x3 matrix, got shape {R.shape}')
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0.0:
            raise InputError('R_enu_imu: not a rotation matrix (orthonormal, det +1) to 1e-6')
        for name, x in (('v_enu_m_s', v), ('p_enu_m', p)):
            if x.shape != (3,) or not np.all(np.isfinite(x)):
                raise InputError(f'{name}: expected 3 finite numbers, got shape {x.shape}')
        self._q = Rotation.from_matrix(R).as_quat()
        self._v = v.copy()
        self._p = p.copy()

    @property
    def R_enu_imu(self) -> FloatArray:
        """Current attitude, shape (3, 3)."""
        return _quat_to_matrix(self._q)

    @property
    def q_enu_imu(self) -> FloatArray:
        """Current attitude as a unit quaternion (x, y, z, w)."""
        return self._q.copy()

    @property
    def v_enu_m_s(self) -> FloatArray:
        """Current velocity in ENU [m/s]."""
        return self._v.copy()

    @property
    def p_enu_m(self) -> FloatArray:
        """Current position in ENU [m]."""
        return self._p.copy()

    def reset_memory(self) -> None:
        """Forget the previous sample (after a gap): no coning/sculling term for the next one."""
        self._prev_gyro: FloatArray | None = None
        self._prev_accel: FloatArray | None = None
        self._prev_dt = 0.0
        self._prev_omega_ie_imu = np.zeros(3)

    # ------------------------------------------------------------- feedback
    def correct(self, dtheta_enu: ArrayLike, dv_enu: ArrayLike = (0.0, 0.0, 0.0),
                dp_enu: ArrayLike = (0.0, 0.0, 0.0)) -> None:
        """Remove estimated errors (estimate minus truth, see the module docstring).

        ``R <- exp(-[dtheta_enu x]) R``, ``v <- v - dv_enu``, ``p <- p - dp_enu``.

        Parameters
        ----------
        dtheta_enu : array_like, shape (3,)
            Attitude error [rad]: ``R_est = exp([dtheta_enu x]) R_true``.
        dv_enu : array_like, shape (3,)
            Velocity error [m/s].
        dp_enu : array_like, shape (3,)
            Position error [m].
        """
        dth = np.asarray(dtheta_enu, dtype=float).reshape(3)
        self._q = _quat_mul_normalised(_rotvec_to_quat(-dth), self._q)
        self._v = self._v - np.asarray(dv_enu, dtype=float).reshape(3)
        self._p = self._p - np.asarray(dp_enu, dtype=float).reshape(3)

    # ------------------------------------------------------------ propagate
    def propagate(self, dt_s: ArrayLike, gyro_rad_s: ArrayLike,
                  accel_m_s2: ArrayLike) -> NavBatch:
        """Integrate N consecutive IMU samples (vectorised; no per-sample Python loop).

        Parameters
        ----------
        dt_s : array_like, shape (N,) or scalar
            Length of each sample's interval [s] (> 0).
        gyro_rad_s : array_like, shape (N, 3)
            Mean angular rate relative to inertial space over each interval, IMU frame.
        accel_m_s2 : array_like, shape (N, 3)
            Mean specific force over each interval, IMU frame.

        Returns
        -------
        NavBatch
            The state at the end of every interval; the navigator keeps the last one.

        Raises
        ------
        InputError
            Wrong shapes, non-finite values, or a non-positive ``dt_s``.
        """
        w = np.asarray(gyro_rad_s, dtype=float)
        f = np.asarray(accel_m_s2, dtype=float)
        if w.ndim != 2 or w.shape[1] != 3 or f.shape != w.shape:
            raise InputError(f'gyro_rad_s {w.shape} and accel_m_s2 {f.shape}: expected (N, 3)')
        n = w.shape[0]
        dt = np.broadcast_to(np.asarray(dt_s, dtype=float), (n,))
        if n == 0:
            e = np.zeros((0, 3))
            return NavBatch(np.zeros((0, 3, 3)), np.zeros((0, 4)), e, e.copy(), e.copy())
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(f))):
            raise InputError('gyro_rad_s/accel_m_s2: non-finite sample')
        if not (np.all(np.isfinite(dt)) and np.all(dt > 0.0)):
            raise InputError('dt_s: every interval must be finite and > 0')

        # previous sample's mean rates (memory across calls) for coning and sculling
        if self._prev_gyro is None or self._prev_accel is None:  # both set together
            w_prev = np.vstack([w[:1], w[:-1]])
            f_prev = np.vstack([f[:1], f[:-1]])
            dt_prev = np.concatenate([dt[:1], dt[:-1]])
            has_prev = np.ones(n)
            has_prev[0] = 0.0
        else:
            w_prev = np.vstack([self._prev_gyro, w[:-1]])
            f_prev = np.vstack([self._prev_accel, f[:-1]])
            dt_prev = np.concatenate([[self._prev_dt], dt[:-1]])
            has_prev = np.ones(n)
        # rates linear in time across the two intervals (Savage part 1 eq. 29, part 2 eq. 39):
        # coning = dt^3 / (6 (dt + dt_prev)) w_prev x w  (= dtheta_prev x dtheta / 12)
        k = (has_prev * dt ** 3 / (6.0 * (dt + dt_prev)))[:, None]
        phi = w * dt[:, None] + k * _cross(w_prev, w)

        # attitude: q_k = E(t_k) q_0 Q_k, E(t) = exp(-omega_ie t) (fixed axis: commutes)
        t_end = np.cumsum(dt)
        q_inc = Rotation.from_rotvec(phi).as_quat()
        q_body = _qmul(self._q, _quat_prefix_product(q_inc))
        half = -0.5 * self._earth_rate * t_end
        q_earth = np.empty((n, 4))
        q_earth[:, :3] = np.sin(half)[:, None] * self._earth_axis
        q_earth[:, 3] = np.cos(half)
        q = _qmul(q_earth, q_body)
        q /= np.linalg.norm(q, axis=1, keepdims=True)

        # specific-force increment: R(t) = R_{k-1} D(t), D driven by the rate relative to ENU
        # w - C(t)^T R_{k-1}^T omega_ie (C: body turn since t_{k-1}); the earth-rate part is
        # averaged over the interval from its ends (R_k^T omega_ie = C(dt)^T R_{k-1}^T omega_ie)
        # to O((w dt)^2), so the rotation and sculling terms need no separate earth term.
        R = Rotation.from_quat(q).as_matrix()
        R_start = np.concatenate([_quat_to_matrix(self._q)[None], R[:-1]])
        omega_ie_end = self._omega_ie_enu @ R  # R_k^T omega_ie
        omega_ie_start = np.vstack([self._omega_ie_enu @ R_start[0], omega_ie_end[:-1]])
        omega_ie_imu = 0.5 * (omega_ie_start + omega_ie_end)
        if self._prev_gyro is None:
            omega_ie_prev = np.vstack([omega_ie_imu[:1], omega_ie_imu[:-1]])
        else:
            omega_ie_prev = np.vstack([self._prev_omega_ie_imu, omega_ie_imu[:-1]])
        w_rel = w - omega_ie_imu
        dtheta = w_rel * dt[:, None]
        dv = f * dt[:, None]
        scul = k * (_cross(w_prev - omega_ie_prev, f) + _cross(f_prev, w_rel))
        th_x_dv = _cross(dtheta, dv)
        a1, a2 = _rotation_coefficients(np.einsum('ij,ij->i', dtheta, dtheta))
        dv_body = dv + a1[:, None] * th_x_dv + a2[:, None] * _cross(dtheta, th_x_dv) + scul
        dv_enu = (R_start @ dv_body[:, :, None])[:, :, 0]
        f_enu = dv_enu / dt[:, None]

        # velocity: v_k = C(dt_k) v_{k-1} + C(dt_k / 2) b_k with C(t) = exp(-2 omega_ie t)
        # => v_k = C(t_k) [v_0 + sum_j C(-(t_j - dt_j / 2)) b_j]  (closed form, no loop)
        b = dv_enu + self._g_enu * dt[:, None]
        two_rate = 2.0 * self._earth_rate
        acc = np.cumsum(_rotate_about_axis(self._earth_axis, two_rate * (t_end - 0.5 * dt), b),
                        axis=0)
        v = _rotate_about_axis(self._earth_axis, -two_rate * t_end, acc + self._v)

        # position: trapezoid
        v_start = np.vstack([self._v, v[:-1]])
        p = self._p + np.cumsum(0.5 * (v_start + v) * dt[:, None], axis=0)

        self._q = q[-1].copy()
        self._v = v[-1].copy()
        self._p = p[-1].copy()
        self._prev_gyro = w[-1].copy()
        self._prev_accel = f[-1].copy()
        self._prev_dt = float(dt[-1])
        self._prev_omega_ie_imu = omega_ie_imu[-1].copy()
        return NavBatch(R, q, v, p, f_enu)
