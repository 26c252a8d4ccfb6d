"""Self-checks of the independent world oracle (imu_calib_ros.testing), fast (< 30 s).

Analytic cases (rest, a 360 deg turn with a scale error, interval mean vs point sample, the
size effect by hand), timing (latency, receipt-delay reordering), the bag read back with
rosbags (and with our reader), the truth file, and one cross-check against our own
simulator (core/simulator.py) on a shared case.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from imu_calib_ros.testing.world_cases import compare_calibration, make_case
from imu_calib_ros.testing.world_sim import (EARTH_RATE_RAD_S, Mounting, Unit, UnitErrors,
                                             UnitNoise, WorldConfig, WorldFixture, _Instant,
                                             body_motion, draw_unit, fixture_path, generate,
                                             joint_profile, normal_gravity, sensor_outputs,
                                             write_bag)
from imu_calib_ros.testing.world_units import SPECS, UNIT_KINDS

LAT_DEG = 48.0
START = WorldConfig().start_stamp_ns


def _fixture_file(tmp_path: Path, rpy_deg: Any = (0.0, 0.0, 0.0), xyz_m: Any = (0, 0, 0),
                  axes: Any = ((0.0, 0.0, 1.0),), name: str = 'fx.yaml',
                  gravity: float | None = None) -> Path:
    site: dict[str, Any] = {'latitude_deg': LAT_DEG, 'height_m': 300.0}
    if gravity is not None:
        site['gravity_m_s2'] = gravity
    d = {'site': site,
         'joints': [{'name': f'j{i}', 'axis': list(map(float, a))} for i, a in enumerate(axes)],
         'imu': {'rpy_deg': list(map(float, rpy_deg)), 'xyz_m': list(map(float, xyz_m))}}
    p = tmp_path / name
    p.write_text(yaml.safe_dump(d))
    return p


def _plan(steps: list[dict[str, Any]]) -> Any:
    from imu_calib_ros.core.plans import plan_from_dict
    return plan_from_dict({'name': 'test', 'steps': steps})


def _unit(errors: UnitErrors | None = None) -> Unit:
    return Unit('nav', 1.0, errors or UnitErrors.zeros(), UnitNoise())


def _rpy_matrix(r: float, p: float, y: float) -> np.ndarray:
    """Rz(y) Ry(p) Rx(r), written out by hand (CONTRACT 2)."""
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y),
                              math.sin(y))
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


NOISE_FREE = WorldConfig(noise=False)


# ------------------------------------------------------------------------------ earth
def test_normal_gravity_and_earth_rate_match_the_references() -> None:
    """Own WGS-84 formula vs core.earth (a different transcription) and TR8350.2 values."""
    from imu_calib_ros.core import earth
    for lat in (0.0, 30.0, 55.7, 90.0):
        for h in (0.0, 200.0, 3000.0):
            g = normal_gravity(math.radians(lat), h)
            assert g == pytest.approx(earth.normal_gravity_m_s2(math.radians(lat), h),
                                      rel=1e-10)
    assert normal_gravity(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert normal_gravity(math.pi / 2, 0.0) == pytest.approx(9.8321849378, abs=1e-9)
    assert EARTH_RATE_RAD_S == pytest.approx(earth.EARTH_RATE_RAD_S, rel=3e-8)


def test_rpy_convention_is_rz_ry_rx(tmp_path: Path) -> None:
    fx = WorldFixture.from_yaml(_fixture_file(tmp_path, rpy_deg=(30.0, -20.0, 75.0)))
    want = _rpy_matrix(*np.radians([30.0, -20.0, 75.0]))
    assert np.abs(fx.R_joint_imu_nominal.as_matrix() - want).max() < 1e-15


# ----------------------------------------------------------------------- analytic cases
def test_error_free_unit_at_rest_reads_g_up_and_earth_rate(tmp_path: Path) -> None:
    fxp = _fixture_file(tmp_path)
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 1.0}}]), fxp)
    for st in ('interval_mean', 'point'):
        d = generate(fx, prof, _unit(), Mounting(), dataclasses.replace(NOISE_FREE,
                                                                         sample_type=st))
        lat = math.radians(LAT_DEG)
        g = normal_gravity(lat, 300.0)
        w = EARTH_RATE_RAD_S * np.array([0.0, math.cos(lat), math.sin(lat)])
        assert np.abs(d.accel_m_s2 - [0.0, 0.0, g]).max() < 1e-14
        assert np.abs(d.gyro_rad_s - w).max() < 1e-19
    fx2 = WorldFixture.from_yaml(_fixture_file(tmp_path, gravity=9.81, name='g.yaml'))
    d = generate(fx2, prof, _unit(), Mounting(), NOISE_FREE)
    assert np.abs(d.accel_m_s2 - [0.0, 0.0, 9.81]).max() < 1e-14


def test_360_turn_with_scale_error_integrates_to_2pi_1_plus_k(tmp_path: Path) -> None:
    fxp = _fixture_file(tmp_path)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 1.0}},
                                {'move': {'joint': 'j0', 'by_deg': 360.0, 'duration_s': 4.0}},
                                {'dwell': {'duration_s': 1.0}}]), fxp)
    k = 0.01
    errors = UnitErrors.zeros().replace(gyro_scale_misalignment=np.diag([0.0, 0.0, k]))
    fx = dataclasses.replace(WorldFixture.from_yaml(fxp), earth_rate_rad_s=0.0)
    for rate in (100.0, 137.0):  # 137 Hz: samples straddle the move's start and end
        d = generate(fx, prof, _unit(errors), Mounting(),
                     dataclasses.replace(NOISE_FREE, imu_rate_hz=rate))
        dt = int(round(1e9 / rate)) * 1e-9
        angle = d.gyro_rad_s[:, 2].sum() * dt
        assert angle == pytest.approx(2.0 * math.pi * (1.0 + k), rel=1e-13)
    # with the earth turning: (1 + k) (2 pi + Omega sin(lat) T)
    fx = WorldFixture.from_yaml(fxp)
    d = generate(fx, prof, _unit(errors), Mounting(), NOISE_FREE)
    t_end = len(d.gyro_rad_s) * 0.01
    want = (1 + k) * (2 * math.pi + EARTH_RATE_RAD_S * math.sin(math.radians(LAT_DEG)) * t_end)
    assert d.gyro_rad_s[:, 2].sum() * 0.01 == pytest.approx(want, rel=1e-13)


def test_interval_mean_and_point_sample_differ_as_they_should(tmp_path: Path) -> None:
    """Mean of qd over (t-dt, t] = (q(t) - q(t-dt)) / dt; point = qd(t); their difference
    is -qdd dt / 2 to first order."""
    fxp = _fixture_file(tmp_path)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 0.5}},
                                {'move': {'joint': 'j0', 'by_deg': 90.0, 'duration_s': 2.0}},
                                {'dwell': {'duration_s': 0.5}}]), fxp)
    fx = dataclasses.replace(WorldFixture.from_yaml(fxp), earth_rate_rad_s=0.0)
    rate = 50.0
    mean = generate(fx, prof, _unit(), Mounting(), dataclasses.replace(NOISE_FREE,
                                                                        imu_rate_hz=rate))
    point = generate(fx, prof, _unit(), Mounting(),
                     dataclasses.replace(NOISE_FREE, imu_rate_hz=rate, sample_type='point'))
    dt = 1.0 / rate
    t = (mean.imu_stamps_ns - START) * 1e-9
    q1, qd1, qdd1 = prof.evaluate(t)
    q0, _, _ = prof.evaluate(t - dt)
    # (q1 - q0) / dt loses ~eps q / dt = 1e-14 rad/s to cancellation
    assert np.abs(mean.gyro_rad_s[:, 2] - (q1 - q0)[:, 0] / dt).max() < 1e-12
    assert np.abs(point.gyro_rad_s[:, 2] - qd1[:, 0]).max() < 1e-15
    diff = mean.gyro_rad_s[:, 2] - point.gyro_rad_s[:, 2]
    assert np.abs(diff).max() > 1e-3  # they do differ, by about half a sample of qdd
    assert np.abs(diff + qdd1[:, 0] * dt / 2).max() < 0.05 * np.abs(qdd1[:, 0] * dt / 2).max()


def test_size_effect_against_a_hand_calculation(tmp_path: Path) -> None:
    """Spin about the vertical with the IMU tilted: u = spin axis in the IMU frame, then
    accelerometer i gains w^2 u_i (u . r_i) + qdd (u x r_i)_i (r_i[i] = 0), nothing else."""
    rpy = np.radians([30.0, 20.0, 10.0])
    fxp = _fixture_file(tmp_path, rpy_deg=np.degrees(rpy), xyz_m=(0.02, -0.01, 0.03))
    fx = dataclasses.replace(WorldFixture.from_yaml(fxp), earth_rate_rad_s=0.0)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 0.2}},
                                {'spin': {'joint': 'j0', 'rate_deg_s': 200.0,
                                          'duration_s': 3.0, 'ramp_s': 1.0}}]), fxp)
    r = np.array([[0.0, 0.011, -0.007], [0.013, 0.0, 0.005], [-0.004, 0.009, 0.0]])
    cfg = dataclasses.replace(NOISE_FREE, sample_type='point', imu_rate_hz=20.0)
    with_r = generate(fx, prof, _unit(UnitErrors.zeros().replace(size_effect_m=r)),
                      Mounting(), cfg)
    without = generate(fx, prof, _unit(), Mounting(), cfg)
    t = (with_r.imu_stamps_ns - START) * 1e-9
    _, qd, qdd = prof.evaluate(t)
    u = _rpy_matrix(*rpy).T @ np.array([0.0, 0.0, 1.0])
    want = np.empty((len(t), 3))
    for i in range(3):
        want[:, i] = qd[:, 0] ** 2 * u[i] * (u @ r[i]) + qdd[:, 0] * np.cross(u, r[i])[i]
    got = with_r.accel_m_s2 - without.accel_m_s2
    assert np.abs(want).max() > 0.03  # a real effect: 0.065 m/s^2 at 200 deg/s
    assert np.abs(got - want).max() < 1e-13
    assert np.abs(with_r.gyro_rad_s - without.gyro_rad_s).max() == 0.0


def test_specific_force_includes_lever_arm_centripetal_and_coriolis(tmp_path: Path) -> None:
    """Reference point at rho from a vertical axis spinning at w: f = (-w^2 rho_xy, g) plus
    the Coriolis 2 Omega x v and the earth's Omega x (Omega x rho) (ENU expansion)."""
    rho = np.array([0.05, 0.0, 0.0])
    fxp = _fixture_file(tmp_path, xyz_m=rho)
    fx = WorldFixture.from_yaml(fxp)
    w = math.radians(90.0)
    q = np.array([[0.3]])
    m = body_motion(fx, Mounting(), q, np.array([[w]]), np.array([[0.0]]))
    _, _, f = sensor_outputs(UnitErrors.zeros(), m)
    c, s = math.cos(0.3), math.sin(0.3)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])  # R_enu_imu
    p = R @ rho
    we = np.array([0.0, 0.0, w])
    om = fx.omega_ie_enu
    v = np.cross(we, p)
    f_enu = np.cross(we, v) + 2 * np.cross(om, v) + np.cross(om, np.cross(om, p)) + \
        [0, 0, fx.gravity]
    assert np.abs(R.T @ f_enu - f[0]).max() < 1e-15


