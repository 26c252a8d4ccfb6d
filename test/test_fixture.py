"""fixture.py: exact joint-chain kinematics checked by finite differences, geometry of the
shipped fixtures (Savage's Table 1), and strict validation of fixture files."""
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from imu_calib_ros.core.config import share_dir
from imu_calib_ros.core.earth import EARTH_RATE_RAD_S, Site
from imu_calib_ros.core.errors import ConfigError
from imu_calib_ros.core.fixture import Fixture, Joint, load_fixture
from imu_calib_ros.core.rotation import rot_axis_angle, rpy_to_matrix, unskew

FIXTURES = share_dir() / 'config' / 'fixtures'
E, N, U = np.eye(3)


@dataclass(frozen=True)
class FastEarthSite(Site):
    """A site whose earth turns at 0.3 rad/s, so earth-rate terms are visible in FD checks."""

    @property
    def omega_ie_enu(self) -> np.ndarray:
        return np.array([0.05, 0.2, -0.22])


def random_fixture(site: Site, n: int = 3, seed: int = 0) -> Fixture:
    rng = np.random.default_rng(seed)
    joints = []
    for i in range(n):
        a = rng.normal(size=3)
        joints.append(Joint(f'j{i}', a / np.linalg.norm(a)))
    return Fixture(site, tuple(joints), rng.uniform(-3, 3, 3), rng.normal(scale=0.05, size=3))


