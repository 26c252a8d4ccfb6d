"""The measurement models of core/estimator/measurements.py against the fixture kinematics and
against finite differences.

Two checks per model. (1) The innovation vanishes at the truth: the true motion comes from
``Fixture.kinematics`` of a fixture with a mounting error (a rotation of degrees and a lever
arm of centimetres), independent of the model's formula, so a wrong ``z`` (a sign, a frame,
the mounting on the wrong side) fails. (2) ``H`` is the derivative of ``z`` along every
error-state direction, by central differences, with the error conventions of
``error_model``/``strapdown`` (estimate minus truth: ``R_hat = exp([psi x]) R``,
``v_hat = v + dv``, ``rho_hat = rho + x_rho``, ``exp(mu_hat) = exp(mu) exp(x_mu)``), so a
wrong sign, a missing term, a transposed rotation or a column in the wrong place fails.
Tolerances: the zero-velocity ``H`` leaves out the earth-rate part of ``omega_eb`` through
psi, ``|Omega_ie| |rho|`` per radian (documented in the model), against columns of ~0.1;
the encoder-attitude ``H`` is exact at ``z = 0`` and off by ``O(|z|)`` (BCH) at the ~1e-4 rad
errors used; central differences with a 1e-6 step are good to ~1e-9 here.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_calib_ros.core.estimator import error_model as em
from imu_calib_ros.core.estimator.measurements import (MEAS_SCALE, encoder_attitude,
                                                       to_filter_units, zero_velocity)
from imu_calib_ros.core.estimator.priors import nominal_lever_arm
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.rotation import matrix_to_rotvec, rotvec_to_matrix, rpy_to_matrix
from imu_calib_ros.core.urdf_fixture import UrdfOptions

FX = load_fixture('three_axis')
DRPY = np.array([0.03, -0.05, 0.08])  # true mounting rotation (rpy, rad): ~5.6 deg
DXYZ = np.array([0.04, -0.03, 0.05])  # true reference point offset (m)
LAYOUT = em.StateLayout.build(('gyro_bias', 'gyro_scale', 'lever_arm', 'mounting'))
STEP = 1e-6
ZERO = np.zeros(3)  # default of the helpers (never written to)


def _truth(seed: int, B: int = 6):  # noqa: ANN202
    """True motion of the mounted IMU at B random joint states (moving: |qd| ~ 1 rad/s)."""
    rng = np.random.default_rng(seed)
    true_fx = FX.with_mounting(DRPY, DXYZ)
    q = rng.uniform(-np.pi, np.pi, (B, 3))
    kin = true_fx.kinematics(q, rng.uniform(-1.5, 1.5, (B, 3)), rng.uniform(-1, 1, (B, 3)))
    mu = matrix_to_rotvec(rpy_to_matrix(DRPY))
    return rng, q, kin, nominal_lever_arm(true_fx), mu


def _central_differences(z_of, n: int) -> np.ndarray:  # noqa: ANN001
    """``dz/dx`` (..., n) by central differences of ``z_of`` at 0 along each of ``n`` axes."""
    cols = []
    for k in range(n):
        e = np.zeros(n)
        e[k] = STEP
        cols.append((z_of(e) - z_of(-e)) / (2 * STEP))
    return np.stack(cols, axis=-1)


def _column_error(H: np.ndarray, fd: np.ndarray, cols: slice) -> float:
    return float(np.abs(H[:, :, cols] - fd).max())


# ------------------------------------------------------------------ zero velocity
@pytest.mark.parametrize('seed', [0, 1, 2])
def test_zero_velocity_vanishes_at_the_truth(seed: int) -> None:
    _, _, kin, rho, _ = _truth(seed)
    assert np.abs(kin.v_enu_m_s).max() > 0.05  # the reference point does move
    z, _ = zero_velocity(kin.v_enu_m_s, kin.R_enu_imu, kin.omega_ib_imu_rad_s,
                         FX.site.omega_ie_enu, rho, LAYOUT)
    assert np.abs(z).max() < 1e-15


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_zero_velocity_jacobian_matches_finite_differences(seed: int) -> None:
    rng, _, kin, rho, _ = _truth(seed)
    om = FX.site.omega_ie_enu
    w = kin.omega_ib_imu_rad_s
    # the working point: an estimate with small errors in every state
    R_hat = rotvec_to_matrix(rng.normal(0, 1e-4, 3)) @ kin.R_enu_imu
    v_hat = kin.v_enu_m_s + rng.normal(0, 1e-5, 3)
    rho_hat = rho + rng.normal(0, 1e-3, 3)
    z0, H = zero_velocity(v_hat, R_hat, w, om, rho_hat, LAYOUT)

    def z_of(d_psi: np.ndarray = ZERO, d_v: np.ndarray = ZERO,
             d_rho: np.ndarray = ZERO) -> np.ndarray:
        return zero_velocity(v_hat + d_v, rotvec_to_matrix(d_psi) @ R_hat, w, om,
                             rho_hat + d_rho, LAYOUT)[0]

    def fd(arg: str) -> np.ndarray:
        cols = []
        for i in range(3):
            e = np.zeros(3)
            e[i] = STEP
            cols.append((z_of(**{arg: e}) - z_of(**{arg: -e})) / (2 * STEP))
        return np.stack(cols, axis=-1)  # (B, 3, 3)

    earth = np.linalg.norm(om) * np.linalg.norm(rho_hat)  # left out of H (documented)
    assert np.abs(H[:, :, 0:3]).max() > 1e3 * earth  # the test can see a wrong psi column
    assert _column_error(H, fd('d_psi'), slice(0, 3)) < 1.01 * earth + 1e-9
    assert _column_error(H, fd('d_v'), slice(3, 6)) < 1e-9
    assert _column_error(H, fd('d_rho'), LAYOUT.slices['lever_arm']) < 1e-9
    # no other state enters this model
    others = np.ones(LAYOUT.n, bool)
    others[0:6] = False
    others[LAYOUT.slices['lever_arm']] = False
    assert not H[:, :, others].any()
    np.testing.assert_array_equal(z_of(), z0)


def test_zero_velocity_without_lever_arm_state_has_no_column() -> None:
    _, _, kin, rho, _ = _truth(0)
    lay = em.StateLayout.build(('gyro_bias',))
    _, H = zero_velocity(kin.v_enu_m_s, kin.R_enu_imu, kin.omega_ib_imu_rad_s,
                         FX.site.omega_ie_enu, rho, lay)
    assert H.shape == (6, 3, lay.n) and not H[:, :, 6:].any()


# ------------------------------------------------------------------ encoder attitude
@pytest.mark.parametrize('seed', [0, 1, 2])
def test_encoder_attitude_vanishes_at_the_truth(seed: int) -> None:
    _, q, kin, _, mu = _truth(seed)
    z, _ = encoder_attitude(kin.R_enu_imu, FX.R_enu_imu(q), mu, LAYOUT)
    assert np.abs(z).max() < 1e-14
    # with the nominal mounting (mu = 0) the innovation is the mounting, seen in ENU
    z0, _ = encoder_attitude(kin.R_enu_imu, FX.R_enu_imu(q), np.zeros(3), LAYOUT)
    np.testing.assert_allclose(np.linalg.norm(z0, axis=1), np.linalg.norm(mu), rtol=1e-12)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_encoder_attitude_jacobian_matches_finite_differences(seed: int) -> None:
    rng, q, kin, _, mu = _truth(seed)
    R_fix = FX.R_enu_imu(q)
    R_hat = rotvec_to_matrix(rng.normal(0, 1e-4, 3)) @ kin.R_enu_imu
    mu_hat = (Rotation.from_rotvec(mu) * Rotation.from_rotvec(rng.normal(0, 1e-4, 3))
              ).as_rotvec()
    z0, H = encoder_attitude(R_hat, R_fix, mu_hat, LAYOUT)
    assert np.abs(z0).max() < 1e-3  # near the truth: H is exact at z = 0, O(|z|) here

    def z_of(d_psi: np.ndarray = ZERO, d_mu: np.ndarray = ZERO) -> np.ndarray:
        mu_p = (Rotation.from_rotvec(mu_hat) * Rotation.from_rotvec(d_mu)).as_rotvec()
        return encoder_attitude(rotvec_to_matrix(d_psi) @ R_hat, R_fix, mu_p, LAYOUT)[0]

    def fd(arg: str) -> np.ndarray:
        cols = []
        for i in range(3):
            e = np.zeros(3)
            e[i] = STEP
            cols.append((z_of(**{arg: e}) - z_of(**{arg: -e})) / (2 * STEP))
        return np.stack(cols, axis=-1)

    tol = 2 * np.abs(z0).max() + 1e-8
    assert _column_error(H, fd('d_psi'), slice(0, 3)) < tol
    assert _column_error(H, fd('d_mu'), LAYOUT.slices['mounting']) < tol
    others = np.ones(LAYOUT.n, bool)
    others[0:3] = False
    others[LAYOUT.slices['mounting']] = False
    assert not H[:, :, others].any()


# ------------------------------------------------------------------ filter units
def test_filter_units_preserve_z_equals_H_x() -> None:
    """``H_s x_s`` in the filter's units is ``H x`` (SI) over MEAS_SCALE."""
    rng = np.random.default_rng(3)
    H = rng.normal(size=(4, 3, LAYOUT.n))
    z = rng.normal(size=(4, 3))
    x_s = rng.normal(size=LAYOUT.n)
    H_si = H.copy()
    z_s, H_s = to_filter_units(z, H, LAYOUT.scale)
    np.testing.assert_allclose(H_s @ x_s, (H_si @ (LAYOUT.scale * x_s)) / MEAS_SCALE,
                               rtol=1e-12)
    np.testing.assert_allclose(z_s, z / MEAS_SCALE, rtol=0)