def test_a_base_off_level_turns_gravity_and_earth_rate_not_the_table_rates() -> None:
    """A base tilted by (t_e, t_n) about ENU east and north: at rest the IMU reads gravity
    tilted by it, while a turn about the (tilted) outer axis reads the same rate in the IMU
    frame as on a level base; the world's kinematics agree with the product's fixture
    (``Fixture.with_base_tilt``, written on its own) to rounding."""
    from scipy.spatial.transform import Rotation

    from imu_calib_ros.core.fixture import load_fixture
    fx = WorldFixture.from_yaml(fixture_path('three_axis'))
    t = np.array([3e-3, -2e-3])
    base = Rotation.from_rotvec([t[0], t[1], 0.0])
    zero = np.zeros((1, 3))
    m = body_motion(fx, Mounting(), zero, zero, zero, base)
    _, _, f = sensor_outputs(UnitErrors.zeros(), m)
    _, _, f_level = sensor_outputs(UnitErrors.zeros(), body_motion(fx, Mounting(), zero, zero,
                                                                   zero))
    # gravity as seen on the base's own axes: up, tilted back by t (about east: +y)
    g_base = base.inv().apply([0.0, 0.0, fx.gravity])
    assert g_base[1] == pytest.approx(fx.gravity * t[0], rel=1e-3)
    R_level = body_motion(fx, Mounting(), zero, zero, zero).R_enu_imu
    assert np.abs(f[0] - R_level.inv().apply(g_base)).max() < 1e-6  # (+ earth's centripetal)
    assert np.linalg.norm(f[0] - f_level[0]) == pytest.approx(fx.gravity * np.linalg.norm(t),
                                                              rel=1e-3)
    qd = np.array([[0.5, 0.0, 0.0]])
    level = body_motion(fx, Mounting(), zero, qd, zero)
    tilted = body_motion(fx, Mounting(), zero, qd, zero, base)
    d = tilted.omega_ib_imu_rad_s - level.omega_ib_imu_rad_s
    assert np.abs(d).max() < 1e-3 * EARTH_RATE_RAD_S * 10  # only earth rate turns, by t
    q = np.random.default_rng(4).uniform(-3.0, 3.0, (7, 3))
    m = body_motion(fx, Mounting(), q, np.zeros_like(q), np.zeros_like(q), base)
    R_product = load_fixture('three_axis').with_base_tilt(t).R_enu_imu(q)
    assert np.abs(R_product - m.R_enu_imu.as_matrix()).max() < 1e-14


