"""sensor_model.py: each CONTRACT 3 term by hand, the size effect against rigid-body
kinematics, the exact inverse, the parameter vector and the CONTRACT 4 mapping."""
import copy

import numpy as np
import pytest

from imu_calib_ros.core.earth import Site
from imu_calib_ros.core.errors import ConfigError
from imu_calib_ros.core.fixture import Fixture, Joint
from imu_calib_ros.core.sensor_model import (
    N_PARAMETERS, PARAMETER_KEYS, PARAMETER_NAMES, PARAMETER_SLICES, SensorErrors, compensate,
    compensate_one,
    mean_rate_derivative, measure, size_effect_term)

G = 9.81
DEG_H = np.radians(1.0) / 3600.0


def mems_errors(rng: np.random.Generator) -> SensorErrors:
    """Random errors of MEMS magnitude (MTi-1 class, generous): the realistic worst case."""
    n = rng.normal
    kg = n(scale=3e-3, size=(3, 3))
    r = n(scale=5e-3, size=(3, 3))
    np.fill_diagonal(r, 0.0)
    return SensorErrors(
        gyro_bias_rad_s=n(scale=500 * DEG_H, size=3),
        gyro_scale_misalignment=(kg + kg.T) / 2,
        gyro_scale_asymmetry=n(scale=1e-3, size=3),
        gyro_g_sensitivity_rad_s_per_m_s2=n(scale=np.radians(0.1) / G, size=(3, 3)),
        accel_bias_m_s2=n(scale=0.05, size=3),
        accel_scale_misalignment=n(scale=3e-3, size=(3, 3)),
        accel_scale_asymmetry=n(scale=1e-3, size=3),
        accel_quadratic_per_m_s2=n(scale=1e-4 / G, size=3),
        size_effect_m=r,
    )


def random_motion(rng: np.random.Generator, n: int = 500):
    w = rng.normal(scale=2.0, size=(n, 3))
    w[:20] *= 1e-6  # near zero: |.| terms switch sign here
    wd = rng.normal(scale=10.0, size=(n, 3))
    f = rng.normal(scale=8.0, size=(n, 3))
    f[20:40] *= 1e-7
    return w, wd, f


def test_parameter_vector_layout() -> None:
    assert N_PARAMETERS == 45 == len(PARAMETER_NAMES)
    covered = np.zeros(45, int)
    for k in PARAMETER_KEYS:
        covered[PARAMETER_SLICES[k]] += 1
    assert np.all(covered == 1)
    assert PARAMETER_NAMES[PARAMETER_SLICES['gyroscope.scale_misalignment']][3] == \
        'gyroscope.scale_misalignment[xy]'
    assert PARAMETER_NAMES[39:45] == tuple(f'accelerometer.size_effect[{p}]' for p in
                                           ('xy', 'xz', 'yx', 'yz', 'zx', 'zy'))
    x = np.arange(1.0, 46.0)
    e = SensorErrors.from_vector(x)
    np.testing.assert_array_equal(e.as_vector(), x)
    np.testing.assert_array_equal(e.gyro_scale_misalignment, [[4, 7, 8], [7, 5, 9], [8, 9, 6]])
    np.testing.assert_array_equal(e.size_effect_m, [[0, 40, 41], [42, 0, 43], [44, 45, 0]])
    np.testing.assert_array_equal(e.accel_scale_misalignment.ravel(), x[24:33])
    np.testing.assert_array_equal(SensorErrors.zeros().as_vector(), 0.0)
    with pytest.raises(ValueError):
        e.gyro_bias_rad_s[0] = 3.0  # read-only


def test_constructor_refuses_bad_values() -> None:
    z = SensorErrors.zeros()
    kg = np.zeros((3, 3))
    kg[0, 1] = 1e-6
    with pytest.raises(ValueError, match='symmetric'):
        z.replace(gyro_scale_misalignment=kg)
    with pytest.raises(ValueError, match='diagonal'):
        z.replace(size_effect_m=np.eye(3) * 1e-3)
    with pytest.raises(ValueError, match='shape'):
        z.replace(accel_bias_m_s2=np.zeros(4))
    with pytest.raises(ValueError, match='finite'):
        z.replace(accel_bias_m_s2=np.array([0, np.nan, 0]))


