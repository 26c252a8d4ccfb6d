"""The estimator's block compensation (propagation.BlockCompensation) against
sensor_model.compensate: the same fixed point to rounding, with and without a g-sensitivity
(coupled and rates-alone iterations), a size effect or none, and MEMS errors 40x too large."""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core.estimator.propagation import BlockCompensation
from imu_calib_ros.core.sensor_model import ImplausibleErrors, SensorErrors, compensate, measure
from test_sensor_model import mems_errors, random_motion


def _variants(e: SensorErrors) -> dict[str, SensorErrors]:
    v = e.as_vector()
    no_g = v.copy()
    no_g[12:21] = 0.0
    no_size = no_g.copy()
    no_size[39:45] = 0.0
    return {'all': e, 'no_g_sensitivity': SensorErrors.from_vector(no_g),
            'no_size_effect': SensorErrors.from_vector(no_size),
            'large': SensorErrors.from_vector(40 * v)}


@pytest.mark.parametrize('seed', [0, 1])
@pytest.mark.parametrize('kind', ['all', 'no_g_sensitivity', 'no_size_effect', 'large'])
def test_block_compensation_is_compensate_to_rounding(seed: int, kind: str) -> None:
    rng = np.random.default_rng(seed)
    e = _variants(mems_errors(rng))[kind]
    w, wd, f = random_motion(rng, 300)
    gm, am = measure(e, w, wd, f)
    comp = BlockCompensation.of(e)
    rates = comp.rates(gm, am)
    w0, _ = compensate(e, gm, am, np.zeros_like(wd))  # the rates without omega_dot
    np.testing.assert_allclose(rates.T, w0, rtol=0, atol=1e-15 * np.abs(w0).max())
    w1, f1 = comp.samples(gm, am, wd.T, rates)
    w2, f2 = compensate(e, gm, am, wd)
    np.testing.assert_allclose(w1.T, w2, rtol=0, atol=1e-15 * np.abs(w2).max())
    np.testing.assert_allclose(f1.T, f2, rtol=0, atol=1e-15 * np.abs(f2).max())
    np.testing.assert_allclose(f1.T, f, rtol=0, atol=1e-12 * np.abs(f).max())


def test_block_compensation_refuses_what_does_not_converge() -> None:
    rng = np.random.default_rng(3)
    v = mems_errors(rng).as_vector()
    v[9:12] = 1.5  # gyro asymmetry 150 %: no contraction
    e = SensorErrors.from_vector(v)
    w, _, f = random_motion(rng, 50)
    with pytest.raises(ImplausibleErrors), np.errstate(over='ignore', invalid='ignore'):
        BlockCompensation.of(e).rates(w, f)


def test_compensation_inverses_are_those_of_the_jacobians_matrices() -> None:
    """error_model.compensation_inverses: D_g^-1 by sign pattern (the same bits as one LAPACK
    inverse per sample, zero rates included) and D_a^-1 by its adjugate (to rounding)."""
    from imu_calib_ros.core.estimator.error_model import compensation_inverses
    rng = np.random.default_rng(4)
    e = mems_errors(rng)
    w, _, f = random_motion(rng, 200)
    w[5] = 0.0
    w[7, 1] = 0.0
    Dg_inv, Da_inv = compensation_inverses(e, w, f)
    eye = np.eye(3)
    Dg = eye + e.gyro_scale_misalignment + np.einsum(
        'ni,ij->nij', e.gyro_scale_asymmetry * np.sign(w), eye)
    Da = eye + e.accel_scale_misalignment + np.einsum(
        'ni,ij->nij', e.accel_scale_asymmetry * np.sign(f)
        + 2 * e.accel_quadratic_per_m_s2 * f, eye)
    assert np.array_equal(Dg_inv, np.linalg.inv(Dg))
    np.testing.assert_allclose(Da_inv, np.linalg.inv(Da), rtol=0, atol=1e-15)


