"""Kozlov & Kapralov's size-effect calibration by harmonic heading oscillations: the formulas.

Kozlov, Kapralov, "Millimeter-level calibration of IMU size effect" (seed
``000_48e8c74b179d4ba1.txt``). The IMU oscillates about a vertical axis,
``psi = psi_0 + A sin(2 pi t / T)`` (eq. 2; a cosine phase gives the same period means), with
one IMU axis (close to) vertical. An uncompensated size effect makes the navigated
horizontal acceleration biased on average, and the bias is the lever arm divided by
``c(A, T)`` (eq. 6). One module so that the simulator tests, the oscillation method and the
reports use the one formula.

The signs of the paper's eqs. 3-9 are in its airborne frame (X forward, Y up, Z lateral)
and its heading convention; :func:`size_effect_mean_acceleration_enu` derives them afresh
for ENU and the IMU frame of CONTRACT section 3 (see its docstring), and the tests check
the result against the simulator and navigator.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import j1

FloatArray = NDArray[np.float64]

__all__ = ['kozlov_c', 'kozlov_difference_factor', 'size_effect_mean_acceleration_enu',
           'size_effect_from_mean_acceleration']

#: First positive zero of J1: beyond it c(A, T) changes sign (and is infinite at it).
_J1_FIRST_ZERO = 3.8317059702075125


def kozlov_c(amplitude_rad: float, period_s: float) -> float:
    """Kozlov's oscillation coefficient ``c(A, T) = T^2 / (4 pi^2 A J1(A))`` [s^2] (eq. 6).

    ``1 / c = A W^2 J1(A)`` (``W = 2 pi / T``) is minus the period mean of
    ``psi_ddot sin(psi - psi_0)``; a lever arm ``r`` gives a mean navigated acceleration
    ``r / c``. For A = 90 deg, T = 5 s: 0.711 s^2 (the paper's "around 0.7").

    Parameters
    ----------
    amplitude_rad : float
        Oscillation amplitude A [rad], in (0, 3.83) (J1's first zero).
    period_s : float
        Oscillation period T [s], > 0.

    Raises
    ------
    ValueError
        If ``amplitude_rad`` or ``period_s`` is out of range (named in the message).
    """
    a = float(amplitude_rad)
    t = float(period_s)
    if not (math.isfinite(a) and 0.0 < a < _J1_FIRST_ZERO):
        raise ValueError(f'amplitude_rad {a!r} must be in (0, {_J1_FIRST_ZERO:.4f}) rad')
    if not (math.isfinite(t) and t > 0.0):
        raise ValueError(f'period_s {t!r} must be > 0')
    return t * t / (4.0 * math.pi ** 2 * a * float(j1(a)))


def kozlov_difference_factor(amplitude_rad: float, period1_s: float, period2_s: float) -> float:
    """Factor ``c1 c2 / (c2 - c1)`` [s^2] of the two-period difference (eq. 10, corrected).

    With ``<a>(T) = r / c(A, T) + e`` (``e`` the instrumental part that does not depend on
    ``T``), ``r = c1 c2 / (c2 - c1) (<a>(T1) - <a>(T2))`` in the IMU's centre-heading frame.
    The extracted paper's ``c1 - c2`` is wrong (docs: METHODS.md section 2). For
    A = 90 deg, T1 = 5 s, T2 = 10 s: 0.948 s^2.
    """
    c1 = kozlov_c(amplitude_rad, period1_s)
    c2 = kozlov_c(amplitude_rad, period2_s)
    if c1 == c2:
        raise ValueError(f'period1_s and period2_s must differ, both {period1_s!r}')
    return c1 * c2 / (c2 - c1)


def size_effect_mean_acceleration_enu(size_effect_m: ArrayLike, R_enu_imu_center: ArrayLike,
                                      amplitude_rad: float, period_s: float) -> FloatArray:
    """Period-mean navigated acceleration error [m/s^2, ENU] from an uncompensated size effect.

    Derivation (our frames; replaces Kozlov eqs. 3-9). The IMU turns about the ENU vertical
    ``z = (0, 0, 1)``: ``R(t) = Rot_z(phi) R_c`` with ``phi = psi - psi_0 = A sin(W t)``,
    ``W = 2 pi / T``, ``R_c`` the attitude at the centre heading. In the IMU frame the rate is
    ``psi_dot u`` with ``u = R_c^T z`` (earth rate neglected: its products with ``psi_dot``
    are 1e-4 of the effect). CONTRACT section 3: accelerometer i at ``r_i`` reads
    ``f_i + (omega_dot x r_i + omega x (omega x r_i))_i``, so the navigator, fed the raw
    outputs, sees the extra specific force ``df = psi_ddot d + psi_dot^2 e`` with::

        d_i = (u x r_i)_i,    e_i = (u x (u x r_i))_i = u_i (u . r_i) - |u|^2 r_ii

    mapped to ENU by ``Rot_z(phi) R_c``. Period means (J1 = Bessel function; checked
    numerically in the tests): ``<psi_ddot cos phi> = 0``, ``<psi_ddot sin phi> = -A W^2 J1(A)
    = -1/c``, ``<psi_ddot> = 0``, ``<psi_dot^2 cos phi> = A W^2 J1(A) = 1/c``,
    ``<psi_dot^2 sin phi> = 0``, ``<psi_dot^2> = A^2 W^2 / 2``. With ``Rot_z(phi) = cos phi P
    + sin phi [z x] + z z^T`` (``P`` the horizontal projector)::

        <da_enu> = -(1/c) z x (R_c d) + (1/c) P R_c e + (A^2 W^2 / 2) z z^T R_c e

    For IMU axis k exactly up or down and (i, j, k) cyclic, ``e`` is zero (``r_kk = 0``) and
    ``d = s (-r_ij e_i + r_ji e_j)`` (``s = +-1``), which gives, independent of ``s``::

        <da_enu> = (1/c) R_c (r_ji e_i + r_ij e_j)

    i.e. in the IMU frame at the centre heading, the mean acceleration along horizontal axis
    m is ``r_nm / c``, n the other horizontal axis (accelerometer n's lever arm along m).
    Example: z up, only ``r_xy`` (accelerometer x displaced along y): ``r_xy / c`` along the
    IMU's y axis at the centre heading.

    Parameters
    ----------
    size_effect_m : array_like, shape (3, 3)
        Row i = ``r_i`` (CONTRACT section 3), zero diagonal expected.
    R_enu_imu_center : array_like, shape (3, 3)
        IMU attitude at the centre heading ``psi_0``.
    amplitude_rad, period_s : float
        Oscillation amplitude A and period T.

    Returns
    -------
    ndarray, shape (3,)
        ``<da_enu>``, the bias of the navigated acceleration (estimate minus truth).
    """
    r = np.asarray(size_effect_m, dtype=float).reshape(3, 3)
    Rc = np.asarray(R_enu_imu_center, dtype=float).reshape(3, 3)
    z = np.array([0.0, 0.0, 1.0])
    u = Rc.T @ z
    c = kozlov_c(amplitude_rad, period_s)
    d = np.array([np.cross(u, r[i])[i] for i in range(3)])
    e = np.array([np.cross(u, np.cross(u, r[i]))[i] for i in range(3)])
    w = 2.0 * math.pi / float(period_s)
    P = np.diag([1.0, 1.0, 0.0])
    return (-np.cross(z, Rc @ d) / c + P @ (Rc @ e) / c
            + 0.5 * (float(amplitude_rad) * w) ** 2 * z * (z @ Rc @ e))


def size_effect_from_mean_acceleration(a_mean_enu: ArrayLike, R_enu_imu_center: ArrayLike,
                                       amplitude_rad: float, period_s: float) -> FloatArray:
    """The two lever arms one oscillation cycle observes (inverse of the rule above).

    Parameters
    ----------
    a_mean_enu : array_like, shape (3,)
        Period-mean navigated acceleration [m/s^2] over whole oscillation periods (e.g. the
        slope of the navigated velocity), instrumental part removed or differenced away.
    R_enu_imu_center : array_like, shape (3, 3)
        IMU attitude at the centre heading; one IMU axis must be within 0.1 rad of vertical.
    amplitude_rad, period_s : float
        Oscillation amplitude and period.

    Returns
    -------
    ndarray, shape (3, 3)
        ``r`` with the two observed entries ``r_nm = c (R_c^T a)_m`` (m, n the horizontal
        IMU axes) and NaN elsewhere.

    Raises
    ------
    ValueError
        If no IMU axis is within 0.1 rad of the vertical.
    """
    Rc = np.asarray(R_enu_imu_center, dtype=float).reshape(3, 3)
    a_imu = Rc.T @ np.asarray(a_mean_enu, dtype=float).reshape(3)
    u = Rc.T @ np.array([0.0, 0.0, 1.0])
    k = int(np.argmax(np.abs(u)))
    if abs(u[k]) < math.cos(0.1):
        raise ValueError('R_enu_imu_center: no IMU axis within 0.1 rad of the vertical')
    c = kozlov_c(amplitude_rad, period_s)
    out = np.full((3, 3), np.nan)
    i, j = (k + 1) % 3, (k + 2) % 3
    out[j, i] = c * a_imu[i]
    out[i, j] = c * a_imu[j]
    return out