def profile(t: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Analytic joint angles q = A sin(w t + phi) + c t and their derivatives, (N, n)."""
    A = np.array([1.3, -0.7, 2.1, 0.4])[:n]
    w = np.array([1.1, 2.3, 0.7, 3.0])[:n]
    ph = np.array([0.2, -1.0, 0.5, 2.0])[:n]
    c = np.array([0.3, -0.5, 0.9, 0.1])[:n]
    tt = t[:, None]
    q = A * np.sin(w * tt + ph) + c * tt
    qd = A * w * np.cos(w * tt + ph) + c
    qdd = -A * w ** 2 * np.sin(w * tt + ph)
    return q, qd, qdd


def d_dt(fun, t: np.ndarray, h: float = 1e-3):
    """Fourth-order central difference of fun(t) (arrays with leading dim N)."""
    return (fun(t - 2 * h) - 8 * fun(t - h) + 8 * fun(t + h) - fun(t + 2 * h)) / (12 * h)


def d2_dt2(fun, t: np.ndarray, h: float = 2e-3):
    """Fourth-order central second difference."""
    return (-fun(t - 2 * h) + 16 * fun(t - h) - 30 * fun(t) + 16 * fun(t + h)
            - fun(t + 2 * h)) / (12 * h * h)


def assert_rel(actual: np.ndarray, ref: np.ndarray, rtol: float) -> None:
    scale = np.max(np.abs(ref))
    assert scale > 0
    err = np.max(np.abs(actual - ref))
    assert err <= rtol * scale, f'max error {err:.3g} > {rtol:g} * {scale:.3g}'


@pytest.mark.parametrize('n', [1, 2, 3, 4])
def test_kinematics_by_finite_differences(n: int) -> None:
    site = FastEarthSite(40.0, 0.0)
    fx = random_fixture(site, n, seed=n)
    t = np.linspace(0.0, 6.0, 41)
    k = fx.kinematics(*profile(t, n))
    Om = site.omega_ie_enu
    Om_rate = np.linalg.norm(Om)

    def p(tt):
        return fx.p_enu_m(profile(tt, n)[0])

    def R(tt):
        return fx.R_enu_imu(profile(tt, n)[0])

    def v(tt):
        return fx.kinematics(*profile(tt, n)).v_enu_m_s

    def earth(tt):  # ENU (earth-fixed) -> inertial: rotation about Omega by |Omega| t
        return rot_axis_angle(Om / Om_rate, Om_rate * tt)

    def R_i_imu(tt):
        return earth(tt) @ R(tt)

    def omega_ib(tt):
        return fx.kinematics(*profile(tt, n)).omega_ib_imu_rad_s

    np.testing.assert_allclose(k.R_enu_imu, R(t), atol=1e-15)
    assert_rel(k.v_enu_m_s, d_dt(p, t), 1e-9)
    assert_rel(k.a_enu_m_s2, d_dt(v, t), 1e-9)
    # omega relative to inertial space, from the derivative of the inertial attitude
    Ri = R_i_imu(t)
    w_fd = unskew(np.swapaxes(Ri, -1, -2) @ d_dt(R_i_imu, t))
    assert_rel(k.omega_ib_imu_rad_s, w_fd, 1e-9)
    # relative to the earth: omega_eb in ENU from dR/dt R^T
    R0 = R(t)
    assert_rel(k.omega_eb_enu_rad_s, unskew(d_dt(R, t) @ np.swapaxes(R0, -1, -2)), 1e-9)
    assert_rel(k.omega_dot_ib_imu_rad_s2, d_dt(omega_ib, t), 1e-9)
    # specific force: inertial acceleration of the point (FD of its inertial position) minus
    # gravitation; the model neglects Omega x (Omega x p), so add that back to the reference
    r_i = lambda tt: np.einsum('nij,nj->ni', earth(tt), p(tt))  # noqa: E731
    a_i_enu = np.einsum('nji,nj->ni', earth(t), d2_dt2(r_i, t))
    f_enu_ref = a_i_enu - np.cross(Om, np.cross(Om, p(t))) - site.g_enu
    f_ref = np.einsum('nji,nj->ni', R0, f_enu_ref)
    assert_rel(k.f_imu_m_s2, f_ref, 1e-9)
    # and the motion-only part (gravity removed) to the same relative level
    g_imu = np.einsum('nji,j->ni', R0, site.g_enu)
    assert_rel(k.f_imu_m_s2 + g_imu, f_ref + g_imu, 1e-8)


def test_kinematics_vectorised_equals_pointwise_and_batch_shapes() -> None:
    fx = random_fixture(Site(55.7, 200.0), 3, seed=9)
    t = np.linspace(0, 2, 7)
    q, qd, qdd = profile(t, 3)
    kb = fx.kinematics(q, qd, qdd)
    for i in range(len(t)):
        ki = fx.kinematics(q[i:i + 1], qd[i:i + 1], qdd[i:i + 1])
        np.testing.assert_allclose(ki.f_imu_m_s2[0], kb.f_imu_m_s2[i], rtol=0, atol=1e-15)
        np.testing.assert_allclose(ki.omega_dot_ib_imu_rad_s2[0], kb.omega_dot_ib_imu_rad_s2[i],
                                   rtol=0, atol=1e-15)
    assert fx.R_enu_imu(q.reshape(7, 1, 3)).shape == (7, 1, 3, 3)
    assert fx.joint_axes_enu(q).shape == (7, 3, 3)
    with pytest.raises(ValueError):
        fx.kinematics(q[:, :2], qd, qdd)


def test_static_specific_force_is_gravity_in_body_and_rate_is_earth_rate() -> None:
    fx = load_fixture('three_axis')
    rng = np.random.default_rng(1)
    q = rng.uniform(-np.pi, np.pi, size=(20, 3))
    k = fx.kinematics(q, np.zeros_like(q), np.zeros_like(q))
    g = fx.site.gravity
    R_T = np.swapaxes(k.R_enu_imu, -1, -2)
    np.testing.assert_allclose(k.f_imu_m_s2, R_T @ np.array([0, 0, g]), atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(k.f_imu_m_s2, axis=1), g, rtol=1e-15)
    np.testing.assert_allclose(k.omega_ib_imu_rad_s, R_T @ fx.site.omega_ie_enu, atol=1e-19)
    np.testing.assert_allclose(np.linalg.norm(k.omega_ib_imu_rad_s, axis=1), EARTH_RATE_RAD_S,
                               rtol=1e-14)
    assert np.all(k.omega_dot_ib_imu_rad_s2 == 0) and np.all(k.v_enu_m_s == 0)
    # IMU level and aligned with ENU: accelerometers read +g up (CONTRACT 1)
    level = Fixture.from_dict(_good())
    k0 = level.kinematics(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)))
    np.testing.assert_allclose(k0.f_imu_m_s2[0], [0, 0, level.site.gravity], atol=1e-15)


def test_lever_arm_spin_about_vertical_axis() -> None:
    """Constant spin about the vertical outer axis, IMU point 10 cm off axis: centripetal
    acceleration w^2 r towards the axis, speed w r, Coriolis 2 Omega x v."""
    d = {'site': {'latitude_deg': 55.7, 'height_m': 200.0},
         'joints': [{'name': 'yaw', 'axis': [0, 0, 1]}],
         'imu': {'rpy_deg': [0, 0, 0], 'xyz_m': [0.1, 0, 0]}}
    fx = Fixture.from_dict(d)
    w = 2.0
    t = np.linspace(0, 3, 5)
    k = fx.kinematics((w * t)[:, None], np.full((5, 1), w), np.zeros((5, 1)))
    np.testing.assert_allclose(np.linalg.norm(k.v_enu_m_s, axis=1), 0.2, rtol=1e-15)
    # in the IMU frame the point is at +x: centripetal -w^2 r x; tangential zero
    Om_imu = np.einsum('nji,j->ni', k.R_enu_imu, fx.site.omega_ie_enu)
    v_imu = np.einsum('nji,nj->ni', k.R_enu_imu, k.v_enu_m_s)
    expect = np.array([-w * w * 0.1, 0, fx.site.gravity]) + 2 * np.cross(Om_imu, v_imu)
    np.testing.assert_allclose(k.f_imu_m_s2, expect, atol=1e-14)
    np.testing.assert_allclose(k.omega_ib_imu_rad_s, Om_imu + [0, 0, w], atol=1e-15)


def test_savage_fixture_geometry_table_1() -> None:
    fx = load_fixture('savage_2axis')
    assert fx.joint_names == ('outer', 'inner')
    outer_enu = fx.joints[0].axis
    np.testing.assert_allclose(abs(outer_enu @ U), 0, atol=1e-15)  # horizontal
    R0 = fx.R_enu_imu(np.zeros(2))
    np.testing.assert_allclose(R0 @ [0, 0, 1], [0, 0, -1], atol=1e-15)  # z down
    np.testing.assert_allclose(R0 @ [0, 1, 0], outer_enu, atol=1e-15)  # y along outer
    # inner axis along IMU z at all angles; outer axis along IMU y at zero angles
    q = np.random.default_rng(2).uniform(-4, 4, size=(10, 2))
    ax_imu = fx.joint_axes_imu(q)
    np.testing.assert_allclose(ax_imu[:, 1], np.tile([0, 0, 1.0], (10, 1)), atol=1e-15)
    np.testing.assert_allclose(fx.joint_axes_imu(np.zeros(2))[0], [0, 1, 0], atol=1e-15)
    down = np.array([0, 0, -1.0])
    # Table 1 (METHODS.md): (inner, outer) deg -> IMU axis down, IMU axis along outer
    rows = {(0, 0): (2, 1), (90, 0): (2, 0), (0, -90): (0, 1), (90, 90): (1, 0)}
    for (inner, outer), (ax_down, ax_outer) in rows.items():
        R = fx.R_enu_imu(np.radians([outer, inner]))
        np.testing.assert_allclose(R[:, ax_down], down, atol=1e-15,
                                   err_msg=f'inner {inner} outer {outer}')
        np.testing.assert_allclose(abs(R[:, ax_outer] @ outer_enu), 1.0, atol=1e-15)


def test_three_axis_fixture() -> None:
    """Vertical outer axis, horizontal middle axis, inner axis perpendicular to the middle
    one; the IMU mounted square (axes along joint axes) so each IMU axis can be stood up
    and down with quarter turns, and the inner axis stays along one IMU axis."""
    fx = load_fixture('three_axis')
    assert fx.joint_names == ('outer', 'middle', 'inner')
    rng = np.random.default_rng(3)
    q = rng.uniform(-4, 4, size=(20, 3))
    ax = fx.joint_axes_enu(q)
    np.testing.assert_allclose(ax[:, 0], np.tile(U, (20, 1)), atol=1e-15)  # outer vertical
    np.testing.assert_allclose(ax[:, 1] @ U, 0.0, atol=1e-15)  # middle horizontal
    np.testing.assert_allclose(np.einsum('ni,ni->n', ax[:, 1], ax[:, 2]), 0.0, atol=1e-15)
    # R_rpy is a signed permutation: IMU axes along the joint frame's axes
    Rm = fx.R_joint_imu
    np.testing.assert_allclose(np.sort(np.abs(Rm), axis=None)[-3:], 1.0, atol=1e-15)
    inner_imu = fx.joint_axes_imu(q)[:, 2]
    np.testing.assert_allclose(inner_imu, np.tile(inner_imu[0], (20, 1)), atol=1e-15)
    assert np.max(np.abs(inner_imu[0])) == pytest.approx(1.0, abs=1e-15)
    # every IMU axis can point up and down with middle/inner at multiples of 90 deg
    grid = np.radians([[0, m, i] for m in (-90, 0, 90, 180) for i in (-90, 0, 90, 180)])
    R = fx.R_enu_imu(grid)
    for axis in range(3):
        for sign in (1, -1):
            assert np.any(np.abs(R[:, 2, axis] - sign) < 1e-15), (axis, sign)
    for name in ('savage_2axis', 'three_axis'):
        f = load_fixture(name)
        assert f.site.latitude_deg == 55.7 and f.site.height_m == 200.0
        np.testing.assert_array_equal(f.imu_xyz_m, 0.0)


def test_with_mounting_composes_small_rotation_in_imu_frame() -> None:
    fx = load_fixture('savage_2axis')
    drpy = np.array([1e-3, -0.5e-3, 0.8e-3])
    dxyz = np.array([0.002, -0.003, 0.001])
    true = fx.with_mounting(drpy, dxyz)
    q = np.array([[0.3, -1.2]])
    np.testing.assert_allclose(true.R_enu_imu(q), fx.R_enu_imu(q) @ rpy_to_matrix(drpy),
                               atol=1e-15)
    np.testing.assert_allclose(true.imu_xyz_m, dxyz, atol=0)
    np.testing.assert_allclose(true.p_enu_m(q), fx.R_enu_joint(q) @ dxyz, atol=1e-18)
    assert fx.imu_xyz_m[0] == 0.0  # nominal untouched


def test_round_trip_to_dict() -> None:
    fx = load_fixture('savage_2axis')
    fx2 = Fixture.from_dict(fx.to_dict())
    np.testing.assert_allclose(fx2.R_joint_imu, fx.R_joint_imu, atol=1e-15)
    assert fx2.site == fx.site and fx2.joint_names == fx.joint_names


def test_axis_nearly_unit_is_normalised() -> None:
    d = _good()
    d['joints'][1]['axis'] = [1.0005, 0.0, 0.0]
    fx = Fixture.from_dict(d)
    np.testing.assert_allclose(np.linalg.norm(fx.joints[1].axis), 1.0, rtol=1e-15)


def _good() -> dict:
    return {'site': {'latitude_deg': 55.7, 'height_m': 200.0},
            'joints': [{'name': 'outer', 'axis': [0, 0, 1]},
                       {'name': 'middle', 'axis': [1, 0, 0]},
                       {'name': 'inner', 'axis': [0, 1, 0]}],
            'imu': {'rpy_deg': [0, 0, 0], 'xyz_m': [0, 0, 0]}}


def _set(d: dict, path: list, value) -> dict:
    node = d
    for p in path[:-1]:
        node = node[p]
    if value is _DEL:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return d


_DEL = object()


@pytest.mark.parametrize('path, value, key, words', [
    (['extra'], 1, 'extra', 'unknown key'),
    (['imu'], _DEL, 'imu', 'missing'),
    (['site'], _DEL, 'site', 'missing'),
    (['joints'], [], 'joints', 'non-empty'),
    (['joints', 1, 'axis'], [1.1, 0, 0], 'joints[1].axis', 'unit'),
    (['joints', 1, 'axis'], [0, 0, 0], 'joints[1].axis', 'zero'),
    (['joints', 1, 'axis'], [0, 0, -1], 'joints[1].axis', 'parallel'),
    (['joints', 2, 'axis'], [1, 0, 0], 'joints[2].axis', 'parallel'),
    (['joints', 1, 'axis'], [1, 0], 'joints[1].axis', 'list of 3'),
    (['joints', 2, 'name'], 'outer', 'joints[2].name', 'duplicate'),
    (['joints', 0, 'name'], '', 'joints[0].name', 'string'),
    (['joints', 0, 'speed'], 3, 'joints[0].speed', 'unknown key'),
    (['joints', 0, 'axis'], _DEL, 'joints[0].axis', 'missing'),
    (['site', 'latitude_deg'], 120.0, 'site.latitude_deg', '[-90, 90]'),
    (['site', 'gravity_m_s2'], 9.6, 'site.gravity_m_s2', 'outside'),
    (['imu', 'xyz_m'], [0, 'a', 0], 'imu.xyz_m', 'numbers'),
    (['imu', 'rpy_deg'], _DEL, 'imu.rpy_deg', 'missing'),
])
def test_from_dict_refuses(path: list, value, key: str, words: str) -> None:
    d = _set(_good(), path, value)
    with pytest.raises(ConfigError) as ei:
        Fixture.from_dict(d, 'fx.yaml')
    assert ei.value.source == 'fx.yaml'
    assert ei.value.key == key, str(ei.value)
    assert words in str(ei.value)
    assert '\n' not in str(ei.value)


def test_from_yaml_errors_name_the_file(tmp_path: Path) -> None:
    p = tmp_path / 'bad.yaml'
    p.write_text('site: [1, 2\n')
    with pytest.raises(ConfigError, match='bad.yaml'):
        Fixture.from_yaml(p)
    with pytest.raises(ConfigError, match='no shipped fixtures'):
        load_fixture('no_such_fixture')
    p.write_text('site: {latitude_deg: 95, height_m: 0}\njoints: [{name: a, axis: [0,0,1]}]\n'
                 'imu: {rpy_deg: [0,0,0], xyz_m: [0,0,0]}\n')
    with pytest.raises(ConfigError, match=r'bad.yaml: site.latitude_deg'):
        Fixture.from_yaml(p)
