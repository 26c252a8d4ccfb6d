"""Simulator: exact physics without errors/noise, and noise with the configured statistics."""
import dataclasses
import math

import allantools
import numpy as np
import pytest
from scipy.stats import chi2

from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.plans import build_profile, plan_from_dict
from imu_calib_ros.core.sensor_model import SensorErrors
from imu_calib_ros.core.simulator import SimConfig, quantize_means, simulate

EXACT = SimConfig(noise=False, quantize=False, seed=1)
MOUNT = (np.array([1e-3, -2e-3, 0.5e-3]), np.array([0.003, -0.002, 0.004]))


def _plan(steps):
    return plan_from_dict({'name': 't', 'steps': steps}, '<test>')


def _quiet(grade_name: str, **noise):
    """A grade with only the given noise terms (white noise tests)."""
    g = load_grade(grade_name).without_noise()
    return dataclasses.replace(g, **noise)


@pytest.mark.parametrize('down', ['x', '-y', 'z'])
def test_static_specific_force_is_gravity_in_the_body(down: str) -> None:
    fx = load_fixture('three_axis')
    prof = build_profile(_plan([{'orient': {'down': down, 'duration_s': 3}},
                                {'dwell': {'duration_s': 2}}]), fx)
    res = simulate(fx, prof, load_grade('nav_grade'), EXACT, errors=SensorErrors.zeros(),
                   mounting=MOUNT)
    still = res.times_s > prof.segments[-1].t0_s + 1e-9
    R = res.true_fixture.R_enu_imu(prof.evaluate(res.times_s[still])[0])
    site = fx.site
    f_exp = np.einsum('nji,j->ni', R, -site.g_enu)
    w_exp = np.einsum('nji,j->ni', R, site.omega_ie_enu)
    np.testing.assert_allclose(res.imu.accel_m_s2[still], f_exp, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.imu.gyro_rad_s[still], w_exp, rtol=0, atol=1e-15)
    assert np.linalg.norm(f_exp, axis=1) == pytest.approx(site.gravity, abs=1e-12)


def test_noisy_static_mean_within_its_sigma() -> None:
    fx = load_fixture('savage_2axis')
    g = _quiet('mems_mti1', gyro_noise_rad_s_rt_hz=1.2e-4, accel_noise_m_s2_rt_hz=1.2e-3)
    prof = build_profile(_plan([{'dwell': {'duration_s': 50}}]), fx)
    res = simulate(fx, prof, g, SimConfig(seed=4), errors=SensorErrors.zeros(),
                   mounting=MOUNT)
    R = res.true_fixture.R_enu_imu(prof.q_start)
    f_exp = R.T @ -fx.site.g_enu
    n = len(res.imu)
    dt = 1.0 / res.config.imu_rate_hz
    sig_mean = g.accel_noise_m_s2_rt_hz / math.sqrt(dt) / math.sqrt(n)
    assert np.all(np.abs(res.imu.accel_m_s2.mean(axis=0) - f_exp) < 4.0 * sig_mean)
    assert np.any(np.abs(res.imu.accel_m_s2.mean(axis=0) - f_exp) > 0.05 * sig_mean)  # noisy


@pytest.mark.parametrize('joint,deg', [('outer', 360.0), ('inner', -250.0)])
def test_mean_gyro_integrates_to_the_commanded_angle(joint: str, deg: float) -> None:
    """sum(gyro . a_imu) dt = dq + (a_enu . Omega_ie) T, exactly (a fixed in both frames)."""
    fx = load_fixture('three_axis')
    prof = build_profile(_plan([{'dwell': {'duration_s': 0.5}},
                                {'move': {'joint': joint, 'by_deg': deg, 'duration_s': 3.3}},
                                {'dwell': {'duration_s': 0.5}}]), fx)
    res = simulate(fx, prof, load_grade('nav_grade'), EXACT, errors=SensorErrors.zeros(),
                   mounting=MOUNT)
    j = fx.joint_names.index(joint)
    q0 = prof.q_start
    a_imu = res.true_fixture.joint_axes_imu(q0)[j]
    a_enu = res.true_fixture.joint_axes_enu(q0)[j]
    dt = 1.0 / res.config.imu_rate_hz
    T = len(res.imu) * dt
    angle = np.sum(res.imu.gyro_rad_s @ a_imu) * dt
    expected = math.radians(deg) + float(a_enu @ fx.site.omega_ie_enu) * T
    assert angle == pytest.approx(expected, abs=1e-9)