# ------------------------------------------------------------------------ quadrature
def test_interval_means_are_exact_at_zero_crossings(tmp_path: Path) -> None:
    """With asymmetry errors the integrand has kinks; the world splits at the roots, so a
    brute-force adaptive quadrature agrees to ~1e-12 on every sample of a tumbling move."""
    from scipy.integrate import quad
    fxp = _fixture_file(tmp_path, rpy_deg=(20.0, 35.0, 0.0), axes=((0, 0, 1.0), (1.0, 0, 0)))
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 0.1}},
                                {'move': {'joint': 'j1', 'by_deg': 200.0, 'duration_s': 1.5}},
                                {'dwell': {'duration_s': 0.1}}]), fxp)
    e = UnitErrors.zeros().replace(gyro_scale_asymmetry=[3e-3, -2e-3, 1e-3],
                                   accel_scale_asymmetry=[3e-3, 2e-3, -3e-3])
    d = generate(fx, prof, _unit(e), Mounting(), dataclasses.replace(NOISE_FREE,
                                                                      imu_rate_hz=20.0))
    inst = _Instant(fx, prof, Mounting(), e)
    dt = 0.05
    x, w = np.polynomial.legendre.leggauss(6)
    worst, worst_plain = 0.0, 0.0
    for k in range(len(d.gyro_rad_s)):
        t_gl = (k + 0.5) * dt + 0.5 * dt * x
        g, a, _, _ = inst(t_gl)
        plain = (w @ np.concatenate([g, a], axis=1)) / 2.0  # one rule, no split
        world = np.concatenate([d.gyro_rad_s[k], d.accel_m_s2[k]])
        if k % 4 and np.abs(plain - world).max() < 1e-12:
            continue  # quadrature (slow) on the samples with a kink and every 4th other one
        for c in range(6):
            def fn(t: float, c: int = c) -> float:
                g, a, _, _ = inst(np.array([t]))
                return float(np.concatenate([g, a], axis=1)[0, c])
            with warnings.catch_warnings():
                warnings.simplefilter('ignore')  # quad's roundoff notice near 1e-15
                ref = quad(fn, k * dt, (k + 1) * dt, epsabs=1e-15, epsrel=1e-14,
                           limit=200)[0] / dt
            got = np.concatenate([d.gyro_rad_s[k], d.accel_m_s2[k]])[c]
            scale = 1.0 if c < 3 else 10.0
            worst = max(worst, abs(got - ref) / scale)
            worst_plain = max(worst_plain, abs(plain[c] - ref) / scale)
    assert worst < 1e-11
    assert worst_plain > 1e-7  # the test has teeth: one unsplit rule per sample is far off


