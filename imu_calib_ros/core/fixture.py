"""The fixture (turntable or robot arm) of CONTRACT section 2 and the exact kinematics of its
chain.

``R_enu_imu = Rot(a_1, q_1) ... Rot(a_n, q_n) R_rpy``: joint ``i`` turns about its axis
``a_i``, given in its parent frame (the first joint's parent is the site's ENU frame); the
IMU body frame sits in the innermost joint frame with the nominal attitude ``R_rpy`` and its
reference point at ``xyz_m`` from the axes' common point, which is fixed to the earth.

Kinematics (rigid-body chain, e.g. Siciliano et al., "Robotics", 2009, sect. 3.1, written
for revolute joints about one fixed point). With ``R_i = Rot(a_1, q_1) ... Rot(a_i, q_i)``
and ``u_i = R_{i-1} a_i`` joint ``i``'s axis in ENU::

    omega_eb = sum_i u_i qd_i                                  (ENU, relative to the earth)
    d/dt omega_eb = sum_i (u_i qdd_i + (omega_{i-1} x u_i) qd_i),  omega_{i-1} = sum_{j<i} u_j qd_j
    omega_ib_imu = R_imu_enu (omega_ie + omega_eb)             (earth rate added)
    omega_dot_ib_imu = R_imu_enu (d/dt omega_eb + omega_ie x omega_eb)
    p = R_n xyz,  v = omega_eb x p,  a = d/dt omega_eb x p + omega_eb x (omega_eb x p)
    f_imu = R_imu_enu (a + 2 omega_ie x v - g_enu)

General chains (issue 15: a robot arm from its URDF, :mod:`.urdf_fixture`): joint ``i`` may
have a fixed origin ``(xyz_i, R_o,i)`` in its parent frame (URDF ``<origin>``) and may be
prismatic. With ``O_i`` the origin of joint frame ``i`` in ENU (``O_0 = 0``, the base),
``R'_i = R_{i-1} R_o,i``, ``u_i = R'_i a_i`` and ``r_i = O_i - O_{i-1} = R_{i-1} xyz_i (+ u_i q_i
for a prismatic joint)``, the outward recursion (Siciliano et al. sect. 3.1, 7.5; Featherstone,
"Rigid body dynamics algorithms", 2008, ch. 3) is::

    R_i = R'_i Rot(a_i, q_i)   (prismatic: R_i = R'_i)
    w_i = w_{i-1} + u_i qd_i,  wd_i = wd_{i-1} + u_i qdd_i + w_{i-1} x u_i qd_i   (revolute)
    v_O,i = v_O,i-1 + w_{i-1} x r_i (+ u_i qd_i)
    a_O,i = a_O,i-1 + wd_{i-1} x r_i + w_{i-1} x (w_{i-1} x r_i)
            (+ 2 w_{i-1} x u_i qd_i + u_i qdd_i)                                   (prismatic)
    p = O_n + R_n xyz,  v = v_O,n + w_n x (R_n xyz),  a = a_O,n + wd_n x r + w_n x (w_n x r)

The estimator's velocity measurement compares the navigated velocity with the *anchor*'s plus
``R_enu_imu (omega_eb x rho)``: on a turntable (CONTRACT 2 without origins: every ``O_i = 0``,
the formulas above reduce to the turntable's, bit for bit, the general terms skipped) the
anchor is the axes' common point and ``rho`` the IMU point from it; on a general chain the
anchor is the nominal IMU point ``p(q)`` (from the encoders) and ``rho`` only the mounting's
offset from it (:attr:`Fixture.lever_arm_imu_m`).

``omega_dot_ib_imu`` is the time derivative of the components of ``omega_ib_imu``
(which equals the inertial derivative expressed in the IMU frame). In ``f`` the term
``omega_ie x (omega_ie x p)`` (< 1e-11 m/s^2 for p ~ 1 mm) is neglected; normal gravity
already contains the centrifugal acceleration at the site.
"""
from __future__ import annotations

import dataclasses
import math
import os
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import load_yaml, require_mapping, vector
from .earth import Site
from .errors import ConfigError
from .rotation import matrix_to_rpy, rot_axis_angle, rotvec_to_matrix, rpy_to_matrix

FloatArray = NDArray[np.float64]

#: An axis whose norm differs from 1 by more than this is an error (below: normalised).
AXIS_NORM_TOLERANCE = 1e-3
#: Consecutive axes with |a_i x a_{i+1}| below this are parallel (a degenerate chain).
PARALLEL_AXES_TOLERANCE = 1e-3