def test_white_noise_density_std_and_allan() -> None:
    fx = load_fixture('savage_2axis')
    N = 1e-3
    g = _quiet('mems_mti1', gyro_noise_rad_s_rt_hz=N)
    prof = build_profile(_plan([{'dwell': {'duration_s': 200}}]), fx)
    cfg = SimConfig(seed=9, imu_rate_hz=100.0)
    res = simulate(fx, prof, g, cfg, errors=SensorErrors.zeros(), mounting=MOUNT)
    exact = simulate(fx, prof, g, dataclasses.replace(cfg, noise=False),
                     errors=SensorErrors.zeros(), mounting=MOUNT)
    e = res.imu.gyro_rad_s - exact.imu.gyro_rad_s
    rate = cfg.imu_rate_hz
    m = e.size
    sigma = N * math.sqrt(rate)
    # sample std: chi-square with m-1 dof, two-sided 1e-4 band
    lo, hi = (math.sqrt(chi2.ppf(p, m - 1) / (m - 1)) for p in (0.5e-4, 1 - 0.5e-4))
    assert lo * sigma < np.std(e) < hi * sigma
    # overlapping Allan deviation at tau = 1 s of white rate noise: N / sqrt(tau)
    tau = 1.0
    n_tau = int(tau * rate)
    for k in range(3):
        taus, adev, _, _ = allantools.oadev(e[:, k], rate=rate, data_type='freq',
                                            taus=[tau])[:4]
        edf = allantools.edf_greenhall(alpha=0, d=2, m=n_tau, N=e.shape[0],
                                       overlapping=True, modified=False)
        lo, hi = (math.sqrt(chi2.ppf(p, edf) / edf) for p in (0.5e-4, 1 - 0.5e-4))
        assert lo * N / math.sqrt(tau) < adev[0] < hi * N / math.sqrt(tau)


def test_quantization_carries_the_residual() -> None:
    rng = np.random.default_rng(2)
    dt = 0.005
    mean = rng.normal(0.3, 0.1, (1000, 3))
    q = 1e-4
    out = quantize_means(mean, dt, q)
    inc = out * dt
    np.testing.assert_allclose(inc / q, np.round(inc / q), atol=1e-6)  # whole quanta
    err = np.cumsum(inc, axis=0) - np.cumsum(mean * dt, axis=0)
    assert np.max(np.abs(err)) <= 0.5 * q + 1e-12


def test_gauss_markov_bias_has_its_sigma() -> None:
    fx = load_fixture('savage_2axis')
    g = _quiet('mems_mti1', gyro_bias_instability_rad_s=1e-4, gyro_bias_correlation_s=0.5)
    prof = build_profile(_plan([{'dwell': {'duration_s': 300}}]), fx)
    res = simulate(fx, prof, g, SimConfig(seed=3, imu_rate_hz=50.0),
                   errors=SensorErrors.zeros(), mounting=MOUNT)
    b = res.bias_drift_gyro_rad_s
    # about 300 s / (2 * 0.5 s) = 300 independent values per axis, 900 in all
    assert np.std(b) == pytest.approx(1e-4, rel=5.0 / math.sqrt(2 * 900))
    lag = int(0.5 * 50)  # autocorrelation at one correlation time is exp(-1)
    r = np.mean([np.corrcoef(b[:-lag, k], b[lag:, k])[0, 1] for k in range(3)])
    assert r == pytest.approx(math.exp(-1.0), abs=0.1)
    # the truth file's bias_at_end (what a filter tracking the total bias should end at)
    at_end = res.truth.extra['bias_at_end']
    np.testing.assert_array_equal(at_end['gyro_rad_s'], b[-1])  # turn-on bias zero here
    np.testing.assert_array_equal(at_end['accel_m_s2'], res.bias_drift_accel_m_s2[-1])
    assert np.abs(b[-1]).max() > 1e-6  # a real drift, not zeros


def test_reproducible_truth_and_joint_states() -> None:
    fx = load_fixture('three_axis')
    prof = build_profile(_plan([{'move': {'joint': 'outer', 'by_deg': 400, 'duration_s': 5}},
                                {'dwell': {'duration_s': 1}}]), fx)
    g = load_grade('mems_mti1')
    cfg = SimConfig(seed=21, wrap_joint_positions=True)
    a = simulate(fx, prof, g, cfg)
    b = simulate(fx, prof, g, cfg)
    np.testing.assert_array_equal(a.imu.gyro_rad_s, b.imu.gyro_rad_s)
    np.testing.assert_array_equal(a.imu.accel_m_s2, b.imu.accel_m_s2)
    np.testing.assert_array_equal(a.truth.errors.as_vector(), b.truth.errors.as_vector())
    mnt = a.truth.extra['mounting']
    assert 0 < np.max(np.abs(mnt['rpy_rad'])) < 5e-3
    # stamps: IMU at the interval ends, joints from t = 0 at their own rate
    dt_ns = int(1e9 / cfg.imu_rate_hz)
    assert a.imu.stamps_ns[0] == cfg.start_stamp_ns + dt_ns
    assert np.all(np.diff(a.joints.stamps_ns) == int(1e9 / cfg.joint_rate_hz))
    q = a.joints.positions_rad
    assert np.all(q > -math.pi) and np.all(q <= math.pi)
    t = (a.joints.stamps_ns - cfg.start_stamp_ns) * 1e-9
    q_true = prof.evaluate(t)[0]
    d = np.angle(np.exp(1j * (q - q_true)))
    assert np.std(d) == pytest.approx(cfg.encoder_noise_rad, rel=0.2)
    c = simulate(fx, prof, g, dataclasses.replace(cfg, seed=22))
    assert not np.array_equal(a.truth.errors.as_vector(), c.truth.errors.as_vector())