# ------------------------------------------------------------------------------ timing
def test_latency_shifts_joint_stamps(tmp_path: Path) -> None:
    fxp = _fixture_file(tmp_path)
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 0.5}},
                                {'move': {'joint': 'j0', 'by_deg': 90.0, 'duration_s': 2.0}},
                                {'dwell': {'duration_s': 0.5}}]), fxp)
    for lat in (-0.05, 0.02):
        d = generate(fx, prof, _unit(), Mounting(),
                     dataclasses.replace(NOISE_FREE, joint_latency_s=lat, joint_rate_hz=40.0))
        t_stamp = (d.joint_stamps_ns - START) * 1e-9
        q_true, qd_true, _ = prof.evaluate(t_stamp - lat)  # stamp = true time + latency
        assert np.abs(d.joint_position_rad - q_true).max() < 1e-15
        assert np.abs(d.joint_velocity_rad_s - qd_true).max() < 1e-15
        q_at_stamp, _, _ = prof.evaluate(t_stamp)
        assert np.abs(d.joint_position_rad - q_at_stamp).max() > 0.01
        assert d.truth['imu_calibration']['time']['joint_latency_s'] == lat


def _read_rosbags(bag: Path) -> list[tuple[int, str, Any]]:
    """(log time, topic, message) in storage order, with rosbags' own reader."""
    from rosbags.highlevel import AnyReader
    out = []
    with AnyReader([bag]) as r:
        for conn, log_ns, raw in r.messages():
            out.append((log_ns, conn.topic, r.deserialize(raw, conn.msgtype)))
    return out