# ------------------------------------------------------------------ joint zero offsets (issue 15)
# A general chain (the six-axis arm): the joint at ``q + o`` when its encoder reads ``q``. The
# estimator evaluates the chain at ``q + o_hat``; ``o_hat = o + x_o``.
ARM = load_fixture('arm6.urdf', UrdfOptions('base_link', 'imu_link'))
ARM_JOINTS = list(em.joint_offset_joints(ARM))
ARM_LAYOUT = em.StateLayout.build(('gyro_bias', 'lever_arm', 'mounting'), len(ARM_JOINTS))


def _offset_arm(o: np.ndarray):  # noqa: ANN202
    """The arm whose joints ``ARM_JOINTS`` are off by ``o`` (origin turned about the axis, as
    ``fixture.perturbed_chain`` does)."""
    from dataclasses import replace

    from imu_calib_ros.core.rotation import rot_axis_angle
    joints = list(ARM.joints)
    for k, j in enumerate(ARM_JOINTS):
        jn = joints[j]
        R = np.eye(3) if jn.origin_R is None else np.asarray(jn.origin_R)
        joints[j] = replace(jn, origin_R=R @ rot_axis_angle(jn.axis, o[k]))
    return ARM.with_joints(tuple(joints))


def _arm_truth(seed: int, B: int = 6):  # noqa: ANN202
    rng = np.random.default_rng(seed)
    o = rng.normal(0, 2e-3, len(ARM_JOINTS))
    q = rng.uniform(-1.5, 1.5, (B, ARM.n_joints))
    qd = rng.uniform(-1.0, 1.0, (B, ARM.n_joints))
    kin = _offset_arm(o).kinematics(q, qd, rng.uniform(-1, 1, (B, ARM.n_joints)))
    return rng, o, q, qd, kin


