"""Savage's SRT processor: the linear model in code reproduces Table 2, and the processor
recovers the simulator's truth within its noise-limited sigmas."""
import numpy as np
import pytest

from imu_calib_ros.core.methods import srt

G = 9.80665
ALL = ['1', '1a', '2', '2a', '3', '3a', '4', '5', '6', '7', '8', '9', '10', '11', '12', '13',
       '14']


@pytest.fixture(scope='module')
def design():
    J, rows = srt.design_sensitivities(ALL, g_m_s2=G, dwell_s=2.0)
    return J, rows


def _row(design, name):
    J, rows = design
    return J[rows.index(name)]


def _p(name):
    return srt.PARAM_NAMES.index(name)


# Savage eq. (12) with v_ij = 2 Kg_ij, mu_ij = Ka_ij, kappa_iii = ag_i, lambda_i = ba_i
# (row, {param: coefficient}) -- every other parameter must have (near) zero sensitivity
EQ12 = [
    ('srt:1 dA_+x', {'Kg_yy': -2 * np.pi * G, 'ag_y': -2 * np.pi * G}),
    ('srt:2 dA_+y', {'Kg_xx': 2 * np.pi * G, 'ag_x': 2 * np.pi * G}),
    ('srt:3 dA_+y', {'Kg_zz': -2 * np.pi * G, 'ag_z': -2 * np.pi * G}),
    ('srt:1a dA_+x', {'Kg_yy': 2 * np.pi * G, 'ag_y': -2 * np.pi * G}),
    ('srt:2a dA_+y', {'Kg_xx': -2 * np.pi * G, 'ag_x': 2 * np.pi * G}),
    ('srt:3a dA_+y', {'Kg_zz': 2 * np.pi * G, 'ag_z': -2 * np.pi * G}),
    ('srt:4 dA_+y', {'Kg_yz': 2 * 4 * G}),     # 4 g v_yz
    ('srt:5 dA_+x', {'Kg_xz': 2 * 4 * G}),     # 4 g v_zx
    ('srt:6 dA_+y', {'Kg_xy': 2 * 4 * G}),     # 4 g v_xy
    ('srt:7 dA_+x', {'Ka_xy': 2 * G, 'Kg_xy': G * 2}),  # 2 g (mu_xy + v_xy / 2)
    ('srt:7 dA_+z', {'ba_z': -2, 'Kg_xx': -np.pi * G, 'ag_x': -np.pi * G}),
    ('srt:8 dA_+x', {'Ka_xz': 2 * G, 'Kg_xz': 2 * G}),
    ('srt:9 dA_+z', {'Ka_zx': 2 * G, 'Kg_xz': 2 * G}),
    ('srt:10 dA_+z', {'Ka_zy': 2 * G, 'Kg_yz': 2 * G}),
    ('srt:11 dA_+y', {'Ka_yz': 2 * G, 'Kg_yz': 2 * G}),
    ('srt:12 dA_+y', {'Ka_yx': 2 * G, 'Kg_xy': 2 * G}),
    ('srt:13 dA_+y', {'ba_y': -2, 'Kg_yz': -2 * 2 * G}),  # -2 (lambda_y + g v_yz)
    ('srt:14 dA_+x', {'ba_x': -2, 'Kg_xz': -2 * 2 * G}),
]


@pytest.mark.parametrize('row,coeffs', EQ12, ids=[r for r, _ in EQ12])
def test_linear_model_reproduces_eq12_and_table2(design, row, coeffs):
    """H_k = 2 pi g (scale), 4 g (non-orthogonality), 2 g (accel misalignment) with
    Savage's signs. Tolerance: the earth-rate coupling of eq. (17) (omega_e T ~ 1e-3)."""
    J = _row(design, row)
    expected = np.zeros(len(srt.PARAM_NAMES))
    for name, c in coeffs.items():
        expected[_p(name)] = c
    scale = np.where(np.arange(len(expected)) >= 21, 1.0, G)  # biases are per m/s^2
    np.testing.assert_allclose(J / scale, expected / scale, atol=3e-3)


def test_table2_magnitudes(design):
    assert abs(_row(design, 'srt:1 dA_+x')[_p('Kg_yy')]) == pytest.approx(2 * np.pi * G, 1e-3)
    # per Savage's v_yz = 2 Kg_yz: H = 4 g
    assert _row(design, 'srt:4 dA_+y')[_p('Kg_yz')] / 2 == pytest.approx(4 * G, 1e-3)
    assert _row(design, 'srt:7 dA_+x')[_p('Ka_xy')] == pytest.approx(2 * G, 1e-3)


def test_down_components_eq12(design):
    """a_Down7 start = -g (lambda_yy - lambda_yyy) + lambda_y (y down), end with the signs
    flipped for asymmetry and bias (eq. 12)."""
    J, rows = design
    i = [k for k, r in enumerate(rows) if r.endswith('down')]
    # the design matrix stacks [2 horizontal, 2 windows] per sequence; sequence 7 is 10th
    k7 = ALL.index('7') * 4
    start, end = J[k7 + 2], J[k7 + 3]
    assert rows[k7 + 2].endswith('down') and i
    assert start[_p('Ka_yy')] == pytest.approx(-G, 1e-6)
    assert start[_p('aa_y')] == pytest.approx(G, 1e-6)
    assert start[_p('ba_y')] == pytest.approx(1.0, 1e-6)
    assert end[_p('aa_y')] == pytest.approx(-G, 1e-6)
    assert end[_p('ba_y')] == pytest.approx(-1.0, 1e-6)