def test_each_term_by_hand() -> None:
    z = SensorErrors.zeros()
    w = np.array([[-0.5, 2.0, 0.1]])
    wd = np.zeros((1, 3))
    f = np.array([[1.0, -3.0, 9.8]])
    g, a = measure(z, w, wd, f)
    np.testing.assert_array_equal(g, w)
    np.testing.assert_array_equal(a, f)
    # gyro: scale/misalignment, asymmetry, g-sensitivity, bias
    kg = np.array([[1e-3, 2e-4, 0], [2e-4, -5e-4, 0], [0, 0, 0]])
    g, _ = measure(z.replace(gyro_scale_misalignment=kg), w, wd, f)
    np.testing.assert_allclose(g[0], [-0.5 - 0.5e-3 + 4e-4, 2.0 - 1e-4 - 1e-3, 0.1], rtol=1e-15)
    g, _ = measure(z.replace(gyro_scale_asymmetry=np.array([1e-3, 1e-3, 0])), w, wd, f)
    np.testing.assert_allclose(g[0], [-0.5 + 0.5e-3, 2.0 + 2e-3, 0.1], rtol=1e-15)
    G_ = np.zeros((3, 3))
    G_[2, 2] = 1e-4
    g, _ = measure(z.replace(gyro_g_sensitivity_rad_s_per_m_s2=G_), w, wd, f)
    np.testing.assert_allclose(g[0], [-0.5, 2.0, 0.1 + 9.8e-4], rtol=1e-15)
    # accel: scale, asymmetry, quadratic, bias
    ka = np.zeros((3, 3))
    ka[1, 2] = 1e-3
    _, a = measure(z.replace(accel_scale_misalignment=ka), w, wd, f)
    np.testing.assert_allclose(a[0], [1.0, -3.0 + 9.8e-3, 9.8], rtol=1e-15)
    _, a = measure(z.replace(accel_scale_asymmetry=np.array([2e-3, 2e-3, 0]),
                             accel_quadratic_per_m_s2=np.array([0, 0, 1e-5]),
                             accel_bias_m_s2=np.array([0.01, 0, 0])), w, wd, f)
    np.testing.assert_allclose(a[0], [1.0 + 2e-3 + 0.01, -3.0 + 6e-3, 9.8 + 9.8 ** 2 * 1e-5],
                               rtol=1e-15)


def test_size_effect_by_hand() -> None:
    r = np.zeros((3, 3))
    r[0, 1] = 0.01  # accelerometer x displaced 1 cm along y
    r[0, 2] = 0.02  # ... and 2 cm along z
    # angular acceleration about z: point (0, .01, .02) accelerates along -x by wdot*0.01
    s = size_effect_term(r, np.zeros(3), np.array([0, 0, 2.0]))
    np.testing.assert_allclose(s, [-0.02, 0, 0], atol=1e-17)
    # spin about x and z: omega x (omega x r) x-component = w_x (w . r) = 1 * (2 * .02)
    s = size_effect_term(r, np.array([1.0, 0, 2.0]), np.zeros(3))
    np.testing.assert_allclose(s, [0.04, 0, 0], atol=1e-17)


def test_size_effect_equals_rigid_body_lever_arm() -> None:
    """Accelerometer i at r_i senses f at r_i: compare with the fixture kinematics of a
    reference point moved to r_i (the fixture neglects Omega x (Omega x r) < 1e-11)."""
    rng = np.random.default_rng(4)
    joints = []
    for i in range(3):
        a = rng.normal(size=3)
        joints.append(Joint(f'j{i}', a / np.linalg.norm(a)))
    site = Site(55.7, 200.0)
    t = np.linspace(0, 3, 30)[:, None]
    q = np.sin([1.1, 2.0, 3.3] * t) * [2.0, 1.0, 1.5]
    qd = np.cos([1.1, 2.0, 3.3] * t) * [2.0 * 1.1, 2.0, 1.5 * 3.3]
    qdd = -np.sin([1.1, 2.0, 3.3] * t) * [2.0 * 1.1 ** 2, 4.0, 1.5 * 3.3 ** 2]
    r = rng.normal(scale=0.02, size=(3, 3))
    np.fill_diagonal(r, 0.0)
    ref = Fixture(site, tuple(joints), np.zeros(3), np.zeros(3)).kinematics(q, qd, qdd)
    s = size_effect_term(r, ref.omega_ib_imu_rad_s, ref.omega_dot_ib_imu_rad_s2)
    assert np.max(np.abs(s)) > 0.1  # the test exercises a real effect
    Om = site.omega_ie_enu
    for i in range(3):
        at_ri = Fixture(site, tuple(joints), np.zeros(3), r[i]).kinematics(q, qd, qdd)
        # add back the neglected Omega x (Omega x r) (~1e-10 m/s^2 here)
        neglected = np.cross(Om, np.cross(Om, at_ri.p_enu_m))
        neglected_imu = np.einsum('nji,nj->ni', at_ri.R_enu_imu, neglected)
        np.testing.assert_allclose(at_ri.f_imu_m_s2[:, i] - ref.f_imu_m_s2[:, i]
                                   + neglected_imu[:, i], s[:, i], rtol=0, atol=2e-14)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_compensate_inverts_measure_to_machine_precision(seed: int) -> None:
    rng = np.random.default_rng(seed)
    e = mems_errors(rng)
    w, wd, f = random_motion(rng)
    gm, am = measure(e, w, wd, f)
    w2, f2 = compensate(e, gm, am, omega_dot_imu_rad_s2=wd)
    np.testing.assert_allclose(w2, w, rtol=0, atol=1e-12 * np.max(np.abs(w)))
    np.testing.assert_allclose(f2, f, rtol=0, atol=1e-12 * np.max(np.abs(f)))
    # and it really removed something large: errors are >> the tolerance
    assert np.max(np.abs(gm - w)) > 1e-3 and np.max(np.abs(am - f)) > 1e-2