def test_receipt_delay_reorders_log_times_at_2khz(tmp_path: Path) -> None:
    fxp = _fixture_file(tmp_path)
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 0.3}}]), fxp)
    cfg = dataclasses.replace(NOISE_FREE, imu_rate_hz=2000.0, receipt_delay_s=(1.5e-3, 2.5e-3))
    d = generate(fx, prof, _unit(), Mounting(), cfg, seed=4)
    bag = write_bag(tmp_path / 'bag', d)
    msgs = _read_rosbags(bag)
    imu = [(log, m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
           for log, topic, m in msgs if topic == '/imu/data_raw']
    logs = np.array([x[0] for x in imu])
    stamps = np.array([x[1] for x in imu])
    assert np.all(np.diff(logs) >= 0)  # the bag is in log-time (receipt) order
    assert np.sum(np.diff(stamps) < 0) > 10  # ... and so header stamps are not
    assert np.all((logs - stamps >= 1_500_000) & (logs - stamps <= 2_500_000))
    assert sorted(stamps.tolist()) == d.imu_stamps_ns.tolist()


def test_receipt_stamps_are_late_by_the_jitter_and_increasing(tmp_path: Path) -> None:
    """imu_stamp_jitter_s / joint_stamp_jitter_s: header stamps U(0, jitter) after the true
    instants, strictly increasing; the values are those of the true instants."""
    fxp = _fixture_file(tmp_path)
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 20.0}}]), fxp)
    base = generate(fx, prof, _unit(), Mounting(), NOISE_FREE, seed=3)
    cfg = dataclasses.replace(NOISE_FREE, imu_stamp_jitter_s=2e-3, joint_stamp_jitter_s=4e-3)
    d = generate(fx, prof, _unit(), Mounting(), cfg, seed=3)
    late_i = (d.imu_stamps_ns - base.imu_stamps_ns) * 1e-9
    late_j = (d.joint_stamps_ns - base.joint_stamps_ns) * 1e-9
    for late, jit in ((late_i, 2e-3), (late_j, 4e-3)):
        assert late.min() >= 0.0 and late.max() <= jit
        assert late.mean() == pytest.approx(jit / 2, rel=0.05)  # 2000 draws: 1.3 % spread
    assert np.all(np.diff(d.imu_stamps_ns) > 0) and np.all(np.diff(d.joint_stamps_ns) > 0)
    assert np.array_equal(d.gyro_rad_s, base.gyro_rad_s)
    assert np.array_equal(d.joint_position_rad, base.joint_position_rad)


def test_joint_states_on_change_are_silent_at_rest(tmp_path: Path) -> None:
    """joint_on_change_rad: a state only when a joint moved by more than the threshold since
    the last one published: one at the start of a dwell, none during it."""
    fxp = _fixture_file(tmp_path)
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 10.0}},
                                {'move': {'joint': 'j0', 'by_deg': 90.0, 'duration_s': 5.0}},
                                {'dwell': {'duration_s': 10.0}}]), fxp)
    cfg = dataclasses.replace(NOISE_FREE, joint_on_change_rad=1e-3)
    d = generate(fx, prof, _unit(), Mounting(), cfg, seed=1)
    t = (d.joint_stamps_ns - START) * 1e-9
    assert t[0] == 0.0 and np.all((t[1:] > 9.9) & (t[1:] < 15.1))  # only while it turns
    dq = np.abs(np.diff(d.joint_position_rad[:, 0]))
    assert np.all(dq[1:] > 1e-3)  # every published state moved by more than the threshold


def test_drops_come_in_bursts_and_keep_the_ends(tmp_path: Path) -> None:
    fxp = _fixture_file(tmp_path)
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 20.0}}]), fxp)
    cfg = dataclasses.replace(NOISE_FREE, drop_fraction_imu=0.02, drop_fraction_joint=0.05)
    d = generate(fx, prof, _unit(), Mounting(), cfg, seed=2)
    k = (d.imu_stamps_ns - START) // 10_000_000
    assert k[0] == 1 and k[-1] == 2000
    lost = 2000 - len(k)
    assert 40 <= lost <= 60
    gaps = np.diff(k)[np.diff(k) > 1] - 1
    assert gaps.mean() > 1.5  # bursts, not single samples
    assert len(d.joint_stamps_ns) < 0.97 * 2001