def _frozen(a: ArrayLike) -> FloatArray:
    out = np.array(a, dtype=float)
    out.setflags(write=False)
    return out


JOINT_TYPES = ('revolute', 'continuous', 'prismatic')


@dataclass(frozen=True, eq=False)
class Joint:
    """One joint: a name, a unit axis in its own frame and, for general chains, a fixed origin.

    ``origin_xyz_m`` and ``origin_R`` (URDF ``<origin>``: the joint frame at ``q = 0`` in its
    parent frame; ``None``: at the parent's origin, unrotated, as in CONTRACT 2), ``kind``
    one of :data:`JOINT_TYPES` (a prismatic joint moves along ``axis`` by ``q`` metres), and
    the URDF limits (``None``: unlimited): ``lower``/``upper`` [rad or m], ``velocity``
    [rad/s or m/s], ``effort`` [N m or N].
    """

    name: str
    axis: FloatArray  # (3,), unit
    kind: str = 'revolute'
    origin_xyz_m: FloatArray | None = None
    origin_R: FloatArray | None = None
    lower: float | None = None
    upper: float | None = None
    velocity: float | None = None
    effort: float | None = None

    def __post_init__(self) -> None:
        axis = np.asarray(self.axis, dtype=float)
        if axis.shape != (3,) or abs(np.linalg.norm(axis) - 1.0) > 1e-9:
            raise ValueError(f'joint {self.name!r}: axis must be a unit 3-vector, got {axis}')
        object.__setattr__(self, 'axis', _frozen(axis))
        if self.kind not in JOINT_TYPES:
            raise ValueError(f'joint {self.name!r}: type {self.kind!r} not in {JOINT_TYPES}')
        if self.origin_xyz_m is not None:
            xyz = np.asarray(self.origin_xyz_m, dtype=float)
            if xyz.shape != (3,) or not np.all(np.isfinite(xyz)):
                raise ValueError(f'joint {self.name!r}: origin_xyz_m must be a finite 3-vector')
            object.__setattr__(self, 'origin_xyz_m', None if not np.any(xyz) else _frozen(xyz))
        if self.origin_R is not None:
            R = np.asarray(self.origin_R, dtype=float)
            if R.shape != (3, 3) or np.abs(R @ R.T - np.eye(3)).max() > 1e-9 \
                    or np.linalg.det(R) < 0:
                raise ValueError(f'joint {self.name!r}: origin_R must be a rotation matrix')
            object.__setattr__(self, 'origin_R', None if np.array_equal(R, np.eye(3))
                               else _frozen(R))
        if self.lower is not None and self.upper is not None and self.lower > self.upper:
            raise ValueError(f'joint {self.name!r}: lower limit {self.lower} > upper '
                             f'{self.upper}')

    @property
    def revolute(self) -> bool:
        """True for revolute and continuous joints (they turn the IMU)."""
        return self.kind != 'prismatic'

    @property
    def has_limits(self) -> bool:
        """True if the joint has a position limit."""
        return self.lower is not None or self.upper is not None


@dataclass(frozen=True, eq=False)
class Kinematics:
    """Exact motion of the IMU at ``N`` time points (all arrays have leading shape (N,)).

    Attributes
    ----------
    R_enu_imu : (N, 3, 3)
        IMU attitude.
    omega_ib_imu_rad_s : (N, 3)
        Angular rate of the IMU relative to inertial space (earth rate included), IMU frame.
    omega_dot_ib_imu_rad_s2 : (N, 3)
        Time derivative of ``omega_ib_imu_rad_s``.
    p_enu_m, v_enu_m_s, a_enu_m_s2 : (N, 3)
        Position, velocity and acceleration of the IMU reference point relative to the
        earth-fixed common point of the axes, in ENU.
    f_imu_m_s2 : (N, 3)
        Specific force at the IMU reference point, IMU frame.
    omega_eb_enu_rad_s : (N, 3)
        Angular rate of the IMU relative to the earth (ENU frame), in ENU.
    """

    R_enu_imu: FloatArray
    omega_ib_imu_rad_s: FloatArray
    omega_dot_ib_imu_rad_s2: FloatArray
    p_enu_m: FloatArray
    v_enu_m_s: FloatArray
    a_enu_m_s2: FloatArray
    f_imu_m_s2: FloatArray
    omega_eb_enu_rad_s: FloatArray