def test_compensate_converges_for_large_nonlinear_terms() -> None:
    rng = np.random.default_rng(11)
    e = SensorErrors.from_vector(40 * mems_errors(rng).as_vector())
    w, wd, f = random_motion(rng, 100)
    gm, am = measure(e, w, wd, f)
    w2, f2 = compensate(e, gm, am, omega_dot_imu_rad_s2=wd)
    np.testing.assert_allclose(w2, w, rtol=0, atol=1e-12 * np.max(np.abs(w)))
    np.testing.assert_allclose(f2, f, rtol=0, atol=1e-12 * np.max(np.abs(f)))


def test_compensate_with_stamps_estimates_omega_dot() -> None:
    rng = np.random.default_rng(5)
    e = mems_errors(rng)
    stamps = 10**9 + np.cumsum(rng.integers(4_900_000, 5_100_000, size=200))
    t = (stamps - stamps[0]) * 1e-9
    w = np.stack([np.sin(3 * t), 2 * np.cos(2 * t), 0.5 * t], axis=1)
    f = np.stack([np.cos(t), np.sin(t), 9.8 + 0 * t], axis=1)
    wd_est = mean_rate_derivative(stamps, w)
    gm, am = measure(e, w, wd_est, f)
    w2, f2 = compensate(e, gm, am, stamps_ns=stamps)
    np.testing.assert_allclose(w2, w, rtol=0, atol=1e-12 * np.max(np.abs(w)))
    np.testing.assert_allclose(f2, f, rtol=0, atol=1e-12 * np.max(np.abs(f)))
    # neither omega_dot nor stamps: omega_dot = 0, only the centripetal part is removed
    w0, f0 = compensate(e, *measure(e, w, np.zeros(3), f))
    np.testing.assert_allclose(f0, f, rtol=0, atol=1e-12 * np.max(np.abs(f)))
    # without a size effect no omega_dot is needed
    w3, _ = compensate(e.replace(size_effect_m=np.zeros((3, 3))), w, f)
    assert w3.shape == w.shape


def test_mean_rate_derivative_exact_for_quadratic_rates() -> None:
    """For omega(t) quadratic, the mean over (t_k - dt, t_k] is omega(t_k - dt/2) + const,
    and the target, the mean of omega_dot over the interval, is omega'(t_k - dt/2)."""
    dt = 0.005
    stamps = (np.arange(1, 101) * dt * 1e9).astype(np.int64) + 7_000_000_000
    tk = (stamps - stamps[0]) * 1e-9
    c1, c2 = np.array([0.3, -1.0, 2.0]), np.array([4.0, 0.5, -3.0])

    def mean_rate(t0, t1):  # exact mean of c1 t + c2 t^2 over (t0, t1]
        return (c1 * (t1**2 - t0**2) / 2 + c2 * (t1**3 - t0**3) / 3) / (t1 - t0)

    w = np.array([mean_rate(t - dt, t) for t in tk])
    wdot_mid = c1 + 2 * c2 * (tk[:, None] - dt / 2)
    np.testing.assert_allclose(mean_rate_derivative(stamps, w), wdot_mid, rtol=0, atol=1e-9)
    # causal: refers to t_k - dt
    got = mean_rate_derivative(stamps, w, causal=True)
    np.testing.assert_allclose(got[1:], (c1 + 2 * c2 * (tk[:, None] - dt))[1:], atol=1e-9)
    with pytest.raises(ValueError):
        mean_rate_derivative(stamps[::-1], w)