# --------------------------------------------------------------------------- bag I/O
def test_bag_reads_back_with_rosbags_and_with_our_reader(tmp_path: Path) -> None:
    from msg_adapters.bag import read_bag
    fxp = _fixture_file(tmp_path, axes=((0, 0, 1.0), (1.0, 0, 0)))
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 0.5}},
                                {'move': {'joint': 'j0', 'by_deg': 270.0, 'duration_s': 2.0}},
                                {'move': {'joint': 'j1', 'by_deg': -200.0, 'duration_s': 2.0}}]),
                         fxp)
    unit = draw_unit('consumer_mems', 1.0, np.random.default_rng(3))
    cfg = WorldConfig(imu_rate_hz=200.0, joint_rate_hz=15.0, wrap_joints=True,
                      joint_velocities=False, joint_order='reversed', extra_joint=True,
                      joint_latency_s=0.013)
    d = generate(fx, prof, unit, Mounting(np.radians([3.0, -5.0, 7.0]), np.array([0.01, 0, 0])),
                 cfg, seed=9)
    bag = write_bag(tmp_path / 'bag', d)
    msgs = _read_rosbags(bag)
    imu = [m for _, topic, m in msgs if topic == '/imu/data_raw']
    js = [m for _, topic, m in msgs if topic == '/joint_states']
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                     for m in imu])
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                    for m in imu])
    assert np.array_equal(gyro, d.gyro_rad_s) and np.array_equal(acc, d.accel_m_s2)
    assert all(m.orientation_covariance[0] == -1.0 and m.header.frame_id == 'imu_link'
               for m in imu)
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in imu] == \
        d.imu_stamps_ns.tolist()
    assert list(js[0].name) == ['j1', 'j0', 'gripper_extra']
    pos = np.array([m.position for m in js])
    assert np.array_equal(pos, d.joint_position_rad)
    assert pos[:, :2].max() <= math.pi and pos[:, :2].min() > -math.pi
    assert pos[:, :2].max() > 3.0  # really wrapped somewhere
    assert all(len(m.velocity) == 0 for m in js)
    # our own reader (msg_adapters.bag) against this independent writer
    ib, jb = read_bag(bag, '/imu/data_raw', '/joint_states')
    assert np.array_equal(ib.gyro_rad_s, d.gyro_rad_s)
    assert np.array_equal(ib.stamps_ns, d.imu_stamps_ns)
    assert np.array_equal(jb.stamps_ns, d.joint_stamps_ns)


def test_truth_file_is_contract4_layout(tmp_path: Path) -> None:
    from imu_calib_ros.core.calibration import CalibrationResult
    plan = tmp_path / 'short.yaml'
    plan.write_text(yaml.safe_dump({'name': 'short', 'steps': [
        {'dwell': {'duration_s': 2}}, {'move': {'joint': 'outer', 'by_deg': 90, 'duration_s': 2}},
        {'move': {'joint': 'inner', 'by_deg': -90, 'duration_s': 2}}]}))
    bag, truth = make_case(tmp_path, unit='tactical', size=0.2, mount_deg=4.0, offset_mm=30,
                           latency_ms=-12, plan=str(plan), seed=1, imu_rate_hz=20.0)
    cal = CalibrationResult.load(truth.path)  # our CONTRACT 4 reader accepts it
    assert np.array_equal(cal.errors.gyro_scale_misalignment,
                          truth.errors.gyro_scale_misalignment)
    assert cal.fixed == () and np.all(cal.sigma.as_vector() == 0.0)
    c = truth.data['imu_calibration']
    assert c['mounting']['angle_deg'] == pytest.approx(4.0)
    assert np.linalg.norm(c['mounting']['xyz_m']) == pytest.approx(0.03)
    assert truth.latency_s == pytest.approx(-0.012) and truth.sample_type == 'interval_mean'
    for key in ('bias_at_end', 'reference_point', 'time', 'noise', 'unit', 'provenance'):
        assert key in c
    rows = compare_calibration(truth.data, truth.data, bias_at_end=False)
    assert len(rows) == 45 and all(r.z == 0.0 for r in rows)
    assert (bag / 'metadata.yaml').exists()


# ------------------------------------------------------------------------ units, noise
def test_draw_unit_covers_each_class_within_its_bounds() -> None:
    rng = np.random.default_rng(0)
    for kind in UNIT_KINDS:
        s = SPECS[kind]
        for size in (0.2, 1.0):
            u = draw_unit(kind, size, rng)
            e = u.errors
            assert np.array_equal(e.gyro_scale_misalignment, e.gyro_scale_misalignment.T)
            assert np.all(np.diag(e.size_effect_m) == 0)
            assert np.abs(np.diag(e.accel_scale_misalignment)).max() <= size * s.scale
            assert np.abs(e.accel_bias_m_s2).max() <= size * s.accel_bias_m_s2
            assert np.abs(e.size_effect_m).max() <= size * s.size_effect_m
            assert s.arw_rad_s_rt_hz[0] <= u.noise.gyro_noise_rad_s_rt_hz <= \
                s.arw_rad_s_rt_hz[1]
            if kind == 'nav':
                assert np.all(e.gyro_g_sensitivity_rad_s_per_m_s2 == 0)
            else:
                assert np.all(np.abs(e.gyro_g_sensitivity_rad_s_per_m_s2) >=
                              size * s.g_sensitivity[0])
    with pytest.raises(ValueError):
        draw_unit('cheap', 1.0, rng)


