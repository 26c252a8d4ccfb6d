"""The motion bridge of a gap (issue 11): ``health.bridge_motion_covariance`` against a
Monte Carlo of the bridge itself, on the true fixture kinematics.

The bridge carries the navigated attitude across a gap by the fixture rotation the encoders
measured, ``R1_hat = dF_meas R0_hat`` (``dF = R_fix(q1) R_fix(q0)^T``: the mounting cancels),
and sets the velocity to the fixture's, ``v1_hat = R1_hat (omega_eb x rho_hat)``. Here the
errors before the gap (attitude, velocity, lever arm, a bias) are drawn from a covariance
with correlations, the encoder increment gets its noise, the bridge is applied to every draw
with the true, mounted fixture (degrees of mounting, centimetres of lever arm, joint rates of
~1 rad/s), and the sample covariance of the true errors after the bridge (estimate minus
truth, the error_model conventions) must match the function's ``P``. Tolerance: 20,000
draws give a relative standard error of ~1 % on a variance and ~0.01 on a correlation; the
first-order model is off by O(|psi| |dF - I|) at the 1e-3 rad errors used.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_calib_ros.core.estimator import error_model as em
from imu_calib_ros.core.estimator.health import bridge_motion_covariance
from imu_calib_ros.core.estimator.priors import nominal_lever_arm
from imu_calib_ros.core.fixture import load_fixture

FX = load_fixture('three_axis')
DRPY = np.array([0.03, -0.05, 0.08])
DXYZ = np.array([0.04, -0.03, 0.05])
LAYOUT = em.StateLayout.build(('gyro_bias', 'lever_arm'))
N_DRAWS = 20_000


@pytest.mark.parametrize('seed', [0, 1])
def test_bridge_covariance_matches_a_monte_carlo_of_the_bridge(seed: int) -> None:
    rng = np.random.default_rng(seed)
    true_fx = FX.with_mounting(DRPY, DXYZ)
    q0 = rng.uniform(-np.pi, np.pi, 3)
    qd = rng.uniform(-1.5, 1.5, 3)
    gap_s = 0.08
    q1 = q0 + qd * gap_s
    R0 = true_fx.R_enu_imu(q0)
    R1 = true_fx.R_enu_imu(q1)
    rho = nominal_lever_arm(true_fx)
    om = true_fx.site.omega_ie_enu
    w_eb = true_fx.kinematics(q1[None], qd[None], np.zeros((1, 3))).omega_ib_imu_rad_s[0] \
        - R1.T @ om
    n = LAYOUT.n
    s = LAYOUT.scale
    # a covariance (SI) with correlations between attitude, velocity, lever arm and bias
    sd = np.ones(n)
    sd[0:3], sd[3:6] = 1e-3, 1e-3
    sd[LAYOUT.slices['lever_arm']] = 5e-3
    sd[LAYOUT.slices['gyro_bias']] = 1e-6
    L = np.tril(rng.normal(0.0, 0.3, (n, n)), -1) + np.eye(n)
    C = L @ L.T
    C = C / np.sqrt(np.outer(np.diag(C), np.diag(C)))
    P_si = C * np.outer(sd, sd)
    var_att = (3e-5) ** 2
    var_vel = np.full(3, (2e-5) ** 2)
    q1_s = np.zeros((n, n))
    P_new = bridge_motion_covariance(P_si / np.outer(s, s), LAYOUT, true_fx.R_enu_imu(q1)
                                     @ true_fx.R_enu_imu(q0).T,
                                     R1 @ np.cross(w_eb, rho), R1, w_eb, var_att, var_vel, q1_s,
                                     gap_s) * np.outer(s, s)
    # Monte Carlo of the bridge on the true kinematics
    x = rng.multivariate_normal(np.zeros(n), P_si, N_DRAWS)
    psi0, x_rho = x[:, 0:3], x[:, LAYOUT.slices['lever_arm']]
    R0_hat = Rotation.from_rotvec(psi0).as_matrix() @ R0
    dF = FX.R_enu_imu(q1) @ FX.R_enu_imu(q0).T  # nominal fixture: the mounting cancels
    assert np.allclose(dF, R1 @ R0.T, atol=1e-12)
    e = rng.normal(0.0, np.sqrt(var_att), (N_DRAWS, 3))
    R1_hat = Rotation.from_rotvec(e).as_matrix() @ dF @ R0_hat
    u_hat = np.cross(w_eb, rho + x_rho)
    v1_hat = np.einsum('kij,kj->ki', R1_hat, u_hat) \
        + rng.normal(0.0, np.sqrt(var_vel[0]), (N_DRAWS, 3))
    v1 = R1 @ np.cross(w_eb, rho)
    psi1 = Rotation.from_matrix(R1_hat @ R1.T).as_rotvec()
    y = x.copy()
    y[:, 0:3], y[:, 3:6] = psi1, v1_hat - v1
    P_mc = np.cov(y.T)
    sd_new = np.sqrt(np.diag(P_new))
    assert np.allclose(np.sqrt(np.diag(P_mc)) / sd_new, 1.0, atol=0.03), \
        np.sqrt(np.diag(P_mc)) / sd_new
    corr_mc = P_mc / np.outer(np.sqrt(np.diag(P_mc)), np.sqrt(np.diag(P_mc)))
    corr = P_new / np.outer(sd_new, sd_new)
    assert np.abs(corr_mc - corr).max() < 0.04, np.abs(corr_mc - corr).max()
