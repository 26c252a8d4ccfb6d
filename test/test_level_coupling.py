"""The levelled tilt carries the accelerometer errors (alignment.level_coupling).

Levelling on a stationary window makes the navigated specific force vertical: the tilt error
is what cancels the accelerometer error there. ``P0`` must say so; a diagonal ``P0`` claimed
the tilt known to 2 mrad while an unmeasured bias of a raw unit (100 mg) tilts it by up to
0.1 rad, which a three-pose plan then saw as an unmodelled velocity error at its first
rotation. The signs are proven here by levelling a simulated window, not by algebra.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_calib_ros.core.estimator import error_model as em
from imu_calib_ros.core.estimator.alignment import level, level_coupling
from imu_calib_ros.core.sensor_model import SensorErrors

ALL = tuple(g[0] for g in em.GROUPS if g[0] != 'mounting')
G = 9.80


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_tilt_of_the_levelling_is_the_coupling_times_the_accel_error(seed: int) -> None:
    rng = np.random.default_rng(seed)
    lay = em.StateLayout.build(ALL)
    R_true = Rotation.from_rotvec(rng.normal(0.0, 1.0, 3)).as_matrix()  # any pose at rest
    f_true = R_true.T @ np.array([0.0, 0.0, G])
    # true errors: bias 5 mg, scale and misalignment 0.1 % (tilts of a few mrad)
    b = rng.normal(0.0, 0.05, 3)
    K = np.diag(rng.normal(0.0, 1e-3, 3)) + 1e-3 * rng.normal(size=(3, 3)) * (1 - np.eye(3))
    f_meas = f_true + K @ f_true + b
    # the fixture's attitude is exact; levelling with the raw (estimate: zero errors) mean
    R_hat = level(R_true, f_meas)
    psi = Rotation.from_matrix(R_hat @ R_true.T).as_rotvec()  # R_hat = exp(psi) R
    # x = estimate - truth: every accel state is 0 - true value
    truth = SensorErrors.zeros().replace(accel_bias_m_s2=b, accel_scale_misalignment=K)
    _, theta_a = em.theta_from_errors(truth)
    x = np.zeros(lay.n)
    x[lay.accel_state_idx] = -theta_a[lay.accel_cols]
    n = 50
    M = level_coupling(lay, R_hat, SensorErrors.zeros(), np.zeros((n, 3)),
                       np.tile(f_meas, (n, 1)), 0.005, np.array([0.0, 5e-5, 5e-5]))
    s = lay.scale
    psi_pred = (M @ (x / s))[0:2] * s[0:2]
    # first order: agreement to the square of the error
    err = float(np.linalg.norm(b + K @ f_true)) / G
    assert np.abs(psi_pred - psi[0:2]).max() < 2 * err ** 2 + 1e-6, (psi_pred, psi[0:2])
    assert np.abs(psi[0:2]).max() > 30 * err ** 2  # the tilt is not negligible here
    # the rest of M is the identity
    M0 = M.copy()
    M0[0:2, lay.accel_state_idx] = 0.0
    assert np.array_equal(M0, np.eye(lay.n))