def test_row_window_means_are_cut_at_the_ends_and_at_gaps() -> None:
    from imu_calib_ros.core.estimator.propagation import RowWindow
    rng = np.random.default_rng(6)
    n, k = 40, 3
    x = rng.normal(size=(3, n))
    gap = np.zeros(n - 1, bool)
    gap[[9, 10, 25]] = True  # rows 10, 11 and 26 follow a gap
    got = RowWindow(n, k, gap)(x)
    seg = np.concatenate([[0], np.cumsum(gap)])
    for i in range(n):
        rows = [j for j in range(i - k, i + k + 1) if 0 <= j < n and seg[j] == seg[i]]
        np.testing.assert_allclose(got[:, i], x[:, rows].mean(axis=1), rtol=0, atol=1e-14)
    assert RowWindow(n, 0, gap)(x) is x


def _static_block(rng: np.random.Generator, errors: SensorErrors, sigma_w: float,
                  sigma_f: float, rate_hz: float, chunks: int):  # noqa: ANN202
    """A level IMU at rest, heading north, ``chunks`` chunks of a second through
    ``propagate_block``: (attitude error [rad] less the integrated gyro noise, velocity error
    [m/s] less the integrated accelerometer noise, seconds)."""
    from imu_calib_ros.core.earth import Site
    from imu_calib_ros.core.estimator import error_model as em
    from imu_calib_ros.core.estimator.propagation import omega_dot_half_span, propagate_block
    from imu_calib_ros.core.rotation import matrix_to_rotvec
    from imu_calib_ros.core.strapdown import Strapdown
    site = Site(45.0, 0.0)
    dt = 1.0 / rate_hz
    n = int(rate_hz)
    h = omega_dot_half_span(dt)
    N = chunks * n + h
    w_true = np.broadcast_to(site.omega_ie_enu, (N, 3))  # body = ENU
    f_true = np.broadcast_to([0.0, 0.0, site.gravity], (N, 3))
    nw = rng.normal(0.0, sigma_w, (N, 3))
    nf = rng.normal(0.0, sigma_f, (N, 3))
    gm, am = measure(errors, w_true, np.zeros((N, 3)), f_true)
    t = (np.arange(1, N + 1) * dt * 1e9).astype(np.int64)
    nav = Strapdown(site, np.eye(3))
    lay = em.StateLayout.build(('gyro_bias', 'gyro_asymmetry', 'accel_bias', 'accel_asymmetry'))
    propagate_block(nav, errors, 0.0, None, t, gm + nw, am + nf, dt, chunks, n, lay,
                    site.omega_ie_enu, table=True)
    m = chunks * n
    # the first sample's interval is a nominal period: the noise integral of samples 0..m-1
    return (matrix_to_rotvec(nav.R_enu_imu) - nw[:m].sum(axis=0) * dt,
            nav.v_enu_m_s - nf[:m].sum(axis=0) * dt, m * dt)


def test_asymmetry_of_a_noisy_gyro_at_rest_adds_no_rate() -> None:
    """CONTRACT 3's ``ag |omega|`` is of the true rate. A noisy sample's magnitude is
    rectified (at rest ``E|n| = 0.8 sigma``): compensated with each sample's own, a consumer
    gyro at 1 kHz (0.02 deg/s/sqrt(Hz)) with ``ag`` 1 % gained 9e-5 rad/s (18 deg/h) of
    rate at rest, the bias estimate that much off. Through ``propagate_block`` the argument
    is the mean over +-5 samples: the attitude drifts by at most a third of that."""
    rng = np.random.default_rng(7)
    ag = np.array([0.01, -0.01, 0.01])
    e = SensorErrors.from_vector(np.zeros(45))
    v = e.as_vector()
    v[9:12] = ag
    e = SensorErrors.from_vector(v)
    sigma = np.radians(0.02) * np.sqrt(1000.0)
    drift, _, T = _static_block(rng, e, sigma, 0.0, 1000.0, 60)
    rect_sample = ag * np.sqrt(2.0 / np.pi) * sigma  # compensate's, per sample
    rect_window = rect_sample / np.sqrt(11.0)  # the window's: 11 samples
    # the compensation subtracts ag |S(w)|: the rate comes out low by the rectification
    # (the |n| mean over 60,000 samples: 0.3 % of it; the earth rate's share 1e-3 of it)
    np.testing.assert_allclose(drift / T, -rect_window, rtol=0.05)
    assert np.all(np.abs(drift / T) < 0.35 * np.abs(rect_sample))


