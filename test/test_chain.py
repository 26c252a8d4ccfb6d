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


@pytest.mark.parametrize('kinds', [('revolute',) * 4, ('revolute', 'prismatic', 'revolute'),
                                   ('prismatic', 'revolute', 'continuous', 'revolute')])
def test_anchor_velocity_jacobian_by_finite_differences(kinds: tuple[str, ...]) -> None:
    """``d v_anchor / d q`` (what a joint zero offset does to the chain velocity, issue 15)
    against central differences of ``anchor_velocity_enu_m_s`` in each joint angle, revolute
    and prismatic; zero at rest; zero on a turntable."""
    fx = random_chain(FastEarthSite(40.0, 0.0), kinds, seed=len(kinds) + 7)
    n = len(kinds)
    rng = np.random.default_rng(n)
    q, qd = rng.uniform(-2, 2, (9, n)), rng.normal(0, 0.7, (9, n))
    J = fx.anchor_velocity_jacobian_q(q, qd)
    h = 1e-6
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        fd = (fx.anchor_velocity_enu_m_s(q + e, qd) - fx.anchor_velocity_enu_m_s(q - e, qd)) / (
            2 * h)
        # a revolute joint turns the rest of the chain; a first prismatic joint moves it
        # without turning (nothing before it turns): no effect on the velocity
        assert np.abs(fd).max() > 1e-2 or (j == 0 and not fx.joints[j].revolute)
        assert np.abs(J[:, :, j] - fd).max() < 1e-8
    assert not fx.anchor_velocity_jacobian_q(q, np.zeros_like(qd)).any()
    tt = load_fixture('three_axis')
    assert not tt.anchor_velocity_jacobian_q(q[:, :3], qd[:, :3]).any()


def arm() -> Fixture:
    return load_fixture('arm6.urdf', ARM)


@pytest.mark.parametrize('name', ['three_axis', 'savage_2axis'])
def test_urdf_tables_equal_yaml_tables(name: str) -> None:
    """The shipped tables as URDF give the same fixture: site, joints, mounting, kinematics."""
    a, b = load_fixture(name), load_fixture(f'{name}.urdf', ARM)
    assert b.concurrent and a.joint_names == b.joint_names and a.site == b.site
    q = np.random.default_rng(0).uniform(-4, 4, (20, a.n_joints))
    ka, kb = a.kinematics(q, q * 0.3, q * 0.1), b.kinematics(q, q * 0.3, q * 0.1)
    for f in ('R_enu_imu', 'omega_ib_imu_rad_s', 'f_imu_m_s2', 'v_enu_m_s'):
        np.testing.assert_allclose(getattr(kb, f), getattr(ka, f), rtol=0, atol=1e-15)


def test_identical_calibrations_from_urdf_and_yaml() -> None:
    """The same bag calibrated with three_axis.yaml and three_axis.urdf: the same numbers."""
    from imu_calib_ros.core.estimator.replay import replay
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.plans import load_plan
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fy, fu = load_fixture('three_axis'), load_fixture('three_axis.urdf', ARM)
    sim = simulate(fy, build_profile(load_plan('demo_short'), fy), load_grade('nav_grade'),
                   SimConfig(imu_rate_hz=50, seed=3))

    def samples():  # noqa: ANN202
        out = [(int(t), 0, sim.joints.sample(i)) for i, t in enumerate(sim.joints.stamps_ns)]
        out += [(int(t), 1, sim.imu.sample(i)) for i, t in enumerate(sim.imu.stamps_ns)]
        return (s for *_, s in sorted(out, key=lambda x: x[:2]))

    ra = replay(samples, fy, None, None, 1).estimate()
    rb = replay(samples, fu, None, None, 1).estimate()
    va, vb = ra.errors.as_vector(), rb.errors.as_vector()
    sa, sb = ra.sigma.as_vector(), rb.sigma.as_vector()
    assert np.all(sa >= 0) and np.max(sa) > 0
    np.testing.assert_allclose(vb, va, rtol=0, atol=1e-12 * (1 + np.abs(va).max()))
    np.testing.assert_allclose(sb, sa, rtol=1e-9, atol=0)


def test_arm_urdf_geometry_and_limits() -> None:
    """UR5-like dimensions: reach at zero angles 0.425 + 0.392 m; limits and fixed joints
    folded (the IMU 30 mm beyond tool0, 82.3 mm beyond wrist 3)."""
    fx = arm()
    assert fx.n_joints == 6 and not fx.concurrent
    p0 = fx.p_enu_m(np.zeros(6))
    assert p0[0] == pytest.approx(0.425 + 0.39225, abs=1e-9)
    assert p0[2] == pytest.approx(0.089159 - 0.09465, abs=1e-9)
    np.testing.assert_allclose(fx.imu_xyz_m, [0, 0.0823 + 0.03, 0], atol=1e-15)
    elbow = fx.joints[fx.joint_index('elbow_joint')]
    assert elbow.upper == pytest.approx(math.pi) and elbow.velocity == pytest.approx(3.15)
    # CONTRACT 2 YAML round trip of the general chain (origins, limits)
    again = Fixture.from_dict(fx.to_dict())
    q = np.random.default_rng(1).uniform(-3, 3, (10, 6))
    np.testing.assert_allclose(again.p_enu_m(q), fx.p_enu_m(q), atol=1e-12)
    np.testing.assert_allclose(again.R_enu_imu(q), fx.R_enu_imu(q), atol=1e-12)