def test_any_sequence_set_rank():
    """Without 1a-3a the asymmetries cannot be told from the scale factors: the solver must
    fix three parameters, not invent them."""
    ids = [i for i in ALL if not i.endswith('a')]
    J, _ = srt.design_sensitivities(ids, g_m_s2=G, dwell_s=2.0)
    sol = srt.solve(J, np.zeros(J.shape[0]), np.full(J.shape[0], 1e-5))
    assert sol.estimated.sum() == len(srt.PARAM_NAMES) - 3


def test_recovers_simulated_truth():
    """Nav-grade IMU on Savage's fixture, all 17 sequences (6 s windows, 100 Hz): every
    estimated parameter within 3 sigma of the truth. Sigma = measured white noise + the
    accelerometer bias instability (row covariance) + the consider covariance of the fixed
    quadratic term (~5 ug at 1 g, otherwise absorbed by aa and ba) and size effect; over
    seeds 1-9 RMS(err/sigma) = 1.00, max 2.6 (270 values), so 3 sigma is honest for one seed,
    and sigmas at the sub-ppm / urad level the noise predicts (Savage sect. 9 scaled:
    0.002 deg/rt(h) over ~15 s -> ~2 urad -> ~0.3 ppm on 2 pi g)."""
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.plans import build_profile, plan_from_dict
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fx = load_fixture('savage_2axis')
    grade = load_grade('nav_grade')
    plan = plan_from_dict({'name': 't', 'steps': [
        {'srt_sequence': {'id': i, 'dwell_s': 6, 'rotation_s': 8}} for i in ALL]})
    sim = simulate(fx, build_profile(plan, fx), grade,
                   SimConfig(imu_rate_hz=100, joint_rate_hz=50, seed=3))
    errs, sig, fixed, extra = srt.estimate(sim.imu, sim.joints, fx, grade)
    labels = {s['label'] for s in extra['srt']['sequences']}
    assert {f'srt:{i}' for i in ALL} <= labels
    assert extra['srt']['not_estimated'] == []
    assert 'accelerometer.size_effect' in fixed
    for fld in ('gyro_bias_rad_s', 'gyro_scale_misalignment', 'gyro_scale_asymmetry',
                'accel_bias_m_s2', 'accel_scale_misalignment', 'accel_scale_asymmetry'):
        e = np.asarray(getattr(errs, fld)) - np.asarray(getattr(sim.truth.errors, fld))
        s = np.asarray(getattr(sig, fld))
        assert np.all(np.abs(e) < 3 * s), (fld, e / s)
    assert np.all(np.asarray(sig.gyro_scale_misalignment) < 1e-6)
    # accel bias: the run-mean bias differs from the turn-on constant by the bias
    # instability (Gauss-Markov, 2 ug), plus ~1-1.5 ug from noise and the fixed terms
    s_ba = np.asarray(sig.accel_bias_m_s2)
    assert np.all(s_ba >= grade.accel_bias_instability_m_s2)
    assert np.all(s_ba < np.hypot(grade.accel_bias_instability_m_s2, 1.5e-5))
    # re-play converged (sect. 8): last correction negligible
    assert extra['srt']['iterations'][-1]['max_abs_correction'] < 1e-9


def test_sample_intervals_follow_the_gap_rule():
    """CONTRACT 1: the sample after a dropped stretch integrates over one nominal period (the
    stamp difference would turn its rate by the whole gap's angle in the DCM of eq. 2)."""
    stamps = np.r_[np.arange(1, 101), np.arange(151, 201)].astype(np.int64) * 10_000_000
    dt = srt._dt(stamps)
    np.testing.assert_allclose(dt, np.full(stamps.size, 0.01), rtol=1e-12)


def test_short_dwells_estimate_only_what_beats_the_prior():
    """Dwells too short for a stationary window between sequences (4 s minus 0.5 s margins
    < 4 s) merge the sequences: few rows, heavily confounded parameters. Nothing is then
    reported better than the grade knows it: every estimated parameter's sigma (noise plus
    consider) is below its assumed sigma, and every parameter not estimated is written at
    its assumed value, 0, with that sigma. Before, such a run wrote a -1.76 % accelerometer
    scale (sigma 3.9 %) and a "not estimated" asymmetry of -298 ppm (sigma 10, 28 sigma
    off the truth)."""
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.plans import build_profile, load_plan
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fx = load_fixture('three_axis')
    grade = load_grade('nav_grade')
    sim = simulate(fx, build_profile(load_plan('demo_short'), fx), grade,
                   SimConfig(imu_rate_hz=100, seed=4))
    errs, sig, fixed, extra = srt.estimate(sim.imu, sim.joints, fx, grade)
    assumed = srt._grade_sigmas(grade)  # noqa: SLF001 - the method's own prior
    not_est = set(extra['srt']['not_estimated'])
    assert len(extra['srt']['sequences']) < 10 and not_est  # merged: not all determined
    for name, fld, idx in srt.PARAMS:
        v = float(np.asarray(getattr(errs, fld))[idx])
        s = float(np.asarray(getattr(sig, fld))[idx])
        if name in not_est:
            assert v == 0.0 and s == assumed[fld][idx], (name, v, s)
        else:
            assert s <= assumed[fld][idx], (name, s, assumed[fld][idx])
    e = errs.as_vector() - sim.truth.tracked_truth().as_vector()
    s = sig.as_vector()
    assert np.all(np.abs(e[s > 0]) < 4 * s[s > 0])