def test_asymmetry_of_a_noisy_level_accelerometer_adds_no_force() -> None:
    """The same for ``aa |f|`` on the level axes (a consumer accelerometer at 1 kHz, 300
    ug/sqrt(Hz), ``aa`` 1 %: 76 ug at rest with each sample's own magnitude); the vertical
    axis reads g, far from the kink."""
    rng = np.random.default_rng(8)
    v = SensorErrors.from_vector(np.zeros(45)).as_vector()
    v[33:36] = [0.01, -0.01, 0.01]  # aa
    e = SensorErrors.from_vector(v)
    sigma = 300e-6 * 9.80665 * np.sqrt(1000.0)
    _, dv, T = _static_block(rng, e, 0.0, sigma, 1000.0, 30)
    rect_window = 0.01 * np.sqrt(2.0 / np.pi) * sigma / np.sqrt(11.0)
    np.testing.assert_allclose(dv[:2] / T, [-rect_window, rect_window], rtol=0.05)


def test_table_regressor_keeps_the_reference_points_centripetal_force() -> None:
    """The specific-force regressor of a table's Jacobians in a steady 1 rad/s turn with the
    IMU 31 cm from the axes: the block mean of the navigation-frame force loses the
    centripetal ``omega x (omega x rho)`` (its direction turns with the table); given it, the
    regressor is the sample's true specific force (noise-free)."""
    from imu_calib_ros.core.estimator.propagation import table_specific_force
    from imu_calib_ros.core.rotation import rotvec_to_matrix
    N, dt = 100, 0.01
    w = np.array([0.0, 0.0, 1.0])  # about the vertical (IMU z up at the start)
    R = rotvec_to_matrix(np.outer(np.arange(N) * dt, w))  # (N, 3, 3) R_enu_imu
    rho = np.array([0.25, -0.17, 0.08])
    cen = np.broadcast_to(np.cross(w, np.cross(w, rho)), (N, 3))
    f_imu = np.einsum('nji,j->ni', R, [0.0, 0.0, 9.81]) + cen
    f_enu = np.einsum('nij,nj->ni', R, f_imu)
    np.testing.assert_allclose(table_specific_force(R, f_enu, cen), f_imu, rtol=0, atol=1e-12)
    # without it: half the centripetal force (0.15 m/s^2) off at the block's ends
    old = table_specific_force(R, f_enu)
    assert np.linalg.norm(old - f_imu, axis=1).max() > 0.4 * np.linalg.norm(cen[0])


def test_propagate_block_passes_the_lever_arm_to_the_table_regressor() -> None:
    """Wiring: in a steady turn the accelerometer-scale columns of a table's transition rows
    change with the lever arm (its centripetal force in the regressor) and the gyro ones
    do not."""
    from imu_calib_ros.core.earth import Site
    from imu_calib_ros.core.estimator import error_model as em
    from imu_calib_ros.core.estimator.propagation import omega_dot_half_span, propagate_block
    from imu_calib_ros.core.strapdown import Strapdown
    site = Site(45.0, 0.0)
    dt, n, B = 0.01, 100, 2
    h = omega_dot_half_span(dt)
    N = B * n + h
    w = np.broadcast_to([0.0, 0.0, 1.0], (N, 3))
    rho = np.array([0.25, -0.17, 0.08])
    f = np.broadcast_to(np.cross(w[0], np.cross(w[0], rho)) + [0.0, 0.0, site.gravity], (N, 3))
    t = (np.arange(1, N + 1) * dt * 1e9).astype(np.int64)
    lay = em.StateLayout.build(('gyro_scale', 'accel_scale'))
    rows = []
    for lever in (None, rho):
        nav = Strapdown(site, np.eye(3))
        rows.append(propagate_block(nav, SensorErrors.from_vector(np.zeros(45)), 0.0, None, t,
                                    w, f, dt, B, n, lay, site.omega_ie_enu, table=True,
                                    lever_arm_imu_m=lever).rows_s)
    g, a = lay.slices['gyro_scale'], lay.slices['accel_scale']
    assert np.array_equal(rows[0][:, :, g], rows[1][:, :, g])
    change = np.abs(rows[0][:, :, a] - rows[1][:, :, a]).max()
    assert change > 1e-3 * np.abs(rows[1][:, :, a]).max()