@dataclass(frozen=True, eq=False)
class Fixture:
    """A turntable: site, joint chain (outermost first) and nominal IMU mounting.

    Parameters
    ----------
    site : Site
    joints : tuple of Joint
        Outermost first; at least one.
    imu_rpy_rad : (3,)
        IMU body frame in the innermost joint frame at zero angles (roll, pitch, yaw).
    imu_xyz_m : (3,)
        IMU reference point in the innermost joint frame, from the axes' common point.
    source : str or None
        The file it came from (for messages only).
    """

    site: Site
    joints: tuple[Joint, ...]
    imu_rpy_rad: FloatArray
    imu_xyz_m: FloatArray
    source: str | None = None

    def __post_init__(self) -> None:
        if not self.joints:
            raise ValueError('a fixture needs at least one joint')
        object.__setattr__(self, 'joints', tuple(self.joints))
        object.__setattr__(self, 'imu_rpy_rad', _frozen(self.imu_rpy_rad))
        object.__setattr__(self, 'imu_xyz_m', _frozen(self.imu_xyz_m))
        if self.imu_rpy_rad.shape != (3,) or self.imu_xyz_m.shape != (3,):
            raise ValueError('imu_rpy_rad and imu_xyz_m must have shape (3,)')
        object.__setattr__(self, '_R_joint_imu', _frozen(rpy_to_matrix(self.imu_rpy_rad)))

    # ----------------------------------------------------------------------------- basics
    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint names, outermost first."""
        return tuple(j.name for j in self.joints)

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return len(self.joints)

    @property
    def R_joint_imu(self) -> FloatArray:
        """Nominal IMU attitude in the innermost joint frame, ``R_rpy`` (3, 3)."""
        return self._R_joint_imu  # type: ignore[attr-defined,no-any-return]

    @property
    def concurrent(self) -> bool:
        """True if every axis passes through the base origin (a turntable, CONTRACT 2 without
        origins): no joint has an origin offset and none is prismatic."""
        return all(j.origin_xyz_m is None and j.revolute for j in self.joints)

    @property
    def lever_arm_imu_m(self) -> FloatArray:
        """Nominal IMU reference point from the anchor, IMU frame: the nominal value of the
        estimator's lever-arm state. A turntable: from the axes' common point; a general
        chain: zero (its anchor is the nominal IMU point itself, so the state is only the
        mounting's offset, millimetres: the gyro errors times a lever of decimetres would
        otherwise corrupt the velocity measurement)."""
        if self.concurrent:
            return self.R_joint_imu.T @ self.imu_xyz_m  # type: ignore[no-any-return]
        return np.zeros(3)

    @property
    def revolute_mask(self) -> FloatArray:
        """(n,) 1.0 for joints that turn the IMU, 0.0 for prismatic ones."""
        return np.array([1.0 if j.revolute else 0.0 for j in self.joints])

    def joint_index(self, name: str) -> int:
        """Index of the joint called ``name`` (``KeyError`` naming the known joints)."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise KeyError(f'no joint {name!r} (joints: {", ".join(self.joint_names)})') from None

    def with_mounting(self, drpy_rad: ArrayLike, dxyz_m: ArrayLike) -> 'Fixture':
        """The same fixture with the IMU mounted slightly differently.

        ``R_joint_imu_true = R_joint_imu @ rpy_to_matrix(drpy_rad)`` (a small rotation in
        the IMU frame) and ``xyz_true = xyz + dxyz_m`` (innermost joint frame).
        """
        R_true = self.R_joint_imu @ rpy_to_matrix(np.asarray(drpy_rad, dtype=float))
        return Fixture(self.site, self.joints, matrix_to_rpy(R_true),
                       self.imu_xyz_m + np.asarray(dxyz_m, dtype=float), self.source)

    def with_base_tilt(self, tilt_en_rad: ArrayLike) -> 'Fixture':
        """The same fixture on a base that is not levelled: the first joint's parent frame
        turned by the rotation vector ``(t_e, t_n, 0)`` in ENU (``R_enu_base``), everything
        after it with it. A fixture file's first axis is in ENU (CONTRACT 2); a real table
        stands a fraction of a milliradian to a degree off level, which only gravity shows
        (the IMU-frame rates do not depend on it: :func:`.estimator.coarse.fit_joint_zeros`).
        """
        t = np.asarray(tilt_en_rad, dtype=float)
        if t.shape != (2,) or not np.all(np.isfinite(t)):
            raise ValueError(f'a base tilt is two finite angles [rad], got {t}')
        if not np.any(t):
            return self
        R_tilt = rotvec_to_matrix(np.array([t[0], t[1], 0.0]))
        j0 = self.joints[0]
        first = dataclasses.replace(
            j0, origin_R=R_tilt if j0.origin_R is None else R_tilt @ j0.origin_R)
        return self.with_joints((first,) + self.joints[1:])

    def with_joints(self, joints: 'tuple[Joint, ...]') -> 'Fixture':
        """The same fixture (site, IMU mounting) with another joint chain (e.g. an arm with
        link-length and zero-offset errors, :func:`perturbed_chain`)."""
        return Fixture(self.site, tuple(joints), self.imu_rpy_rad, self.imu_xyz_m, self.source)

    # ------------------------------------------------------------------------- kinematics
    def _check_q(self, q: ArrayLike, what: str = 'q') -> FloatArray:
        q = np.asarray(q, dtype=float)
        if q.ndim == 0 or q.shape[-1] != self.n_joints:
            raise ValueError(f'{what} must have shape (..., {self.n_joints}), got {q.shape}')
        return q

    def _chain(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``R_n`` (..., 3, 3) and the joint axes in ENU ``u`` (..., n, 3)."""
        R = np.broadcast_to(np.eye(3), q.shape[:-1] + (3, 3))
        axes = []
        for i, joint in enumerate(self.joints):
            if joint.origin_R is not None:
                R = R @ joint.origin_R
            axes.append(R @ joint.axis)
            if joint.revolute:
                R = R @ rot_axis_angle(joint.axis, q[..., i])
        return np.array(R), np.stack(axes, axis=-2)

    def _origins(self, q: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``R_n``, axes ``u`` (..., n, 3) and joint-frame origins ``O`` (..., n, 3) in ENU."""
        R = np.broadcast_to(np.eye(3), q.shape[:-1] + (3, 3))
        O = np.zeros(q.shape[:-1] + (3,))
        axes, origins = [], []
        for i, joint in enumerate(self.joints):
            if joint.origin_xyz_m is not None:
                O = O + R @ joint.origin_xyz_m
            if joint.origin_R is not None:
                R = R @ joint.origin_R
            u = R @ joint.axis
            axes.append(u)
            if joint.revolute:
                R = R @ rot_axis_angle(joint.axis, q[..., i])
            else:
                O = O + u * q[..., i, None]
            origins.append(O)
        return np.array(R), np.stack(axes, axis=-2), np.stack(origins, axis=-2)

    def R_enu_joint(self, q: ArrayLike) -> FloatArray:
        """Attitude of the innermost joint frame, ``Rot(a_1, q_1) ... Rot(a_n, q_n)``."""
        return self._chain(self._check_q(q))[0]

    def R_enu_imu(self, q: ArrayLike) -> FloatArray:
        """IMU attitude for joint angles ``q`` (..., n) -> (..., 3, 3)."""
        return self.R_enu_joint(q) @ self.R_joint_imu

    def p_enu_m(self, q: ArrayLike) -> FloatArray:
        """IMU reference point in ENU for joint angles ``q`` (..., n) -> (..., 3), from the
        base origin (a turntable: the axes' common point)."""
        q = self._check_q(q)
        if self.concurrent:
            return self.R_enu_joint(q) @ self.imu_xyz_m
        R_n, _, O = self._origins(q)
        return O[..., -1, :] + R_n @ self.imu_xyz_m  # type: ignore[no-any-return]

    def anchor_enu_m(self, q: ArrayLike) -> FloatArray:
        """The anchor in ENU, (..., 3): a turntable's axes' common point (zero); a general
        chain's nominal IMU reference point (:attr:`lever_arm_imu_m`)."""
        q = self._check_q(q)
        if self.concurrent:
            return np.zeros(q.shape[:-1] + (3,))
        return self.p_enu_m(q)

    def anchor_velocity_enu_m_s(self, q: ArrayLike, qd: ArrayLike) -> FloatArray:
        """Velocity of the anchor in ENU (relative to the earth), (..., 3); zero on a turntable.

        The estimator's velocity measurement is this plus ``R_enu_imu (omega_eb x rho)``,
        ``rho`` the lever arm from the anchor (:func:`.estimator.measurements.zero_velocity`).
        """
        q = self._check_q(q)
        qd = self._check_q(qd, 'qd')
        if self.concurrent:
            return np.zeros(q.shape[:-1] + (3,))
        R_n, w, _, _, v_O, _ = self._motion(q, qd, np.zeros_like(qd))
        return v_O + np.cross(w, R_n @ self.imu_xyz_m)  # type: ignore[no-any-return]

    def anchor_velocity_jacobian_q(self, q: ArrayLike, qd: ArrayLike) -> FloatArray:
        """``d v_anchor / d q`` (..., 3, n) at fixed rates ``qd``: what a joint zero offset
        does to :meth:`anchor_velocity_enu_m_s` (issue 15, the offsets as filter states).

        With ``v = sum_i c_i``, ``c_i = u_i qd_i x (p - O_i)`` (revolute) or ``u_i qd_i``
        (prismatic; module docstring), turning joint ``j`` by ``dq`` turns every frame beyond
        it about ``u_j`` through ``O_j``: the terms ``i >= j`` turn with it and the IMU point
        ``p`` moves by ``u_j x (p - O_j) dq``, which the joints before ``j`` see. Hence::

            dv/dq_j = u_j x (v - v_<j) + w_<j x (u_j x (p - O_j))     (revolute j)
            dv/dq_j = w_<j x u_j                                      (prismatic j)

        ``v_<j = sum_{i<j} c_i``, ``w_<j = sum_{i<j} u_i qd_i``. Exactly linear in ``qd``
        (zero at rest); zero on a turntable. Checked by finite differences
        (``test/test_chain.py``).
        """
        q = self._check_q(q)
        qd = self._check_q(qd, 'qd')
        J = np.zeros(q.shape[:-1] + (3, self.n_joints))
        if self.concurrent:
            return J
        R_n, u, O = self._origins(q)
        p = O[..., -1, :] + R_n @ self.imu_xyz_m
        v = self.anchor_velocity_enu_m_s(q, qd)
        w = np.zeros(q.shape[:-1] + (3,))
        v_before = np.zeros_like(w)
        for j, joint in enumerate(self.joints):
            uj, qdj = u[..., j, :], qd[..., j, None]
            if joint.revolute:
                r = p - O[..., j, :]
                J[..., :, j] = np.cross(uj, v - v_before) + np.cross(w, np.cross(uj, r))
                v_before = v_before + np.cross(uj * qdj, r)
                w = w + uj * qdj
            else:
                J[..., :, j] = np.cross(w, uj)
                v_before = v_before + uj * qdj
        return J

    def angular_axes_enu(self, q: ArrayLike) -> FloatArray:
        """Joint axes in ENU with prismatic joints' rows zero: ``omega_eb = sum_i u_i qd_i``
        over this, (..., n, 3)."""
        u = self.joint_axes_enu(q)
        if self.concurrent:
            return u
        return u * self.revolute_mask[:, None]  # type: ignore[no-any-return]

    def check_limits(self, q: ArrayLike, qd: ArrayLike | None = None,
                     tol: float = 1e-9) -> str | None:
        """``None`` if ``q`` (..., n) (and ``qd``) stay within every joint's URDF limits, else
        one line naming the first joint and the limit it violates, with the value."""
        q = np.asarray(q, dtype=float).reshape(-1, self.n_joints)
        unit = ('m', 'm/s')
        for i, j in enumerate(self.joints):
            u = unit if not j.revolute else ('deg', 'deg/s')
            k = 1.0 if not j.revolute else math.degrees(1.0)
            lo, hi = float(q[:, i].min()), float(q[:, i].max())
            if j.lower is not None and lo < j.lower - tol:
                return (f'joint {j.name!r} would reach {lo * k:.4g} {u[0]}, below its lower '
                        f'limit {j.lower * k:.4g} {u[0]}')
            if j.upper is not None and hi > j.upper + tol:
                return (f'joint {j.name!r} would reach {hi * k:.4g} {u[0]}, above its upper '
                        f'limit {j.upper * k:.4g} {u[0]}')
            if qd is not None and j.velocity is not None:
                vmax = float(np.abs(np.asarray(qd, float).reshape(-1, self.n_joints)[:, i]).max())
                if vmax > j.velocity * (1 + 1e-9) + tol:
                    return (f'joint {j.name!r} would move at {vmax * k:.4g} {u[1]}, above its '
                            f'velocity limit {j.velocity * k:.4g} {u[1]}')
        return None

    def joint_axes_enu(self, q: ArrayLike) -> FloatArray:
        """Each joint's axis in ENU, ``u_i = R_{i-1} a_i``, shape (..., n, 3)."""
        return self._chain(self._check_q(q))[1]

    def joint_axes_imu(self, q: ArrayLike) -> FloatArray:
        """Each joint's axis in the IMU frame, shape (..., n, 3)."""
        q = self._check_q(q)
        R_n, u = self._chain(q)
        R_imu_enu = np.swapaxes(R_n @ self.R_joint_imu, -1, -2)
        return np.einsum('...ij,...kj->...ki', R_imu_enu, u)

    def kinematics(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> Kinematics:
        """Exact IMU motion from joint angles, rates and accelerations (see module docstring).

        Parameters
        ----------
        q, qd, qdd : array_like, shape (N, n)
            Joint angles [rad], rates [rad/s] and accelerations [rad/s^2].

        Returns
        -------
        Kinematics
        """
        q = self._check_q(q)
        qd = self._check_q(qd, 'qd')
        qdd = self._check_q(qdd, 'qdd')
        if self.concurrent:
            R_n, u = self._chain(q)
            w = np.zeros(q.shape[:-1] + (3,))
            wdot = np.zeros_like(w)
            for i in range(self.n_joints):
                ui = u[..., i, :]
                wdot = wdot + ui * qdd[..., i, None] + np.cross(w, ui) * qd[..., i, None]
                w = w + ui * qd[..., i, None]
            p = R_n @ self.imu_xyz_m
            v = np.cross(w, p)
            a = np.cross(wdot, p) + np.cross(w, v)
        else:
            R_n, w, wdot, O_n, v_O, a_O = self._motion(q, qd, qdd)
            r = R_n @ self.imu_xyz_m
            p = O_n + r
            w_r = np.cross(w, r)
            v = v_O + w_r
            a = a_O + np.cross(wdot, r) + np.cross(w, w_r)
        R = R_n @ self.R_joint_imu
        R_T = np.swapaxes(R, -1, -2)
        omega_ie = self.site.omega_ie_enu
        f_enu = a + 2.0 * np.cross(omega_ie, v) - self.site.g_enu

        def to_imu(x: FloatArray) -> FloatArray:
            return np.einsum('...ij,...j->...i', R_T, x)

        return Kinematics(
            R_enu_imu=R,
            omega_ib_imu_rad_s=to_imu(omega_ie + w),
            omega_dot_ib_imu_rad_s2=to_imu(wdot + np.cross(omega_ie, w)),
            p_enu_m=p, v_enu_m_s=v, a_enu_m_s2=a,
            f_imu_m_s2=to_imu(f_enu),
            omega_eb_enu_rad_s=w,
        )

    def _motion(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> tuple[
            FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """The general outward recursion (module docstring): ``R_n``, ``w_n``, ``wd_n``
        (ENU, relative to the earth) and the anchor's position, velocity, acceleration."""
        R = np.broadcast_to(np.eye(3), q.shape[:-1] + (3, 3))
        shape = q.shape[:-1] + (3,)
        O, v, a = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        w, wd = np.zeros(shape), np.zeros(shape)
        for i, joint in enumerate(self.joints):
            r = np.zeros(shape) if joint.origin_xyz_m is None else R @ joint.origin_xyz_m
            if joint.origin_R is not None:
                R = R @ joint.origin_R
            u = R @ joint.axis
            qi, qdi, qddi = q[..., i, None], qd[..., i, None], qdd[..., i, None]
            if not joint.revolute:
                r = r + u * qi
            w_r = np.cross(w, r)
            O = O + r
            v = v + w_r
            a = a + np.cross(wd, r) + np.cross(w, w_r)
            if joint.revolute:
                wd = wd + u * qddi + np.cross(w, u) * qdi
                w = w + u * qdi
                R = R @ rot_axis_angle(joint.axis, q[..., i])
            else:
                v = v + u * qdi
                a = a + 2.0 * np.cross(w, u) * qdi + u * qddi
        return np.array(R), w, wd, O, v, a

    # ------------------------------------------------------------------------------- files
    def to_dict(self) -> dict[str, Any]:
        """The CONTRACT section 2 mapping (degrees in the file); a joint's optional keys
        (``type``, ``origin_xyz_m``, ``origin_rpy_deg``, ``limits``) only where they are set."""
        joints = []
        for j in self.joints:
            d: dict[str, Any] = {'name': j.name, 'axis': [float(x) for x in j.axis]}
            if j.kind != 'revolute':
                d['type'] = j.kind
            if j.origin_xyz_m is not None:
                d['origin_xyz_m'] = [float(x) for x in j.origin_xyz_m]
            if j.origin_R is not None:
                with warnings.catch_warnings():  # gimbal lock: any valid rpy will do
                    warnings.simplefilter('ignore', UserWarning)
                    rpy = matrix_to_rpy(j.origin_R)
                d['origin_rpy_deg'] = [math.degrees(float(x)) for x in rpy]
            lim = {k: float(getattr(j, k)) for k in _LIMIT_KEYS if getattr(j, k) is not None}
            if lim:
                d['limits'] = lim
            joints.append(d)
        return {
            'site': self.site.to_dict(),
            'joints': joints,
            'imu': {'rpy_deg': [math.degrees(float(x)) for x in self.imu_rpy_rad],
                    'xyz_m': [float(x) for x in self.imu_xyz_m]},
        }

    @classmethod
    def from_yaml(cls, path: str | os.PathLike[str]) -> 'Fixture':
        """Load and validate a fixture file (CONTRACT section 2)."""
        return cls.from_dict(load_yaml(path), str(path))

    @classmethod
    def from_dict(cls, data: Any, source: str | None = None) -> 'Fixture':
        """Validate a CONTRACT section 2 mapping.

        Raises
        ------
        ConfigError
            Unknown or missing keys; no joints; a joint without a name, a duplicate name;
            an axis that is zero, or whose norm differs from 1 by more than
            :data:`AXIS_NORM_TOLERANCE` (smaller deviations are normalised away); two
            consecutive parallel axes; a bad ``site:`` block. The message names ``source``
            and the key, e.g. ``joints[1].axis``.
        """
        d = require_mapping(data, source, None)
        _check_keys(d, ('site', 'joints', 'imu'), ('site', 'joints', 'imu'), source, '')
        site = Site.from_dict(d['site'], source, 'site')
        raw_joints = d['joints']
        if not isinstance(raw_joints, list) or not raw_joints:
            raise ConfigError('expected a non-empty list of joints (outermost first)', source,
                              'joints')
        joints: list[Joint] = []
        for i, rj in enumerate(raw_joints):
            key = f'joints[{i}]'
            rj = require_mapping(rj, source, key)
            _check_keys(rj, ('name', 'axis', *_OPTIONAL_JOINT_KEYS), ('name', 'axis'), source,
                        key)
            name = rj['name']
            if not isinstance(name, str) or not name.strip():
                raise ConfigError(f'expected a non-empty string, got {name!r}', source,
                                  f'{key}.name')
            if name in (j.name for j in joints):
                raise ConfigError(f'duplicate joint name {name!r}', source, f'{key}.name')
            axis = np.array(vector(rj['axis'], 3, source, f'{key}.axis'))
            norm = math.hypot(*axis)  # no overflow for absurd values in a file
            if norm < 1e-9:
                raise ConfigError('zero axis', source, f'{key}.axis')
            if abs(norm - 1.0) > AXIS_NORM_TOLERANCE:
                raise ConfigError(f'axis is not a unit vector (norm {norm:.6g})', source,
                                  f'{key}.axis')
            axis = axis / norm
            joints.append(_joint_options(rj, name, axis, source, key))
        if all(j.origin_xyz_m is None and j.revolute for j in joints):
            # a turntable: the axes meet in one point, so two parallel axes in a row turn the
            # IMU about one line (a degenerate chain); an arm's parallel axes are offset
            for i in range(1, len(joints)):
                if np.linalg.norm(np.cross(joints[i - 1].axis, joints[i].axis)) < \
                        PARALLEL_AXES_TOLERANCE:
                    raise ConfigError(f'axis is parallel to the axis of joint '
                                      f'{joints[i - 1].name!r} (consecutive joints must turn '
                                      'about different axes)', source, f'joints[{i}].axis')
        imu = require_mapping(d['imu'], source, 'imu')
        _check_keys(imu, ('rpy_deg', 'xyz_m'), ('rpy_deg', 'xyz_m'), source, 'imu')
        rpy = np.radians(vector(imu['rpy_deg'], 3, source, 'imu.rpy_deg'))
        xyz = np.array(vector(imu['xyz_m'], 3, source, 'imu.xyz_m'))
        return cls(site, tuple(joints), rpy, xyz, source)


_LIMIT_KEYS = ('lower', 'upper', 'velocity', 'effort')
_OPTIONAL_JOINT_KEYS = ('type', 'origin_xyz_m', 'origin_rpy_deg', 'limits')


def _joint_options(rj: Any, name: str, axis: FloatArray, source: str | None,
                   key: str) -> Joint:
    """A joint with the optional keys of a general chain (issue 15): ``type`` (revolute,
    continuous, prismatic), ``origin_xyz_m`` and ``origin_rpy_deg`` (the joint frame in its
    parent frame at q = 0, URDF ``<origin>``), ``limits`` (lower/upper [rad or m], velocity,
    effort; URDF ``<limit>``)."""
    kind = rj.get('type', 'revolute')
    if kind not in JOINT_TYPES:
        raise ConfigError(f'unknown joint type {kind!r} (known: {", ".join(JOINT_TYPES)})',
                          source, f'{key}.type')
    xyz = (None if 'origin_xyz_m' not in rj
           else np.array(vector(rj['origin_xyz_m'], 3, source, f'{key}.origin_xyz_m')))
    R = (None if 'origin_rpy_deg' not in rj else rpy_to_matrix(np.radians(
        vector(rj['origin_rpy_deg'], 3, source, f'{key}.origin_rpy_deg'))))
    lim: dict[str, float] = {}
    if 'limits' in rj:
        ld = require_mapping(rj['limits'], source, f'{key}.limits')
        _check_keys(ld, _LIMIT_KEYS, (), source, f'{key}.limits')
        for k in _LIMIT_KEYS:
            if k in ld:
                lim[k] = vector([ld[k]], 1, source, f'{key}.limits.{k}')[0]
        for k in ('velocity', 'effort'):
            if k in lim and lim[k] <= 0:
                raise ConfigError('must be > 0', source, f'{key}.limits.{k}')
        if lim.get('lower', -math.inf) > lim.get('upper', math.inf):
            raise ConfigError('lower limit above the upper limit', source, f'{key}.limits')
    return Joint(name, axis, kind, xyz, R, **lim)


def _check_keys(d: Any, known: tuple[str, ...], required: tuple[str, ...], source: str | None,
                prefix: str) -> None:
    for k in d:
        if k not in known:
            raise ConfigError(f'unknown key (known keys: {", ".join(known)})', source,
                              f'{prefix}.{k}' if prefix else str(k))
    for k in required:
        if k not in d:
            raise ConfigError('missing required key', source, f'{prefix}.{k}' if prefix else k)


def load_fixture(name_or_path: str, urdf: Any = None) -> Fixture:
    """Load a fixture by path or by the name of a shipped file in ``config/fixtures/``.

    A ``.urdf`` file (or a shipped ``NAME.urdf`` when there is no ``NAME.yaml``, or URDF XML
    text) is read by :func:`.urdf_fixture.fixture_from_urdf` with ``urdf``, a
    :class:`~.urdf_fixture.UrdfOptions` (base and IMU links, site overrides).
    """
    from pathlib import Path

    from .config import resolve_config_file, share_dir
    from .urdf_fixture import UrdfOptions, fixture_from_urdf, is_urdf
    name = str(name_or_path)
    shipped_urdf = share_dir() / 'config' / 'fixtures' / (
        name if name.endswith('.urdf') else f'{name}.urdf')
    if is_urdf(name) or (not Path(name).is_file() and shipped_urdf.is_file() and not (
            share_dir() / 'config' / 'fixtures' / f'{name}.yaml').is_file()):
        path = name if (name.lstrip().startswith('<') or Path(name).is_file()
                        or not shipped_urdf.is_file()) else str(shipped_urdf)
        return fixture_from_urdf(path, urdf if urdf is not None else UrdfOptions())
    return Fixture.from_yaml(resolve_config_file(name, 'fixtures'))


def perturbed_chain(fixture: Fixture, rng: np.random.Generator, joint_offset_sigma_rad: float,
                    link_sigma_m: float) -> tuple[Fixture, FloatArray, FloatArray]:
    """A chain with the errors of an uncalibrated arm (issue 15 item 4), for simulations: each
    revolute joint's zero is off by ``N(0, joint_offset_sigma_rad)`` (its origin turned about
    its axis: the encoder reads ``q``, the joint is at ``q + dq``) and each joint origin by
    ``N(0, link_sigma_m)`` per coordinate (link lengths and offsets). Returns the true chain,
    the zero offsets (n,) and the origin errors (n, 3)."""
    from dataclasses import replace
    joints = []
    offsets = np.zeros(fixture.n_joints)
    dxyz = np.zeros((fixture.n_joints, 3))
    for i, j in enumerate(fixture.joints):
        xyz = np.zeros(3) if j.origin_xyz_m is None else np.array(j.origin_xyz_m)
        R = np.eye(3) if j.origin_R is None else np.array(j.origin_R)
        if j.revolute:
            offsets[i] = rng.normal(0.0, joint_offset_sigma_rad)
            R = R @ rot_axis_angle(j.axis, offsets[i])
        if fixture.concurrent:  # a turntable keeps its axes through one point
            dxyz[i] = 0.0
        else:
            dxyz[i] = rng.normal(0.0, link_sigma_m, 3)
        joints.append(replace(j, origin_xyz_m=xyz + dxyz[i], origin_R=R))
    return fixture.with_joints(tuple(joints)), offsets, dxyz
