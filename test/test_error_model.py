"""The estimator's error model against brute force.

- M_g, M_a against finite differences of ``sensor_model.measure`` (CONTRACT 3);
- the compensated-sample error ``omega_hat - omega = -M_g (theta_hat - theta)``;
- a chunk's transition matrix against finite differences of the strapdown navigator;
- the SensorErrors <-> parameter-vector round trip.
"""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core import sensor_model as sm
from imu_calib_ros.core.estimator import error_model as em
from imu_calib_ros.core.estimator.ekf import chunk_transitions
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import draw_errors, load_grade
from imu_calib_ros.core.strapdown import Strapdown

ALL = tuple(g[0] for g in em.GROUPS if g[0] not in ('lever_arm', 'mounting'))


def _motion(n: int = 40, dt: float = 0.005, seed: int = 1):
    """Exact IMU motion of a three-axis table swinging all joints (analytic q(t))."""
    fx = load_fixture('three_axis')
    rng = np.random.default_rng(seed)
    t = np.arange(1, n + 1) * dt
    amp, wfreq, ph = rng.uniform(0.5, 1.5, 3), rng.uniform(2, 5, 3), rng.uniform(0, 6, 3)
    q = amp * np.sin(wfreq * t[:, None] + ph)
    qd = amp * wfreq * np.cos(wfreq * t[:, None] + ph)
    qdd = -amp * wfreq ** 2 * np.sin(wfreq * t[:, None] + ph)
    return fx, t, fx.kinematics(q, qd, qdd)


def _random_errors(seed: int = 3) -> sm.SensorErrors:
    grade = load_grade('mems_mti1')
    return draw_errors(grade, np.random.default_rng(seed))


def test_gyro_and_accel_jacobians_match_finite_differences_of_measure() -> None:
    _, _, k = _motion()
    w, wd, f = k.omega_ib_imu_rad_s, k.omega_dot_ib_imu_rad_s2, k.f_imu_m_s2
    fdot = np.gradient(f, axis=0) / 0.005
    e0 = _random_errors()
    tg, ta = em.theta_from_errors(e0)
    w2, f2 = np.diff(w, 2, axis=0), np.diff(f, 2, axis=0)  # any curvature: a column each
    w, wd, f, fdot = w[1:-1], wd[1:-1], f[1:-1], fdot[1:-1]
    Mg = em.gyro_jacobian(w, f, w2)
    Ma = em.accel_jacobian(w, wd, f, fdot, f2)
    h = 1e-6
    aux_g = {em.gyro_cols('gyro_sample_kernel').start}
    aux_a = {em.accel_cols(g).start for g in ('time_offset', 'accel_sample_kernel')}
    for j in sorted(set(range(em.N_GYRO)) - aux_g):  # the auxiliary states: not SensorErrors
        d = np.zeros(em.N_GYRO)
        d[j] = h
        gp, _ = sm.measure(em.errors_from_theta(tg + d, ta, sm.SensorErrors), w, wd, f)
        gm, _ = sm.measure(em.errors_from_theta(tg - d, ta, sm.SensorErrors), w, wd, f)
        # measure is linear in the parameters: central differences are exact to rounding
        np.testing.assert_allclose((gp - gm) / (2 * h), Mg[:, :, j], atol=1e-7, rtol=1e-7)
    for j in sorted(set(range(em.N_ACCEL)) - aux_a):
        d = np.zeros(em.N_ACCEL)
        d[j] = h
        _, ap = sm.measure(em.errors_from_theta(tg, ta + d, sm.SensorErrors), w, wd, f)
        _, am = sm.measure(em.errors_from_theta(tg, ta - d, sm.SensorErrors), w, wd, f)
        np.testing.assert_allclose((ap - am) / (2 * h), Ma[:, :, j], atol=1e-6, rtol=1e-7)
    # time offset: accelerometers sampled tau late read f(t + tau)
    np.testing.assert_array_equal(Ma[:, :, em.accel_cols('time_offset').start], fdot)
    # sampling kernels: a point sample (s = 1) reads the interval mean minus f'' dt^2 / 24
    np.testing.assert_array_equal(Mg[:, :, em.gyro_cols('gyro_sample_kernel').start], -w2 / 24)
    np.testing.assert_array_equal(Ma[:, :, em.accel_cols('accel_sample_kernel').start],
                                  -f2 / 24)
    # and the columns of the other groups do not depend on the curvature
    np.testing.assert_array_equal(np.delete(Mg, sorted(aux_g), axis=2),
                                  np.delete(em.gyro_jacobian(w, f), sorted(aux_g), axis=2))


