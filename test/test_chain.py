"""General chains (issue 15): kinematics of arms with joint origins and prismatic joints
against finite differences, URDF fixtures against the CONTRACT 2 YAML ones, limits."""
import math

import numpy as np
import pytest

from imu_calib_ros.core.earth import Site
from imu_calib_ros.core.errors import ConfigError, PlanError
from imu_calib_ros.core.fixture import Fixture, Joint, load_fixture
from imu_calib_ros.core.plans import build_profile, plan_from_dict
from imu_calib_ros.core.rotation import rpy_to_matrix, unskew
from imu_calib_ros.core.urdf_fixture import UrdfOptions, fixture_from_urdf

from test_fixture import FastEarthSite, d2_dt2, d_dt, profile

ARM = UrdfOptions('base_link', 'imu_link')


def random_chain(site: Site, kinds: tuple[str, ...], seed: int = 0) -> Fixture:
    """Joints with random origins (offsets ~0.3 m, random rotations) of the given kinds."""
    rng = np.random.default_rng(seed)
    joints = []
    for i, kind in enumerate(kinds):
        a = rng.normal(size=3)
        joints.append(Joint(f'j{i}', a / np.linalg.norm(a), kind,
                            rng.normal(scale=0.3, size=3), rpy_to_matrix(rng.uniform(-3, 3, 3))))
    return Fixture(site, tuple(joints), rng.uniform(-3, 3, 3), rng.normal(scale=0.05, size=3))


def assert_rel(actual: np.ndarray, ref: np.ndarray, rtol: float) -> None:
    err = np.max(np.abs(actual - ref))
    assert err <= rtol * np.max(np.abs(ref)), f'max error {err:.3g}'


@pytest.mark.parametrize('kinds', [('revolute',) * 4, ('revolute', 'prismatic', 'revolute'),
                                   ('prismatic', 'revolute', 'continuous', 'revolute')])
def test_chain_kinematics_by_finite_differences(kinds: tuple[str, ...]) -> None:
    """Position, velocity, acceleration of the IMU point and of the anchor, attitude, angular
    rate and its derivative of a general chain, against differences of positions/attitudes."""
    site = FastEarthSite(40.0, 0.0)
    n = len(kinds)
    fx = random_chain(site, kinds, seed=n)
    assert not fx.concurrent
    t = np.linspace(0.0, 6.0, 31)
    k = fx.kinematics(*profile(t, n))

    def p(tt):
        return fx.p_enu_m(profile(tt, n)[0])

    def v(tt):
        return fx.kinematics(*profile(tt, n)).v_enu_m_s

    def R(tt):
        return fx.R_enu_imu(profile(tt, n)[0])

    def anchor(tt):
        return fx.anchor_enu_m(profile(tt, n)[0])

    np.testing.assert_allclose(k.p_enu_m, p(t), atol=1e-15)
    assert_rel(k.v_enu_m_s, d_dt(p, t), 1e-9)
    assert_rel(k.a_enu_m_s2, d_dt(v, t), 1e-9)
    assert_rel(k.a_enu_m_s2, d2_dt2(p, t), 1e-7)
    R0 = R(t)
    assert_rel(k.omega_eb_enu_rad_s, unskew(d_dt(R, t) @ np.swapaxes(R0, -1, -2)), 1e-9)
    q, qd, _ = profile(t, n)
    assert_rel(fx.anchor_velocity_enu_m_s(q, qd), d_dt(anchor, t), 1e-9)
    # a chain's anchor is the nominal IMU point: lever arm zero
    np.testing.assert_array_equal(fx.lever_arm_imu_m, 0.0)
    np.testing.assert_allclose(k.p_enu_m, anchor(t), atol=1e-15)
    np.testing.assert_allclose(fx.anchor_velocity_enu_m_s(q, qd), k.v_enu_m_s, atol=1e-14)
    # specific force = R^T (a + 2 Omega x v - g)
    f = np.einsum('nji,nj->ni', R0, k.a_enu_m_s2 + 2 * np.cross(site.omega_ie_enu,
                                                                 k.v_enu_m_s) - site.g_enu)
    np.testing.assert_allclose(k.f_imu_m_s2, f, atol=1e-12)
