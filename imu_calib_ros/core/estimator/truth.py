"""The true values of the estimator's calibration states for a simulated run (the oracle)."""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from . import error_model as em


def calibration_truth(est: Any, sim: Any) -> NDArray[np.float64]:
    """True values (SI) of ``est``'s calibration states (the state vector without the six
    navigation errors) for the simulation ``sim`` (:class:`~..simulator.SimResult`).

    The filter tracks the total bias, so the biases are the constant part plus the simulated
    drift at the end of the run; the lever arm and mounting rotation come from the true
    fixture against the nominal one the estimator was given.
    """
    lay = est.layout
    tg, ta = em.theta_from_errors(sim.truth.tracked_truth())
    x = np.zeros(lay.n)
    x[lay.gyro_state_idx] = tg[lay.gyro_cols]
    x[lay.accel_state_idx] = ta[lay.accel_cols]
    tf, fx = sim.true_fixture, est.fixture
    q0 = np.zeros(tf.n_joints)
    if fx.concurrent:
        rho = tf.R_enu_imu(q0).T @ tf.p_enu_m(q0)
        R_m = fx.R_enu_imu(q0).T @ tf.R_enu_imu(q0)
    else:
        rho, R_m = last_link_truth(fx, tf)
    if 'lever_arm' in lay.slices:
        x[lay.slices['lever_arm']] = rho
    if 'mounting' in lay.slices:
        x[lay.slices['mounting']] = Rotation.from_matrix(R_m).as_rotvec()
    if lay.n_joint_offsets:  # (a base tilt's residual states after them: a level base)
        off = joint_offsets_truth(fx, tf)[list(est.offset_joints)]
        x[lay.slices[em.CHAIN_GROUP]] = np.concatenate(
            [off, np.zeros(lay.n_joint_offsets - len(off))])
    return x[6:]


def joint_offsets_truth(nominal: Any, true: Any) -> NDArray[np.float64]:
    """True zero offsets (n,) [rad] of a chain's revolute joints: the true joint origin is
    the nominal one turned about the joint's axis, ``O_t = O_n Rot(a, dq)``
    (:func:`~..fixture.perturbed_chain`: the encoder reads ``q``, the joint is at ``q + dq``);
    prismatic joints 0."""
    out = np.zeros(nominal.n_joints)
    for j, (jn, jt) in enumerate(zip(nominal.joints, true.joints)):
        if not jn.revolute:
            continue
        O_n = np.eye(3) if jn.origin_R is None else np.asarray(jn.origin_R)
        O_t = np.eye(3) if jt.origin_R is None else np.asarray(jt.origin_R)
        out[j] = float(Rotation.from_matrix(O_n.T @ O_t).as_rotvec() @ np.asarray(jn.axis))
    return out


def last_link_truth(nominal: Any, true: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """True lever arm (IMU frame, from the nominal IMU point) [m] and mounting rotation (3, 3)
    of a general chain's IMU *on its last link as the encoder reads it* (docs/ESTIMATOR.md,
    "General chains"; :mod:`.chain_consider`).

    The last joint's zero offset ``D = Rot(a_n, dq_n)`` turns the last link and the IMU with
    it whatever the angles: ``R_true(q) = R_nom(q) D R_joint_imu_true``, so the mounting is
    ``R_joint_imu^T D R_joint_imu_true``. Its origin error ``dl_n`` (parent frame) moves the
    IMU point by ``R_{n-1}(q) dl_n``: the part along the joint's axis ``a`` (parent frame
    ``origin_R a``) turns with the last link (a lever arm ``a (a . e)``, ``e = origin_R^T dl``),
    the rest does not; a prismatic last joint does not turn, so all of ``e`` is a lever arm.
    With the IMU point ``imu_xyz`` in the last link: ``rho = R_joint_imu_true^T (a (a . e) +
    imu_xyz_true - D^T imu_xyz)``. Errors of the joints before the last are not mounting or
    lever arm (their share of the estimates is the consider covariance)."""
    jn, jt = nominal.joints[-1], true.joints[-1]
    O_n = np.eye(3) if jn.origin_R is None else np.asarray(jn.origin_R)
    O_t = np.eye(3) if jt.origin_R is None else np.asarray(jt.origin_R)
    D = O_n.T @ O_t if jn.revolute else np.eye(3)
    x_n = np.zeros(3) if jn.origin_xyz_m is None else np.asarray(jn.origin_xyz_m)
    x_t = np.zeros(3) if jt.origin_xyz_m is None else np.asarray(jt.origin_xyz_m)
    e = O_n.T @ (x_t - x_n)
    a = np.asarray(jn.axis, dtype=float)
    shift = a * (a @ e) if jn.revolute else e
    rho = true.R_joint_imu.T @ (shift + true.imu_xyz_m - D.T @ nominal.imu_xyz_m)
    return rho, nominal.R_joint_imu.T @ D @ true.R_joint_imu