def test_compensation_error_is_minus_jacobian_times_parameter_error() -> None:
    _, _, k = _motion()
    w, wd, f = k.omega_ib_imu_rad_s, k.omega_dot_ib_imu_rad_s2, k.f_imu_m_s2
    # G = 0 and r = 0: the neglected cross terms G (f_hat - f) and d(size effect)/d omega
    # (omega_hat - omega) would be ~1e-9 rad/s and ~1e-7 m/s^2 here (documented in
    # error_model.compensated_jacobians)
    e_true = _random_errors(5).replace(gyro_g_sensitivity_rad_s_per_m_s2=np.zeros((3, 3)),
                                       size_effect_m=np.zeros((3, 3)))
    gyro, accel = sm.measure(e_true, w, wd, f)
    tg, ta = em.theta_from_errors(e_true)
    rng = np.random.default_rng(7)
    dg = rng.normal(0, 1e-6, em.N_GYRO)  # estimate minus truth
    da = rng.normal(0, 1e-6, em.N_ACCEL)
    dg[em.gyro_cols('gyro_sample_kernel')] = 0.0  # the auxiliary states: not SensorErrors
    da[em.accel_cols('time_offset')] = da[em.accel_cols('accel_sample_kernel')] = 0.0
    da[em.accel_cols('size_effect')] = rng.normal(0, 1e-5, 6)
    e_hat = em.errors_from_theta(tg + dg, ta + da, sm.SensorErrors)
    w_hat, f_hat = sm.compensate(e_hat, gyro, accel, wd)
    Jg, Ja = em.compensated_jacobians(e_hat, w_hat, wd, f_hat)
    # first order: the residual is second order, |omega_hat - omega| |d| sqrt(21) ~ 2e-10
    # rad/s (~1e-9 m/s^2); a plain M_g without the (I + Kg)^-1 factor is off by ~1e-7 here
    # (samples where an axis crosses zero are left out: |omega_i| has a kink there)
    ok_w = np.all(np.abs(w) > 1e-3, axis=1)
    ok_f = np.all(np.abs(f) > 1e-2, axis=1)
    assert ok_w.sum() > 20 and ok_f.sum() > 20
    np.testing.assert_allclose((w_hat - w)[ok_w], -np.einsum('nij,j->ni', Jg, dg)[ok_w],
                               atol=1e-9)
    np.testing.assert_allclose((f_hat - f)[ok_f], -np.einsum('nij,j->ni', Ja, da)[ok_f],
                               atol=1e-8)


def test_theta_round_trip() -> None:
    e = _random_errors(11)
    tg, ta = em.theta_from_errors(e)
    back = em.errors_from_theta(tg, ta, sm.SensorErrors)
    np.testing.assert_allclose(back.as_vector(), e.as_vector(), rtol=0, atol=0)


@pytest.mark.parametrize('seed', [1, 2])
def test_chunk_transition_matches_strapdown_finite_differences(seed: int) -> None:
    """Perturb one error at a time, re-run the navigator over 20 samples, compare."""
    fx, t, k = _motion(n=20, seed=seed)
    dt = np.full(len(t), 0.005)
    w, wd, f = k.omega_ib_imu_rad_s, k.omega_dot_ib_imu_rad_s2, k.f_imu_m_s2
    e_true = _random_errors(seed)
    gyro, accel = sm.measure(e_true, w, wd, f)
    fdot = np.gradient(f, axis=0) / 0.005
    # the samples' curvature (f'' dt^2), as propagation.propagate_block takes it
    w2 = np.gradient(np.gradient(gyro, axis=0), axis=0)
    f2 = np.gradient(np.gradient(accel, axis=0), axis=0)
    tg, ta = em.theta_from_errors(e_true)
    layout = em.StateLayout.build(ALL)
    R0 = k.R_enu_imu[0]
    kg, ka, kt = (em.gyro_cols('gyro_sample_kernel'), em.accel_cols('accel_sample_kernel'),
                  em.accel_cols('time_offset'))

    def run(dg: np.ndarray, da: np.ndarray, psi0: np.ndarray, dv0: np.ndarray):
        e_hat = em.errors_from_theta(tg + dg, ta + da, sm.SensorErrors)
        w_c, f_c = sm.compensate(e_hat, gyro, accel, wd)
        # the auxiliary states' compensation, as the estimator does
        f_c = f_c - (ta + da)[kt] * fdot
        w_c = w_c - (tg + dg)[kg] * em.sample_kernel_column(w2)
        f_c = f_c - (ta + da)[ka] * em.sample_kernel_column(f2)
        from scipy.spatial.transform import Rotation
        nav = Strapdown(fx.site, Rotation.from_rotvec(psi0).as_matrix() @ R0, dv0)
        out = nav.propagate(dt, w_c, f_c)
        return out, w_c, f_c

    ref, w_c, f_c = run(np.zeros(em.N_GYRO), np.zeros(em.N_ACCEL), np.zeros(3), np.zeros(3))
    e_hat = em.errors_from_theta(tg, ta, sm.SensorErrors)
    Mg, Ma = em.compensated_jacobians(e_hat, w_c, wd, f_c, fdot, w2, f2)
    R_mid = 0.5 * (np.concatenate([R0[None], ref.R_enu_imu[:-1]]) + ref.R_enu_imu)
    phi = chunk_transitions(layout, R_mid[None], ref.f_enu_m_s2[None], Mg[None],
                            Ma[None], dt[None], fx.site.omega_ie_enu)[0]
    from scipy.spatial.transform import Rotation
    R_end, v_end = ref.R_enu_imu[-1], ref.v_enu_m_s[-1]

    def err(out) -> np.ndarray:
        psi = Rotation.from_matrix(out.R_enu_imu[-1] @ R_end.T).as_rotvec()
        return np.concatenate([psi, out.v_enu_m_s[-1] - v_end])

    scale = layout.scale
    for col in range(layout.n):
        h = scale[col] * 10.0  # ten engineering units: linear regime, above rounding
        dg, da = np.zeros(em.N_GYRO), np.zeros(em.N_ACCEL)
        psi0, dv0 = np.zeros(3), np.zeros(3)
        if col < 3:
            psi0[col] = h
        elif col < 6:
            dv0[col - 3] = h
        elif col in layout.gyro_state_idx:
            dg[layout.gyro_cols[list(layout.gyro_state_idx).index(col)]] = h
        else:
            da[layout.accel_cols[list(layout.accel_state_idx).index(col)]] = h
        out, _, _ = run(dg, da, psi0, dv0)
        fd = err(out) / h
        pred = phi[0:6, col]
        # tolerance: 1 % of the column plus the rounding floor of the navigator (~1e-12/h)
        tol = 0.01 * np.abs(pred).max() + 2e-12 / h + 1e-12
        assert np.abs(fd - pred).max() <= tol, (layout.labels()[col], fd, pred)
