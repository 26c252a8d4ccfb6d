"""Rotation helpers: skew matrices, axis-angle, roll-pitch-yaw, rotation vectors, quaternions.

Conventions (docs/DESIGN.md): ``R_a_b`` maps vectors from frame b to frame a
(``v_a = R_a_b @ v_b``); rotations are right-handed (active); quaternions are scipy's
scalar-last ``(x, y, z, w)``. Every function is vectorised over leading batch dimensions.
scipy's :class:`~scipy.spatial.transform.Rotation` does the numerical work.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]

__all__ = [
    'skew', 'unskew', 'rot_axis_angle', 'rpy_to_matrix', 'matrix_to_rpy', 'rotvec_to_matrix',
    'matrix_to_rotvec', 'quat_to_matrix', 'matrix_to_quat', 'quat_multiply',
    'quat_prefix_product', 'orthonormalize',
]


def skew(v: ArrayLike) -> FloatArray:
    """Cross-product matrix: ``skew(v) @ w == cross(v, w)``.

    Parameters
    ----------
    v : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def unskew(m: ArrayLike) -> FloatArray:
    """The vector of the antisymmetric part of ``m`` (inverse of :func:`skew`), shape (..., 3)."""
    m = np.asarray(m, dtype=float)
    return 0.5 * np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0],
                           m[..., 1, 0] - m[..., 0, 1]], axis=-1)


def _from_rotvec(rotvec: FloatArray) -> FloatArray:
    flat = rotvec.reshape(-1, 3)
    return Rotation.from_rotvec(flat).as_matrix().reshape(rotvec.shape[:-1] + (3, 3))


def rot_axis_angle(axis: ArrayLike, angle_rad: ArrayLike) -> FloatArray:
    """Right-handed rotation by ``angle_rad`` about the unit vector ``axis`` (Rodrigues).

    Parameters
    ----------
    axis : array_like, shape (3,) or (..., 3)
        Unit rotation axis (not re-normalised: the caller guarantees unit length).
    angle_rad : array_like, shape (...)
        Rotation angle(s).

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle_rad, dtype=float)
    return _from_rotvec(angle[..., None] * axis)


def rpy_to_matrix(rpy_rad: ArrayLike) -> FloatArray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (ROS/URDF fixed-axis roll-pitch-yaw), shape (..., 3, 3).

    Parameters
    ----------
    rpy_rad : array_like, shape (..., 3)
        ``(roll, pitch, yaw)`` in radians.
    """
    rpy = np.asarray(rpy_rad, dtype=float)
    flat = rpy.reshape(-1, 3)
    # extrinsic 'xyz' = first about fixed x, then fixed y, then fixed z = Rz Ry Rx
    mat = Rotation.from_euler('xyz', flat).as_matrix()
    return mat.reshape(rpy.shape[:-1] + (3, 3))


def matrix_to_rpy(R: ArrayLike) -> FloatArray:
    """Inverse of :func:`rpy_to_matrix`: ``(roll, pitch, yaw)`` with pitch in [-pi/2, pi/2]."""
    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    out = Rotation.from_matrix(flat).as_euler('xyz')
    return out.reshape(R.shape[:-2] + (3,))


def rotvec_to_matrix(rotvec: ArrayLike) -> FloatArray:
    """Exponential map of SO(3): rotation vector (..., 3) -> matrix (..., 3, 3)."""
    return _from_rotvec(np.asarray(rotvec, dtype=float))


def matrix_to_rotvec(R: ArrayLike) -> FloatArray:
    """Logarithm map of SO(3): matrix (..., 3, 3) -> rotation vector (..., 3), angle <= pi."""
    R = np.asarray(R, dtype=float)
    out = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec()
    return out.reshape(R.shape[:-2] + (3,))


def quat_to_matrix(q_xyzw: ArrayLike) -> FloatArray:
    """Unit quaternion (..., 4), scalar last -> rotation matrix (..., 3, 3)."""
    q = np.asarray(q_xyzw, dtype=float)
    out = Rotation.from_quat(q.reshape(-1, 4)).as_matrix()
    return out.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(R: ArrayLike) -> FloatArray:
    """Rotation matrix (..., 3, 3) -> unit quaternion (..., 4), scalar last, w >= 0."""
    R = np.asarray(R, dtype=float)
    out = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat(canonical=True)
    return out.reshape(R.shape[:-2] + (4,))


def quat_multiply(p_xyzw: ArrayLike, q_xyzw: ArrayLike) -> FloatArray:
    """Hamilton product ``p * q`` (rotation ``q`` first, then ``p``), broadcast, shape (..., 4).

    Written out rather than via scipy so that it broadcasts and keeps the sign of ``w``
    (scipy re-normalises and may flip hemispheres), which a cumulative product needs.
    """
    p = np.asarray(p_xyzw, dtype=float)
    q = np.asarray(q_xyzw, dtype=float)
    px, py, pz, pw = np.moveaxis(p, -1, 0)
    qx, qy, qz, qw = np.moveaxis(q, -1, 0)
    return np.stack([
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
        pw * qw - px * qx - py * qy - pz * qz,
    ], axis=-1)


def quat_prefix_product(q_xyzw: ArrayLike, q0_xyzw: ArrayLike | None = None) -> FloatArray:
    """Cumulative product along axis 0: ``out[k] = q0 * q[0] * q[1] * ... * q[k]``.

    Used to chain attitude increments of consecutive samples (scipy has no cumulative
    product). A sequential loop over a (N, 4) array: O(N) Python-level steps, but
    numerically the exact left-to-right product, which a tree reduction would not be.

    Parameters
    ----------
    q_xyzw : array_like, shape (N, 4)
        Increments, each a unit quaternion (body-frame increments compose on the right).
    q0_xyzw : array_like, shape (4,), optional
        Initial attitude (identity if omitted).

    Returns
    -------
    ndarray, shape (N, 4)
        Re-normalised after every step.
    """
    q = np.asarray(q_xyzw, dtype=float)
    out = np.empty_like(q)
    acc = np.array([0.0, 0.0, 0.0, 1.0]) if q0_xyzw is None else np.asarray(q0_xyzw, float)
    for k in range(q.shape[0]):
        acc = quat_multiply(acc, q[k])
        acc = acc / np.linalg.norm(acc)
        out[k] = acc
    return out


def orthonormalize(R: ArrayLike) -> FloatArray:
    """Nearest rotation matrix (polar decomposition via SVD), shape (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    u, _, vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt
