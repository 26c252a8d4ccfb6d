"""The estimator's history (issue 12): what it records, where the physics says its sigmas
fall, and that it stays small."""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core.estimator import CalibrationEstimator, EstimatorConfig
from imu_calib_ros.core.estimator.ekf import GateCounters
from imu_calib_ros.core.estimator.history import EstimateHistory
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.plans import build_profile, load_plan
from imu_calib_ros.core.simulator import SimConfig, simulate


@pytest.fixture(scope='module')
def nav_est():
    fx = load_fixture('three_axis')
    grade = load_grade('nav_grade')
    sim = simulate(fx, build_profile(load_plan('demo_short'), fx), grade,
                   SimConfig(imu_rate_hz=100.0, seed=1))
    est = CalibrationEstimator(fx, None, EstimatorConfig())
    est.push_joint_batch(sim.joints)
    est.push_imu_batch(sim.imu)
    est.flush()
    return est


def test_history_is_in_the_result_and_ends_at_the_estimate(nav_est) -> None:
    res = nav_est.estimate()
    h = res.extra['history']
    st = nav_est.estimate_state()
    assert h['names'] == list(st.labels)
    assert len(h['t_s']) == len(h['value']) == len(h['sigma']) >= 20
    assert np.all(np.diff(h['t_s']) > 0)
    # the last point is the state at the end of the data (4 significant digits)
    np.testing.assert_allclose(h['value'][-1], st.values, rtol=1e-3, atol=1e-15)
    np.testing.assert_allclose(h['sigma'][-1], np.sqrt(np.diag(st.covariance)), rtol=1e-3)
    # every accepted velocity update of the run is in exactly one interval
    assert sum(h['nis']['velocity']['accepted']) == nav_est.filter_accepted('velocity')
    total = nav_est._filter.counters.nis_sum['velocity']
    assert sum(h['nis']['velocity']['sum']) == pytest.approx(total, rel=1e-3)


def test_gyro_scale_sigma_falls_when_its_axis_is_rotated(nav_est) -> None:
    """demo_short turns the IMU about y first (SRT sequences 1, 1a), then x (2, 2a), then z
    (3, 3a): each gyro's scale sigma leaves its prior in that order, and never rises (no
    process noise on a scale factor)."""
    h = nav_est.estimate().extra['history']
    t = np.asarray(h['t_s'])
    s = np.asarray(h['sigma'])
    col = {a: h['names'].index(f'gyro_scale[{i}]') for i, a in enumerate('xyz')}
    prior = s[0, col['y']]

    def first_below(axis: str) -> float:  # time the sigma first drops to a tenth of its prior
        return float(t[np.argmax(s[:, col[axis]] < prior / 10)])

    assert first_below('y') < first_below('x') < first_below('z')
    at_y = first_below('y')
    assert s[t == at_y, col['z']][0] > 0.9 * prior  # z not yet excited when y is known
    for a in 'xyz':
        assert s[-1, col[a]] < prior / 10
        assert np.all(np.diff(s[:, col[a]]) <= 1e-3 * prior), a


def test_history_stays_small_however_long_the_run() -> None:
    """A day of 5-s blocks: at most max_points points, evenly spaced, the NIS counts all
    kept (thinning merges intervals, it never drops updates)."""
    h = EstimateHistory(period_s=1.0, max_points=64)
    c = GateCounters()
    labels = ('a[0]', 'b[0]')
    for k in range(1, 17281):
        c.accepted['velocity'] = k
        c.nis_sum['velocity'] = 3.0 * k
        h.record(k * 5_000_000_000, labels, np.array([1.0 / k, 2.0]), np.array([1.0, 1.0]),
                 c)
    c.accepted['velocity'] = 17281  # the end of the data: flush() forces a last point
    h.record(17281 * 5_000_000_000, labels, np.array([1.0 / 17281, 2.0]), np.ones(2), c,
             force=True)
    d = h.as_dict()
    assert 32 <= len(d['t_s']) <= 64
    dt = np.diff(d['t_s'])[:-1]
    assert np.ptp(dt) <= 0.05 * dt.mean()  # evenly spaced (to within a few blocks)
    assert sum(d['nis']['velocity']['accepted']) == 17281
    assert d['value'][-1][0] == pytest.approx(1.0 / 17281, rel=1e-3)


def test_a_new_filter_starts_new_nis_baselines() -> None:
    """A restart's fresh GateCounters do not make negative interval counts."""
    h = EstimateHistory(period_s=1.0)
    c1, c2 = GateCounters(), GateCounters()
    c1.accepted['velocity'], c1.nis_sum['velocity'] = 10, 30.0
    h.record(1_000_000_000, ('a',), np.zeros(1), np.ones(1), c1)
    c1.accepted['velocity'], c1.nis_sum['velocity'] = 20, 60.0
    h.record(2_000_000_000, ('a',), np.zeros(1), np.ones(1), c1)
    c2.accepted['velocity'], c2.nis_sum['velocity'] = 4, 12.0
    h.record(3_000_000_000, ('a',), np.zeros(1), np.ones(1), c2)
    d = h.as_dict()
    assert d['nis']['velocity']['accepted'] == [10, 10, 4]
    assert d['nis']['velocity']['sum'] == [30.0, 30.0, 12.0]


def test_innovations_of_a_consistent_run_are_white_and_unit(nav_est) -> None:
    """The normalised innovations per ENU component: over the whole demo_short run (nav
    grade, its own noise measured) their mean is within 3 / sqrt(n) of zero per interval in
    all but a few intervals (1 % of intervals x components expected beyond by chance; 5 %
    allowed: the innovations of a filter are white only to first order) and the rms over the
    run is near 1 (0.8-1.2: the run's velocity NIS per dof is 0.85-1.05)."""
    h = nav_est.estimate().extra['history']['nis']['velocity']
    n = np.asarray(h['accepted'], float)
    mean = np.asarray(h['innovation_mean'])
    rms = np.asarray(h['innovation_rms'])
    use = n > 0
    z = mean[use] * np.sqrt(n[use])[:, None]  # N(0, 1) per interval and component
    assert np.mean(np.abs(z) > 3.0) <= 0.05, z
    total = np.sqrt((rms[use] ** 2 * n[use, None]).sum(axis=0) / n[use].sum())
    assert np.all((0.8 < total) & (total < 1.2)), total
    # the sums behind them are the filter's: the squares add up to the NIS for diagonal S
    # only, so check the count and the shapes
    assert mean.shape == rms.shape == (len(n), 3)


def test_innovation_sums_survive_thinning_and_restarts() -> None:
    """Thinning merges the innovation sums of dropped intervals like the NIS (means are
    re-formed from the merged sums); a restart's fresh counters start new baselines."""
    h = EstimateHistory(period_s=1.0, max_points=4)
    c = GateCounters()
    for k in range(1, 9):
        c.accepted['velocity'] = 2 * k
        c.innov_sum['velocity'] = np.array([2.0 * k, 0.0, -2.0 * k])
        c.innov_sq['velocity'] = np.array([2.0 * k, 8.0 * k, 2.0 * k])
        h.record(k * 1_000_000_000, ('a',), np.zeros(1), np.ones(1), c)
    d = h.as_dict()['nis']['velocity']
    assert sum(d['accepted']) == 16
    for m, r in zip(d['innovation_mean'], d['innovation_rms']):
        assert m == pytest.approx([1.0, 0.0, -1.0])
        assert r == pytest.approx([1.0, 2.0, 1.0])
    c2 = GateCounters()
    c2.accepted['velocity'] = 1
    c2.innov_sum['velocity'] = np.array([0.5, 0.5, 0.5])
    c2.innov_sq['velocity'] = np.array([0.25, 0.25, 0.25])
    h.record(20_000_000_000, ('a',), np.zeros(1), np.ones(1), c2)
    last = h.as_dict()['nis']['velocity']
    assert last['innovation_mean'][-1] == pytest.approx([0.5, 0.5, 0.5])
