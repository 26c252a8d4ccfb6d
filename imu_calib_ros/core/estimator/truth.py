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
    if 'lever_arm' in lay.slices:
        x[lay.slices['lever_arm']] = (  # a chain: the true point from the nominal one
            tf.R_enu_imu(q0).T @ tf.p_enu_m(q0) if tf.concurrent
            else tf.R_joint_imu.T @ (tf.imu_xyz_m - fx.imu_xyz_m))
    if 'mounting' in lay.slices:
        R_m = (fx.R_enu_imu(q0).T @ tf.R_enu_imu(q0) if fx.concurrent  # arm: the IMU on its
               else fx.R_joint_imu.T @ tf.R_joint_imu)  # link (joint errors are not mounting)
        x[lay.slices['mounting']] = Rotation.from_matrix(R_m).as_rotvec()
    return x[6:]