def _plus(q: np.ndarray, o: np.ndarray) -> np.ndarray:
    out = q.copy()
    out[:, ARM_JOINTS] += o
    return out


def test_joint_offset_layout_only_on_a_chain() -> None:
    assert em.joint_offset_joints(FX) == ()  # a turntable: no group
    assert 'joint_offset' not in LAYOUT.slices and LAYOUT.n_joint_offsets == 0
    assert ARM_JOINTS == [0, 1, 2, 3, 4]  # the revolute joints before the last (the mounting)
    assert ARM_LAYOUT.labels()[-1] == 'joint_offset[4]' and ARM_LAYOUT.n == 6 + 9 + 5
    np.testing.assert_allclose(ARM_LAYOUT.scale[ARM_LAYOUT.slices['joint_offset']], 1e-6)


@pytest.mark.parametrize('seed', [0, 1])
def test_chain_velocity_vanishes_at_the_true_offsets(seed: int) -> None:
    """The anchor velocity at ``q + o`` is the offset arm's: the innovation is zero at the
    true offsets (up to the earth-rate term) and not at zero offsets."""
    _, o, q, qd, kin = _arm_truth(seed)
    om = ARM.site.omega_ie_enu

    def z_at(o_hat: np.ndarray) -> np.ndarray:
        qo = _plus(q, o_hat)
        return zero_velocity(kin.v_enu_m_s, kin.R_enu_imu, kin.omega_ib_imu_rad_s, om,
                             np.zeros(3), ARM_LAYOUT, ARM.anchor_velocity_enu_m_s(qo, qd))[0]

    assert np.abs(z_at(o)).max() < 1e-12
    assert np.abs(z_at(np.zeros_like(o))).max() > 1e-4  # 2 mrad x ~1 m/s per rad