def test_white_noise_and_bias_drift_have_the_stated_sizes(tmp_path: Path) -> None:
    fxp = _fixture_file(tmp_path)
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 200.0}}]), fxp)
    noise = UnitNoise(gyro_noise_rad_s_rt_hz=1e-4, accel_noise_m_s2_rt_hz=1e-3,
                      gyro_bias_instability_rad_s=1e-5, gyro_bias_correlation_s=50.0,
                      accel_bias_random_walk_m_s3_rt_hz=1e-4)
    unit = Unit('consumer_mems', 1.0, UnitErrors.zeros(), noise)
    for st in ('interval_mean', 'point'):
        d = generate(fx, prof, unit, Mounting(), WorldConfig(sample_type=st, quantize=False),
                     seed=5)
        # outputs minus the drift minus the (constant) true value: the white noise
        white_g = d.gyro_rad_s - d.gyro_drift_rad_s
        white_a = d.accel_m_s2 - d.accel_drift_m_s2
        assert np.std(white_g - white_g.mean(axis=0)) == pytest.approx(1e-4 / math.sqrt(0.01),
                                                                       rel=0.03)
        assert np.std(white_a - white_a.mean(axis=0)) == pytest.approx(1e-3 / math.sqrt(0.01),
                                                                       rel=0.03)
    # Gauss-Markov: stationary sigma; random walk: grows like sqrt(t)
    assert np.std(d.gyro_drift_rad_s) == pytest.approx(1e-5, rel=0.5)
    bias_end = d.truth['imu_calibration']['bias_at_end']['accel_m_s2']
    assert np.array_equal(bias_end, d.accel_drift_m_s2[-1])


def test_quantised_increments_keep_the_running_sum(tmp_path: Path) -> None:
    fxp = _fixture_file(tmp_path)
    fx = WorldFixture.from_yaml(fxp)
    prof = joint_profile(_plan([{'dwell': {'duration_s': 5.0}}]), fxp)
    noise = UnitNoise(gyro_noise_rad_s_rt_hz=1e-5, quantization='increment', gyro_quantum=1e-6,
                      accel_quantum=1e-4)
    unit = Unit('nav', 1.0, UnitErrors.zeros(), noise)
    q = generate(fx, prof, unit, Mounting(), WorldConfig(), seed=1)
    raw = generate(fx, prof, unit, Mounting(), WorldConfig(quantize=False), seed=1)
    inc = q.gyro_rad_s * 0.01
    assert np.abs(inc / 1e-6 - np.round(inc / 1e-6)).max() < 1e-6
    run = np.cumsum((q.gyro_rad_s - raw.gyro_rad_s) * 0.01, axis=0)
    assert np.abs(run).max() <= 0.5e-6 + 1e-15


# --------------------------------------------------------------- our simulator, shared case
def test_cross_check_with_core_simulator(tmp_path: Path) -> None:
    """Same errors, nominal mounting, no noise, a lever arm of 6 cm: the two generators
    agree to ~1e-10 relative (point and interval mean). Two known differences, both below
    that: our fixture.kinematics drops Omega x (Omega x p) (3e-10 m/s^2 at 6 cm) and uses
    the GRS-80 earth rate (1.5e-12 rad/s). With asymmetry errors our simulator's
    Gauss-Legendre rule misses the kink of |.| at zero crossings (the world splits there);
    that is checked against brute-force quadrature in
    test_interval_means_are_exact_at_zero_crossings."""
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.sensor_model import SensorErrors, measure
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fxp = Path(__file__).resolve().parents[1] / 'config' / 'fixtures' / 'three_axis.yaml'
    d = yaml.safe_load(fxp.read_text())
    d['imu']['xyz_m'] = [0.03, -0.02, 0.05]
    fxp = tmp_path / 'lever.yaml'
    fxp.write_text(yaml.safe_dump(d))
    prof = joint_profile(_plan([{'srt_sequence': {'id': '1', 'dwell_s': 1, 'rotation_s': 4}},
                                {'srt_sequence': {'id': '5', 'dwell_s': 1, 'rotation_s': 4}}]),
                         fxp)
    unit = draw_unit('consumer_mems', 1.0, np.random.default_rng(5))
    e = unit.errors.replace(gyro_scale_asymmetry=np.zeros(3), accel_scale_asymmetry=np.zeros(3))
    unit = Unit(unit.kind, 1.0, e, unit.noise)
    ours_e = SensorErrors(**{f.name: getattr(e, f.name) for f in dataclasses.fields(e)})
    fx = WorldFixture.from_yaml(fxp)
    world = generate(fx, prof, unit, Mounting(), WorldConfig(noise=False))
    sim = simulate(load_fixture(str(fxp)), prof, load_grade('mems_mti1'),
                   SimConfig(imu_rate_hz=100.0, noise=False, quantize=False),
                   errors=ours_e, mounting=(np.zeros(3), np.zeros(3)))
    assert np.array_equal(world.imu_stamps_ns - START,
                          sim.imu.stamps_ns - sim.config.start_stamp_ns)
    rel_g = np.abs(world.gyro_rad_s - sim.imu.gyro_rad_s).max(axis=1) / \
        np.linalg.norm(sim.imu.gyro_rad_s, axis=1)
    rel_a = np.abs(world.accel_m_s2 - sim.imu.accel_m_s2).max(axis=1) / \
        np.linalg.norm(sim.imu.accel_m_s2, axis=1)
    assert rel_g.max() < 1e-9 and rel_a.max() < 1e-9
    # point samples against our instantaneous model (fixture.kinematics + measure)
    pt = generate(fx, prof, unit, Mounting(), WorldConfig(noise=False, sample_type='point'))
    t = (pt.imu_stamps_ns - START) * 1e-9
    kin = load_fixture(str(fxp)).kinematics(*prof.evaluate(t))
    g2, a2 = measure(ours_e, kin.omega_ib_imu_rad_s, kin.omega_dot_ib_imu_rad_s2,
                     kin.f_imu_m_s2)
    assert (np.abs(pt.gyro_rad_s - g2).max(axis=1) / np.linalg.norm(g2, axis=1)).max() < 1e-9
    assert (np.abs(pt.accel_m_s2 - a2).max(axis=1) / np.linalg.norm(a2, axis=1)).max() < 1e-9