def test_dict_round_trip_and_validation() -> None:
    e = mems_errors(np.random.default_rng(3))
    d = e.to_dict()
    assert set(d) == {'gyroscope', 'accelerometer'}
    assert isinstance(d['gyroscope']['bias'][0], float)
    e2 = SensorErrors.from_dict(copy.deepcopy(d))
    np.testing.assert_array_equal(e2.as_vector(), e.as_vector())

    def bad(mutate, key, words):
        dd = copy.deepcopy(d)
        mutate(dd)
        with pytest.raises(ConfigError) as ei:
            SensorErrors.from_dict(dd, 'c.yaml', 'imu_calibration')
        assert ei.value.key == key and ei.value.source == 'c.yaml'
        assert words in str(ei.value)

    bad(lambda x: x['gyroscope'].pop('bias'), 'imu_calibration.gyroscope.bias', 'missing')
    bad(lambda x: x.pop('accelerometer'), 'imu_calibration.accelerometer', 'missing')
    bad(lambda x: x['gyroscope'].update(offset=[0, 0, 0]), 'imu_calibration.gyroscope.offset',
        'unknown')
    bad(lambda x: x.update(magnetometer={}), 'imu_calibration.magnetometer', 'unknown')
    bad(lambda x: x['gyroscope'].update(bias=[0, 0]), 'imu_calibration.gyroscope.bias',
        'list of 3')
    bad(lambda x: x['accelerometer'].update(scale_misalignment=[[0, 0, 0]] * 2),
        'imu_calibration.accelerometer.scale_misalignment', '3x3')
    bad(lambda x: x['accelerometer']['bias'].__setitem__(1, float('nan')),
        'imu_calibration.accelerometer.bias', 'not finite')
    bad(lambda x: x['gyroscope']['scale_misalignment'][0].__setitem__(1, 1e-3),
        'imu_calibration.gyroscope.scale_misalignment', 'symmetric')
    bad(lambda x: x['accelerometer']['size_effect'][2].__setitem__(2, 1e-3),
        'imu_calibration.accelerometer.size_effect', 'diagonal')
    bad(lambda x: x['accelerometer']['quadratic'].__setitem__(0, 'a'),
        'imu_calibration.accelerometer.quadratic', 'expected')
    sig = SensorErrors.from_vector(np.abs(e.as_vector())).to_dict()
    SensorErrors.from_dict(sig, nonnegative=True)
    sig['gyroscope']['bias'][2] = -1e-6
    with pytest.raises(ConfigError, match='negative') as ei:
        SensorErrors.from_dict(sig, 'c.yaml', 'imu_calibration.sigma', nonnegative=True)
    assert ei.value.key == 'imu_calibration.sigma.gyroscope.bias'


def test_single_sample_and_empty_batches() -> None:
    e = mems_errors(np.random.default_rng(8))
    w, wd, f = np.array([0.1, -0.2, 0.3]), np.array([1.0, 0.0, -1.0]), np.array([0, 0, 9.8])
    g, a = measure(e, w, wd, f)
    assert g.shape == a.shape == (3,)
    w2, f2 = compensate(e, g, a, wd)
    np.testing.assert_allclose(w2, w, rtol=0, atol=1e-15)
    np.testing.assert_allclose(f2, f, rtol=0, atol=1e-14)
    empty = np.zeros((0, 3))
    w3, f3 = compensate(e, empty, empty, stamps_ns=np.zeros(0, np.int64))
    assert w3.shape == f3.shape == (0, 3)
    # zero input and no errors: exactly zero out, no spurious iteration failure
    w4, f4 = compensate(SensorErrors.zeros(), np.zeros((2, 3)), np.zeros((2, 3)))
    assert np.all(w4 == 0) and np.all(f4 == 0)


