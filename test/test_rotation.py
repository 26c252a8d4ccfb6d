"""rotation.py against analytic cases, scipy and its own inverses."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_calib_ros.core import rotation as rot

RNG = np.random.default_rng(7)


def test_skew_is_cross_product_and_unskew_inverts() -> None:
    v = RNG.normal(size=(5, 4, 3))
    w = RNG.normal(size=(5, 4, 3))
    S = rot.skew(v)
    assert S.shape == (5, 4, 3, 3)
    np.testing.assert_allclose(np.einsum('...ij,...j->...i', S, w), np.cross(v, w), atol=1e-15)
    np.testing.assert_array_equal(S, -np.swapaxes(S, -1, -2))
    np.testing.assert_allclose(rot.unskew(S), v, atol=0)


def test_rot_axis_angle_right_handed_and_batched() -> None:
    Rz = rot.rot_axis_angle([0, 0, 1], np.pi / 2)
    np.testing.assert_allclose(Rz @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # x -> y
    Rx = rot.rot_axis_angle([1, 0, 0], np.pi / 2)
    np.testing.assert_allclose(Rx @ [0, 1, 0], [0, 0, 1], atol=1e-15)  # y -> z
    Ry = rot.rot_axis_angle([0, 1, 0], np.pi / 2)
    np.testing.assert_allclose(Ry @ [0, 0, 1], [1, 0, 0], atol=1e-15)  # z -> x
    axis = RNG.normal(size=3)
    axis /= np.linalg.norm(axis)
    ang = RNG.uniform(-7, 7, size=(3, 4))
    R = rot.rot_axis_angle(axis, ang)
    assert R.shape == (3, 4, 3, 3)
    # Rodrigues written out
    K = rot.skew(axis)
    ref = np.eye(3) + np.sin(ang)[..., None, None] * K + \
        (1 - np.cos(ang))[..., None, None] * (K @ K)
    np.testing.assert_allclose(R, ref, atol=2e-15)
    np.testing.assert_allclose(R @ axis, np.broadcast_to(axis, (3, 4, 3)), atol=2e-15)


def test_rpy_is_rz_ry_rx_and_inverts() -> None:
    rpy = np.array([0.3, -0.4, 2.5])
    ref = rot.rot_axis_angle([0, 0, 1], rpy[2]) @ rot.rot_axis_angle([0, 1, 0], rpy[1]) @ \
        rot.rot_axis_angle([1, 0, 0], rpy[0])
    np.testing.assert_allclose(rot.rpy_to_matrix(rpy), ref, atol=1e-15)
    batch = RNG.uniform([-3, -1.5, -3], [3, 1.5, 3], size=(6, 3))
    np.testing.assert_allclose(rot.matrix_to_rpy(rot.rpy_to_matrix(batch)), batch, atol=1e-12)
    # roll 180, yaw 180 = pitch 180: x -> -x, y -> y, z -> -z
    np.testing.assert_allclose(rot.rpy_to_matrix(np.radians([180, 0, 180])),
                               np.diag([-1.0, 1.0, -1.0]), atol=1e-15)


def test_rotvec_exp_log_round_trip() -> None:
    v = RNG.normal(size=(4, 2, 3))
    v *= (RNG.uniform(0, 3.0, size=(4, 2)) / np.linalg.norm(v, axis=-1))[..., None]
    R = rot.rotvec_to_matrix(v)
    assert R.shape == (4, 2, 3, 3)
    np.testing.assert_allclose(rot.matrix_to_rotvec(R), v, atol=1e-13)
    small = np.array([1e-9, -2e-9, 3e-9])
    np.testing.assert_allclose(rot.rotvec_to_matrix(small), np.eye(3) + rot.skew(small),
                               atol=1e-17)


def test_quaternions_match_scipy_composition() -> None:
    p = Rotation.random(5, rng=1)
    q = Rotation.random(5, rng=2)
    pq = rot.quat_multiply(p.as_quat(), q.as_quat())
    np.testing.assert_allclose(rot.quat_to_matrix(pq), (p * q).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(rot.quat_to_matrix(pq), p.as_matrix() @ q.as_matrix(), atol=1e-14)
    m = p.as_matrix()
    np.testing.assert_allclose(rot.quat_to_matrix(rot.matrix_to_quat(m)), m, atol=1e-15)


def test_quat_prefix_product_chains_increments() -> None:
    q0 = Rotation.random(rng=3)
    inc = Rotation.from_rotvec(RNG.normal(scale=0.1, size=(50, 3)))
    out = rot.quat_prefix_product(inc.as_quat(), q0.as_quat())
    acc = q0.as_matrix()
    for k in range(50):
        acc = acc @ inc[k].as_matrix()
    np.testing.assert_allclose(rot.quat_to_matrix(out[-1]), acc, atol=1e-13)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-15)


def test_orthonormalize() -> None:
    R = Rotation.random(4, rng=5).as_matrix()
    noisy = R + 1e-7 * np.random.default_rng(11).normal(size=R.shape)
    out = rot.orthonormalize(noisy)
    # Orthonormal to rounding: a 3x3 product carries a few ulp (eps = 2.2e-16) per element.
    ulp8 = 8 * np.finfo(float).eps
    np.testing.assert_allclose(out @ np.swapaxes(out, -1, -2), np.broadcast_to(np.eye(3),
                               (4, 3, 3)), atol=ulp8)
    np.testing.assert_allclose(np.linalg.det(out), 1.0, atol=ulp8)
    assert np.max(np.abs(out - R)) < 1e-6


@pytest.mark.parametrize('angle', [0.0, 1e-12, np.pi - 1e-9])
def test_edge_angles(angle: float) -> None:
    R = rot.rot_axis_angle([0, 0, 1], angle)
    np.testing.assert_allclose(np.linalg.norm(rot.matrix_to_rotvec(R)), angle, atol=1e-12)