def test_interval_means_match_adaptive_quadrature_across_breakpoints() -> None:
    """Intervals holding an acceleration jump (oscillation start) are integrated exactly."""
    from scipy.integrate import quad

    from imu_calib_ros.core.sensor_model import measure
    fx = load_fixture('three_axis')
    prof = build_profile(_plan([{'dwell': {'duration_s': 0.5013}},
                                {'oscillate': {'joint': 'outer', 'amplitude_deg': 90,
                                               'period_s': 1.0037, 'cycles': 2}},
                                {'dwell': {'duration_s': 0.5}}]), fx)
    g = load_grade('nav_grade')
    errors = SensorErrors.zeros().replace(size_effect_m=np.array(
        [[0, 0.01, -0.02], [0.015, 0, 0.01], [-0.01, 0.02, 0]]))
    res = simulate(fx, prof, g, EXACT, errors=errors, mounting=MOUNT)
    dt = 1.0 / EXACT.imu_rate_hz
    for bp in prof.breakpoints_s[1:-1]:
        k = int(bp / dt)  # interval [k dt, (k+1) dt] holds the breakpoint
        a, b = k * dt, (k + 1) * dt

        def f(t: float, i: int) -> float:
            q, qd, qdd = prof.evaluate(np.array([t]))
            kin = res.true_fixture.kinematics(q, qd, qdd)
            return float(measure(errors, kin.omega_ib_imu_rad_s, kin.omega_dot_ib_imu_rad_s2,
                                 kin.f_imu_m_s2)[1][0, i])

        ref = [quad(f, a, b, args=(i,), points=[bp], epsabs=1e-15, epsrel=1e-14)[0] / dt
               for i in range(3)]
        np.testing.assert_allclose(res.imu.accel_m_s2[k], ref, rtol=0, atol=1e-12)


def test_arm_errors_are_a_fifth_random_stream_and_the_data_come_from_them() -> None:
    """SimConfig's joint_offset_sigma_rad/link_sigma_m (imu-calib simulate and turntable_sim
    use them): without them every draw is as before (the sensor errors, mounting, noise and
    encoder noise are spawn(4)'s children); with them the IMU is exactly the simulation of
    the chain perturbed_chain draws from the fifth child, the joint states are unchanged
    (encoder readings), and the truth's last-link mounting and lever arm are those
    calibration_truth gives the estimator."""
    from scipy.spatial.transform import Rotation

    from imu_calib_ros.core.estimator.truth import last_link_truth
    from imu_calib_ros.core.fixture import perturbed_chain
    from imu_calib_ros.core.urdf_fixture import UrdfOptions
    fx = load_fixture('arm6.urdf', UrdfOptions('base_link', 'imu_link'))
    prof = build_profile(_plan([{'dwell': {'duration_s': 0.5}},
                                {'move': {'joint': 'elbow_joint', 'by_deg': 30,
                                          'duration_s': 1}}]), fx)
    g = load_grade('mems_mti1')
    cfg = SimConfig(imu_rate_hz=50.0, seed=5)
    plain = simulate(fx, prof, g, cfg)
    arm = simulate(fx, prof, g, dataclasses.replace(cfg, joint_offset_sigma_rad=1e-3,
                                                    link_sigma_m=2e-3))
    rng = np.random.default_rng(np.random.SeedSequence(5).spawn(5)[4])
    true_chain, offsets, dxyz = perturbed_chain(fx, rng, 1e-3, 2e-3)
    mnt = plain.truth.extra['mounting']
    again = simulate(true_chain, prof, g, cfg)
    assert np.array_equal(arm.imu.gyro_rad_s, again.imu.gyro_rad_s)
    assert np.array_equal(arm.imu.accel_m_s2, again.imu.accel_m_s2)
    assert np.abs(arm.imu.gyro_rad_s - plain.imu.gyro_rad_s).max() > 1e-5
    assert np.array_equal(arm.joints.positions_rad, plain.joints.positions_rad)
    assert arm.truth.extra['mounting'] == mnt
    assert np.array_equal(arm.bias_drift_gyro_rad_s, plain.bias_drift_gyro_rad_s)
    ce = arm.truth.extra['chain_errors']
    assert 'chain_errors' not in plain.truth.extra
    assert list(ce['joint_zero_offsets_rad'].values()) == offsets.tolist()
    assert list(ce['joint_origin_errors_m'].values()) == dxyz.tolist()
    rho, R_m = last_link_truth(fx, arm.true_fixture)
    assert np.allclose(ce['last_link']['lever_arm_m'], rho, rtol=0, atol=1e-15)
    assert np.allclose(ce['last_link']['mounting_rotvec_rad'],
                       Rotation.from_matrix(R_m).as_rotvec(), rtol=0, atol=1e-15)
    # the last joint's zero offset is in the reported mounting (about its axis)
    assert abs(np.linalg.norm(ce['last_link']['mounting_rotvec_rad'])) > 0.5 * abs(offsets[-1])
