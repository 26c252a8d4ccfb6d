"""The fixture (turntable) of CONTRACT section 2 and the exact kinematics of its joint chain.

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

``omega_dot_ib_imu`` is the time derivative of the components of ``omega_ib_imu``
(which equals the inertial derivative expressed in the IMU frame). In ``f`` the term
``omega_ie x (omega_ie x p)`` (< 1e-11 m/s^2 for p ~ 1 mm) is neglected; normal gravity
already contains the centrifugal acceleration at the site.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import load_yaml, require_mapping, vector
from .earth import Site
from .errors import ConfigError
from .rotation import matrix_to_rpy, rot_axis_angle, rpy_to_matrix

FloatArray = NDArray[np.float64]

#: An axis whose norm differs from 1 by more than this is an error (below: normalised).
AXIS_NORM_TOLERANCE = 1e-3
#: Consecutive axes with |a_i x a_{i+1}| below this are parallel (a degenerate chain).
PARALLEL_AXES_TOLERANCE = 1e-3


def _frozen(a: ArrayLike) -> FloatArray:
    out = np.array(a, dtype=float)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Joint:
    """One revolute joint: a name and a unit axis in its parent frame."""

    name: str
    axis: FloatArray  # (3,), unit

    def __post_init__(self) -> None:
        axis = np.asarray(self.axis, dtype=float)
        if axis.shape != (3,) or abs(np.linalg.norm(axis) - 1.0) > 1e-9:
            raise ValueError(f'joint {self.name!r}: axis must be a unit 3-vector, got {axis}')
        object.__setattr__(self, 'axis', _frozen(axis))


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
            axes.append(R @ joint.axis)
            R = R @ rot_axis_angle(joint.axis, q[..., i])
        return np.array(R), np.stack(axes, axis=-2)

    def R_enu_joint(self, q: ArrayLike) -> FloatArray:
        """Attitude of the innermost joint frame, ``Rot(a_1, q_1) ... Rot(a_n, q_n)``."""
        return self._chain(self._check_q(q))[0]

    def R_enu_imu(self, q: ArrayLike) -> FloatArray:
        """IMU attitude for joint angles ``q`` (..., n) -> (..., 3, 3)."""
        return self.R_enu_joint(q) @ self.R_joint_imu

    def p_enu_m(self, q: ArrayLike) -> FloatArray:
        """IMU reference point in ENU for joint angles ``q`` (..., n) -> (..., 3)."""
        return self.R_enu_joint(q) @ self.imu_xyz_m

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
        R_n, u = self._chain(q)
        w = np.zeros(q.shape[:-1] + (3,))
        wdot = np.zeros_like(w)
        for i in range(self.n_joints):
            ui = u[..., i, :]
            wdot = wdot + ui * qdd[..., i, None] + np.cross(w, ui) * qd[..., i, None]
            w = w + ui * qd[..., i, None]
        R = R_n @ self.R_joint_imu
        R_T = np.swapaxes(R, -1, -2)
        omega_ie = self.site.omega_ie_enu
        p = R_n @ self.imu_xyz_m
        v = np.cross(w, p)
        a = np.cross(wdot, p) + np.cross(w, v)
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

    # ------------------------------------------------------------------------------- files
    def to_dict(self) -> dict[str, Any]:
        """The CONTRACT section 2 mapping (degrees in the file)."""
        return {
            'site': self.site.to_dict(),
            'joints': [{'name': j.name, 'axis': [float(x) for x in j.axis]} for j in self.joints],
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
            _check_keys(rj, ('name', 'axis'), ('name', 'axis'), source, key)
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
            if joints and np.linalg.norm(np.cross(joints[-1].axis, axis)) < \
                    PARALLEL_AXES_TOLERANCE:
                raise ConfigError(f'axis is parallel to the axis of joint {joints[-1].name!r} '
                                  '(consecutive joints must turn about different axes)',
                                  source, f'{key}.axis')
            joints.append(Joint(name, axis))
        imu = require_mapping(d['imu'], source, 'imu')
        _check_keys(imu, ('rpy_deg', 'xyz_m'), ('rpy_deg', 'xyz_m'), source, 'imu')
        rpy = np.radians(vector(imu['rpy_deg'], 3, source, 'imu.rpy_deg'))
        xyz = np.array(vector(imu['xyz_m'], 3, source, 'imu.xyz_m'))
        return cls(site, tuple(joints), rpy, xyz, source)


def _check_keys(d: Any, known: tuple[str, ...], required: tuple[str, ...], source: str | None,
                prefix: str) -> None:
    for k in d:
        if k not in known:
            raise ConfigError(f'unknown key (known keys: {", ".join(known)})', source,
                              f'{prefix}.{k}' if prefix else str(k))
    for k in required:
        if k not in d:
            raise ConfigError('missing required key', source, f'{prefix}.{k}' if prefix else k)


def load_fixture(name_or_path: str) -> Fixture:
    """Load a fixture by path or by the name of a shipped file in ``config/fixtures/``."""
    from .config import resolve_config_file
    return Fixture.from_yaml(resolve_config_file(name_or_path, 'fixtures'))