def test_plan_refuses_a_limit_naming_joint_and_limit() -> None:
    fx = arm()
    plan = plan_from_dict({'name': 'x', 'steps': [
        {'move': {'joint': 'elbow_joint', 'to_deg': 200.0, 'duration_s': 10.0}}]})
    with pytest.raises(PlanError, match=r"elbow_joint.*upper limit 180 deg"):
        build_profile(plan, fx)
    fast = plan_from_dict({'name': 'x', 'steps': [
        {'move': {'joint': 'wrist_3_joint', 'by_deg': 300.0, 'duration_s': 1.0}}]})
    with pytest.raises(PlanError, match=r"wrist_3_joint.*velocity limit"):
        build_profile(fast, fx)


def test_urdf_errors_name_the_problem(tmp_path) -> None:  # noqa: ANN001
    text = (Path_shipped('arm6.urdf')).read_text()
    with pytest.raises(ConfigError, match='no link'):
        load_fixture('arm6.urdf', UrdfOptions('base_link', 'imu'))
    with pytest.raises(ConfigError, match='not below'):
        load_fixture('arm6.urdf', UrdfOptions('imu_link', 'base_link'))
    bare = tmp_path / 'bare.urdf'
    bare.write_text(text.replace('<imu_calib_site', '<!-- ').replace(
        'base_rpy_deg="0 0 0"/>', '-->'))
    with pytest.raises(ConfigError, match='needs the site'):
        fixture_from_urdf(bare, ARM)
    fx = fixture_from_urdf(bare, UrdfOptions('base_link', 'imu_link', 10.0, 0.0))
    assert fx.site.latitude_deg == 10.0


def Path_shipped(name: str):  # noqa: ANN201, N802
    from imu_calib_ros.core.config import share_dir
    return share_dir() / 'config' / 'fixtures' / name


def test_shipped_arm_plan_within_limits_and_chain_velocity_measurement_exact() -> None:
    """The generated excitation plan runs within the URDF limits, turns the IMU about each
    of its axes; on the exact motion the chain velocity measurement's innovation is zero."""
    from imu_calib_ros.core.estimator.error_model import StateLayout
    from imu_calib_ros.core.estimator.measurements import zero_velocity
    from imu_calib_ros.core.plans import load_plan
    fx = arm()
    prof = build_profile(load_plan('arm6_excitation'), fx)
    t = np.linspace(0, prof.duration_s, 4001)
    q, qd, qdd = prof.evaluate(t)
    assert fx.check_limits(q, qd) is None
    k = fx.kinematics(q, qd, qdd)
    turned = {s.meta.get('imu_axis') for s in prof.segments if s.kind == 'move'}
    rot_labels = {s.label.split(':')[1] for s in prof.segments if s.label.startswith('rot:')}
    assert rot_labels == {'x', 'y', 'z'}, turned
    lay = StateLayout.build(('lever_arm',))
    z, _ = zero_velocity(k.v_enu_m_s, k.R_enu_imu, k.omega_ib_imu_rad_s, fx.site.omega_ie_enu,
                         np.zeros(3), lay, fx.anchor_velocity_enu_m_s(q, qd))
    assert np.abs(k.v_enu_m_s).max() > 0.3  # the arm moves the IMU fast
    assert np.abs(z).max() < 1e-12


def test_still_joint_clamp_does_not_hide_a_starting_move() -> None:
    """A chain joint's rate is zero only where it stays within the tolerance over the
    estimator's still window (CHAIN_STILL_HALF_WINDOW_S either side), not just +-3 samples:
    a quintic move of 1.5 rad over 5.4 s (arm6_excitation's orient moves) stays within 1e-4
    rad over +-3 samples at 100 Hz for its first ~0.1 s while its rate reaches 3e-3 rad/s;
    clamped, that is a 2-3 mm/s error at the end of an arm (gated against a tactical unit's
    zero-velocity noise, and taken for bias walk)."""
    from imu_calib_ros.core.estimator.buffers import JointBuffer
    from imu_calib_ros.core.estimator.estimator import CHAIN_STILL_HALF_WINDOW_S
    buf = JointBuffer({'joint_samples': 0})
    t = np.arange(0.0, 8.0, 0.01)  # 100 Hz: at rest 2 s, then the move
    s = np.clip((t - 2.0) / 5.4, 0.0, 1.0)
    q = 1.5 * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)
    buf.extend((t * 1e9).astype(np.int64), q[:, None])
    ts = np.array([1.0, 2.04, 2.07], float)  # at rest, 40 and 70 ms into the move
    true_rate = 1.5 * 30 * ((ts - 2.0).clip(0) / 5.4) ** 2 / 5.4
    _, _, qd3 = buf.motion_at((ts * 1e9).astype(np.int64), 1e-4)
    assert qd3[0, 0] == 0.0 and qd3[1, 0] == 0.0 and qd3[2, 0] == 0.0  # +-3 samples: clamped
    _, _, qd = buf.motion_at((ts * 1e9).astype(np.int64), 1e-4, CHAIN_STILL_HALF_WINDOW_S)
    assert qd[0, 0] == 0.0  # at rest, away from the move: still exactly zero
    np.testing.assert_allclose(qd[1:, 0], true_rate[1:], rtol=0.05)