@pytest.mark.parametrize('scale', [1.0, 40.0])
def test_compensate_same_bits_alone_and_in_any_batch(scale: float) -> None:
    """The live stream (one sample, Python floats) and the offline batch give identical bits.

    This is what the compensator node's bit-for-bit test against offline compensation rests
    on: each row iterates and stops on its own, with the same IEEE operations per component.
    """
    rng = np.random.default_rng(21)
    e = SensorErrors.from_vector(scale * mems_errors(rng).as_vector())
    w, wd, f = random_motion(rng, 300)
    gm, am = measure(e, w, wd, f)
    w_all, f_all = compensate(e, gm, am, omega_dot_imu_rad_s2=wd)
    for size in (1, 2, 7, 9, 64):  # both the Python-float and the numpy-column paths
        parts = [compensate(e, gm[k:k + size], am[k:k + size], wd[k:k + size])
                 for k in range(0, len(gm), size)]
        np.testing.assert_array_equal(np.vstack([p[0] for p in parts]), w_all)
        np.testing.assert_array_equal(np.vstack([p[1] for p in parts]), f_all)
    one = [compensate_one(e, gm[k], am[k], wd[k]) for k in range(len(gm))]
    np.testing.assert_array_equal(np.array([o[0] for o in one]), w_all)
    np.testing.assert_array_equal(np.array([o[1] for o in one]), f_all)
    # and the result is the inverse of the model (not merely self-consistent)
    np.testing.assert_allclose(w_all, w, rtol=0, atol=1e-12 * np.max(np.abs(w)))


def test_compensate_non_finite_sample_is_nan_and_leaves_others() -> None:
    e = mems_errors(np.random.default_rng(2))
    w, wd, f = random_motion(np.random.default_rng(3), 20)
    gm, am = measure(e, w, wd, f)
    gm[5, 1] = np.nan
    am[9, 2] = np.inf
    w2, f2 = compensate(e, gm, am, wd)
    bad = np.zeros(20, bool)
    bad[[5, 9]] = True
    assert np.all(np.isnan(w2[bad])) and np.all(np.isnan(f2[bad]))
    np.testing.assert_allclose(w2[~bad], w[~bad], rtol=0, atol=1e-12 * np.max(np.abs(w)))
    assert all(np.isnan(v) for v in compensate_one(e, gm[5], am[5], wd[5])[0])


def test_mean_rate_derivative_not_across_a_gap() -> None:
    """CONTRACT 1: after a gap the rates jump (a step in the lost stretch); the derivative is
    taken per stretch (one-sided at its ends; the causal form is zero at stretch starts), so
    the step never shows up as omega_dot, and a lone sample between two gaps gets zero. A
    linear ramp is exact inside each stretch."""
    dt_ns = 5_000_000
    k = np.r_[1:41, 61:62, 81:121]  # gaps before samples 61 and 81: sample 61 is alone
    stamps = k * dt_ns + 7_000_000_000
    t = (stamps - stamps[0]) * 1e-9
    slope = np.array([0.5, -1.0, 2.0])
    w = t[:, None] * slope + np.where(k > 60, 3.0, 0.0)[:, None]  # +3 rad/s step in the gap
    lone = int(np.flatnonzero(k == 61)[0])
    got = mean_rate_derivative(stamps, w)
    np.testing.assert_allclose(np.delete(got, lone, axis=0),
                               np.broadcast_to(slope, (len(k) - 1, 3)), atol=1e-9)
    np.testing.assert_array_equal(got[lone], 0.0)
    # causal: zero at each stretch start (nothing before it), the slope elsewhere
    got = mean_rate_derivative(stamps, w, causal=True)
    starts = np.flatnonzero(np.r_[True, np.diff(k) > 1])
    np.testing.assert_array_equal(got[starts], 0.0)
    np.testing.assert_allclose(np.delete(got, starts, axis=0),
                               np.broadcast_to(slope, (len(k) - len(starts), 3)), atol=1e-9)


@pytest.mark.parametrize('hz', [50.0, 100.0, 200.0, 400.0, 800.0])
def test_causal_rate_derivative_gap_rule_at_exactly_one_and_a_half_periods(hz: float) -> None:
    """The offline causal derivative decides a gap exactly as the live node does
    (``core.stream_compensation.StreamCompensation``: ``0 < dn * 1e-9 <= 1.5 * period``), also
    at the boundary, where a comparison in integer ns rounds the other way at these rates."""
    period = 1.0 / hz
    thr = int(round(1.5 * period * 1e9))
    for dn in range(thr - 2, thr + 3):
        stamps = np.array([0, int(period * 1e9), int(period * 1e9) + dn], np.int64)
        w = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
        got = mean_rate_derivative(stamps, w, causal=True, nominal_period_s=period)[2, 0]
        assert (got != 0.0) == (0.0 < dn * 1e-9 <= 1.5 * period), (hz, dn, got)