def test_make_case_builds_the_documented_example(tmp_path: Path) -> None:
    bag, truth = make_case(tmp_path, unit='consumer_mems', size=1.0, mount_deg=10,
                           latency_ms=20, sample_type='point', joint_rate_hz=20, seed=3,
                           imu_rate_hz=50.0)
    assert (bag / 'metadata.yaml').exists() and truth.path.exists()
    assert truth.fixture_path.name == 'three_axis.yaml' and truth.fixture_path.exists()
    assert np.degrees(np.linalg.norm(truth.mounting_rotvec_rad)) == pytest.approx(10.0)
    assert truth.sample_type == 'point' and truth.unit_kind == 'consumer_mems'
    # reproducible: the same arguments give the same truth
    _, again = make_case(tmp_path / 'again', unit='consumer_mems', size=1.0, mount_deg=10,
                         latency_ms=20, sample_type='point', joint_rate_hz=20, seed=3,
                         imu_rate_hz=50.0)
    assert again.data['imu_calibration']['gyroscope'] == \
        truth.data['imu_calibration']['gyroscope']


# ------------------------------------------------------------------- the bench's design
def test_bench_design_is_the_documented_fractional_design() -> None:
    """Every timing level and (size, mounting) combination appears in every cell (unit
    class, plan); per class each timing level meets each combination exactly once."""
    import importlib.util
    path = Path(__file__).resolve().parents[1] / 'bench' / 'bench_robustness.py'
    spec = importlib.util.spec_from_file_location('bench_robustness', path)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    sys.modules['bench_robustness'] = bench  # dataclasses look their module up
    spec.loader.exec_module(bench)
    cases = bench.design()
    main = [c for c in cases if c.unit != 'control']
    assert len(main) == 68 and len(cases) == 75 and len({c.name for c in cases}) == 75
    assert {c.timing for c in cases if c.unit == 'control'} == set(bench.TIMINGS)
    for u in bench.UNITS:
        levels = bench.TIMINGS if u == 'nav' else bench.TIMINGS[:4]
        mine = [c for c in main if c.unit == u]
        for p in range(len(bench.PLANS)):
            at_p = [c for c in mine if c.plan_index == p]
            assert {c.timing for c in at_p} == set(levels)
            assert {(c.size, c.mount) for c in at_p} == set(bench.COMBOS)
        for t in levels:
            combos = {(c.size, c.mount) for c in mine if c.timing == t}
            assert combos == set(bench.COMBOS)
    assert {c.cell for c in cases[:17]} == {c.cell for c in cases}  # seed index first
    quick = [c for c in cases if (c.unit, c.plan_index, c.seed_index) in set(bench.QUICK)]
    assert len(quick) == 5 and {c.unit for c in quick} == set(bench.UNITS) | {'control'}
    drawn = bench.draw_case(next(c for c in main if c.timing == 'fast_jitter'))
    assert drawn.config.imu_rate_hz == 2000.0 and drawn.config.receipt_delay_s is not None


def test_bench_reads_the_targets_from_bench_accuracy() -> None:
    import importlib
    bench = sys.modules.get('bench_robustness')
    if bench is None:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'bench'))
        bench = importlib.import_module('bench_robustness')
    nav, mems, source = bench.targets_from_bench_accuracy()
    assert source.endswith('bench_accuracy.py')
    assert nav['gyro_scale'] == (1.0, 'both') and mems['gyro_bias'][1] == 'both'
    assert set(nav) >= {'gyro_scale', 'accel_bias', 'size_effect', 'gyro_bias'}