@pytest.mark.parametrize('seed', [0, 1])
def test_chain_velocity_offset_jacobian_matches_finite_differences(seed: int) -> None:
    rng, o, q, qd, kin = _arm_truth(seed)
    om = ARM.site.omega_ie_enu
    o_hat = o + rng.normal(0, 1e-4, len(o))
    rho = rng.normal(0, 1e-3, 3)

    def z_of(d_o: np.ndarray) -> np.ndarray:
        qo = _plus(q, o_hat + d_o)
        return zero_velocity(kin.v_enu_m_s, kin.R_enu_imu, kin.omega_ib_imu_rad_s, om, rho,
                             ARM_LAYOUT, ARM.anchor_velocity_enu_m_s(qo, qd))[0]

    qo = _plus(q, o_hat)
    D = ARM.anchor_velocity_jacobian_q(qo, qd)[:, :, ARM_JOINTS]
    _, H = zero_velocity(kin.v_enu_m_s, kin.R_enu_imu, kin.omega_ib_imu_rad_s, om, rho,
                         ARM_LAYOUT, ARM.anchor_velocity_enu_m_s(qo, qd), D)
    fd = _central_differences(z_of, len(o))
    sl = ARM_LAYOUT.slices['joint_offset']
    assert np.abs(fd).max() > 0.1  # the offsets do move the anchor velocity
    assert _column_error(H, fd, sl) < 1e-8
    # without the derivative: no offset columns (the turntable's call)
    _, H0 = zero_velocity(kin.v_enu_m_s, kin.R_enu_imu, kin.omega_ib_imu_rad_s, om, rho,
                          ARM_LAYOUT, ARM.anchor_velocity_enu_m_s(qo, qd))
    assert not H0[:, :, sl].any()


@pytest.mark.parametrize('seed', [0, 1])
def test_encoder_attitude_vanishes_at_the_true_offsets(seed: int) -> None:
    _, o, q, _, kin = _arm_truth(seed)
    z, _ = encoder_attitude(kin.R_enu_imu, ARM.R_enu_imu(_plus(q, o)), np.zeros(3), ARM_LAYOUT)
    assert np.abs(z).max() < 1e-13
    z0, _ = encoder_attitude(kin.R_enu_imu, ARM.R_enu_imu(q), np.zeros(3), ARM_LAYOUT)
    assert np.abs(z0).max() > 1e-3


@pytest.mark.parametrize('seed', [0, 1])
def test_encoder_attitude_offset_jacobian_matches_finite_differences(seed: int) -> None:
    rng, o, q, _, kin = _arm_truth(seed)
    o_hat = o + rng.normal(0, 1e-4, len(o))
    mu = rng.normal(0, 1e-4, 3)
    psi = rng.normal(0, 1e-4, 3)
    R_hat = rotvec_to_matrix(psi) @ kin.R_enu_imu
    qo = _plus(q, o_hat)
    axes = ARM.angular_axes_enu(qo)[:, ARM_JOINTS]
    z0, H = encoder_attitude(R_hat, ARM.R_enu_imu(qo), mu, ARM_LAYOUT, axes)

    def z_of(d_o: np.ndarray) -> np.ndarray:
        return encoder_attitude(R_hat, ARM.R_enu_imu(_plus(q, o_hat + d_o)), mu,
                                ARM_LAYOUT)[0]

    fd = _central_differences(z_of, len(o))
    assert np.abs(fd).max() > 0.5  # unit axes
    assert _column_error(H, fd, ARM_LAYOUT.slices['joint_offset']) < 2 * np.abs(z0).max() + 1e-8
    # and the full model is linear in the errors: z ~ H x with every state's error
    x = np.zeros(ARM_LAYOUT.n)
    x[ARM_LAYOUT.slices['joint_offset']] = o_hat - o
    x[ARM_LAYOUT.slices['mounting']] = mu
    x[0:3] = psi
    lin = np.einsum('bij,j->bi', H, x)
    assert np.abs(z0 - lin).max() < 1e-6  # second order in 1e-4 errors