def test_chunk_end_rates_are_exact_for_a_rate_quadratic_in_time() -> None:
    """The lever arm's velocity takes the rate at each chunk-end instant: from the interval
    means either side and the one before, exact for ``omega = a + b t + c t^2`` (the mean of
    the two either side is ``c dt^2 / 3`` off: 5e-5 rad/s in Kozlov's 90 deg, 5 s oscillations
    at 100 Hz, 1.6e-5 m/s with an IMU 31 cm from the axes, 16 velocity sigmas)."""
    from imu_calib_ros.core.earth import Site
    from imu_calib_ros.core.estimator import error_model as em
    from imu_calib_ros.core.estimator.propagation import omega_dot_half_span, propagate_block
    from imu_calib_ros.core.strapdown import Strapdown
    site = Site(45.0, 0.0)
    dt, n, B = 0.01, 10, 5
    h = omega_dot_half_span(dt)
    N = B * n + h
    t = np.arange(N + 1) * dt  # interval k is (t[k], t[k+1]]
    coef = np.array([[0.1, 2.0, -3.0], [0.0, -1.0, 5.0], [0.3, 0.5, 1.5]])  # a, b, c per axis
    F = np.stack([a * t + b * t ** 2 / 2 + c * t ** 3 / 3 for a, b, c in coef], axis=1)
    w = np.diff(F, axis=0) / dt  # exact interval means
    f = np.broadcast_to([0.0, 0.0, site.gravity], (N, 3))
    stamps = (t[1:] * 1e9).round().astype(np.int64)
    blk = propagate_block(Strapdown(site, np.eye(3)), SensorErrors.from_vector(np.zeros(45)),
                          0.0, None, stamps, w, f, dt, B, n,
                          em.StateLayout.build(('gyro_bias',)), site.omega_ie_enu, table=True)
    t_end = t[1:][blk.ends]
    truth = np.stack([a + b * t_end + c * t_end ** 2 for a, b, c in coef], axis=1)
    np.testing.assert_allclose(blk.omega_ib_end_rad_s, truth, rtol=0, atol=1e-12)
    two = 0.5 * (w[blk.ends] + w[blk.ends + 1])
    np.testing.assert_allclose(two - truth, coef[:, 2] * dt ** 2 / 3 + 0 * truth, rtol=1e-6)
    # a sample lost just before a chunk end: no interval before it, the mean of the two
    gap = stamps.copy()
    gap[blk.ends[2]:] += int(0.02e9)  # the interval ending at chunk 2's end is 30 ms long
    blk2 = propagate_block(Strapdown(site, np.eye(3)), SensorErrors.from_vector(np.zeros(45)),
                           0.0, None, gap, w, f, dt, B, n,
                           em.StateLayout.build(('gyro_bias',)), site.omega_ie_enu, table=True)
    np.testing.assert_allclose(blk2.omega_ib_end_rad_s[2], two[2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(blk2.omega_ib_end_rad_s[3:], truth[3:], rtol=0, atol=1e-12)


def test_lever_acceleration_is_the_cross_products() -> None:
    from imu_calib_ros.core.estimator.propagation import lever_acceleration
    rng = np.random.default_rng(10)
    w, wd, rho = rng.normal(size=(50, 3)), rng.normal(size=(50, 3)), rng.normal(size=3)
    np.testing.assert_allclose(lever_acceleration(w, wd, rho),
                               np.cross(wd, rho) + np.cross(w, np.cross(w, rho)),
                               rtol=0, atol=1e-13)
