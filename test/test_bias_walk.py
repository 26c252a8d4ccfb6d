"""Issue 11 item 5 in the run: the biases' random walk from stationary windows at one pose.

``RunLedger.bias_walk`` pairs the run's stationary windows at the same joint angles (the
compensation is then the same function of the same input, so the calibration's error cancels
in the difference) and fits how their differences grow. Synthetic windows (two poses, 20 s
still, 10 s moves, 100 Hz, 40 min) with a known accelerometer bias process: a random walk is
recovered within the spread of its estimate; a ~100 s Gauss-Markov instability (MEMS), whose
differences saturate, still shows as a walk; white noise alone shows none (the estimate is
t > 3 tested, so a false detection has probability ~1e-3 per group). And what the calibration
file and the command say about the walk the sigmas assumed, and where it came from.
"""
from __future__ import annotations

import math

from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from imu_calib_ros.core.estimator.coarse import CoarseStart
from imu_calib_ros.core.estimator.config import EstimatorConfig
from imu_calib_ros.core.estimator.noise import (MEMS_BIAS_WALK, MEMS_INSTABILITY_CORRELATION_S,
                                                bias_random_walk, bias_walk_sources,
                                                instability_covered)
from imu_calib_ros.core.estimator.run_ledger import RunLedger
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.types import ImuBatch, JointBatch

RATE_HZ = 100.0
N_A = 1.5e-3  # accelerometer white noise [m/s^2/sqrt(Hz)] (consumer MEMS)
N_G = 3e-4  # gyro [rad/s/sqrt(Hz)]


@dataclass
class _Est:
    """What the ledger reads of an estimator (a running filter with known white noise)."""

    fixture: Any
    config: EstimatorConfig
    is_running: bool = False
    raised: tuple[float, float] | None = None

    @property
    def still_tolerance_rad(self) -> float:
        return self.config.stationary_joint_tolerance_rad

    def assumed_noise(self) -> tuple[float, float, float, float]:
        return N_G, N_A, 0.0, 0.0

    def raise_bias_walk(self, q_g: float, q_a: float) -> bool:
        self.raised = (q_g, q_a)
        return True


def _run(bias: np.ndarray, seed: int) -> RunLedger:
    fx = load_fixture('three_axis')
    return _feed(RunLedger(_Est(fx, EstimatorConfig())), bias, seed)


def _feed(led: RunLedger, bias: np.ndarray, seed: int) -> RunLedger:
    fx = led.est.fixture
    rng = np.random.default_rng(seed)
    n = len(bias)
    t = (np.arange(n) * 1e9 / RATE_HZ).astype(np.int64) + 10**18
    ts = (t - t[0]) * 1e-9
    # two poses, 20 s still then a 10 s move, over and over
    phase = ts % 60.0
    target = np.where(phase < 30.0, 0.0, 1.0)
    ramp = np.clip((phase % 30.0 - 20.0) / 10.0, 0.0, 1.0)
    s = np.where(phase < 30.0, ramp, 1.0 - ramp)  # 0 at pose A, 1 at pose B
    del target
    q = np.column_stack([s * 0.5, s * 1.0, np.zeros(n)])
    f = np.column_stack([np.zeros(n), np.zeros(n), np.full(n, 9.8)]) + bias[:, None] \
        + rng.normal(0.0, N_A * np.sqrt(RATE_HZ), (n, 3))
    w = rng.normal(0.0, N_G * np.sqrt(RATE_HZ), (n, 3))
    for k in range(0, n, 6000):
        sl = slice(k, k + 6000)
        led.joints(JointBatch(t[sl][::2], tuple(fx.joint_names), q[sl][::2]))
        led.imu(ImuBatch(t[sl], w[sl], f[sl]))
    return led


def test_a_random_walk_is_measured() -> None:
    rng = np.random.default_rng(1)
    n = int(2400 * RATE_HZ)
    q_true = (3e-5) ** 2  # (m/s^2)^2/s: 3 ug/sqrt(s)
    walk = np.cumsum(rng.normal(0.0, np.sqrt(q_true / RATE_HZ), n))
    q_g, q_a, pairs = _run(walk, 2).bias_walk()
    assert pairs > 100
    assert q_g == 0.0  # the gyros had white noise only
    assert q_true / 2.5 < q_a < q_true * 2.5, (q_a, q_true)


def test_a_gauss_markov_instability_shows_as_a_walk() -> None:
    rng = np.random.default_rng(3)
    n = int(2400 * RATE_HZ)
    sigma, tau = 100e-6 * 9.8, 100.0
    a = np.exp(-1.0 / (RATE_HZ * tau))
    e = rng.normal(0.0, sigma * np.sqrt(1 - a * a), n)
    gm = np.zeros(n)
    for k in range(1, n):
        gm[k] = a * gm[k - 1] + e[k]
    _, q_a, _ = _run(gm, 4).bias_walk()
    # no longer than its correlation time the GM grows like a walk of 2 sigma^2 / tau
    assert 0.05 * 2 * sigma ** 2 / tau < q_a < 2 * 2 * sigma ** 2 / tau, q_a


@pytest.mark.parametrize('seed', [5, 6, 7])
def test_white_noise_alone_is_no_walk(seed: int) -> None:
    n = int(2400 * RATE_HZ)
    q_g, q_a, _ = _run(np.zeros(n), seed).bias_walk()
    assert q_g == 0.0 and q_a == 0.0


def test_the_walk_is_handed_to_a_running_estimator_only() -> None:
    rng = np.random.default_rng(8)
    n = int(600 * RATE_HZ)
    led = _run(np.cumsum(rng.normal(0.0, 1e-4 / np.sqrt(RATE_HZ), n)), 9)
    assert led.est.raised is None  # no filter running: nothing handed over
    led.est.is_running = True
    led._walk_checked = None  # the next check is due
    led._check_walk()
    assert led.est.raised is not None and led.est.raised[1] > 0


def test_white_noise_rarely_raises_the_walk_of_a_running_estimator() -> None:
    """The check runs every minute of data while the filter runs, and a raised walk is held
    for the run: the false alarms of all those looks add up. At 2 standard errors (and t > 3
    for the line over a plan's first few windows) white noise raised the walk in 6 % (gyro)
    and 11 % (accelerometer) of 30-min runs (200 runs); now at most 1 %. 60 runs: at most 3
    with a raise (P < 0.3 % at a 1 % rate; the old thresholds raised it in 6 of these 60,
    and their rates give 3 or fewer with P ~ 1 %)."""
    raised = 0
    for seed in range(100, 160):
        fx = load_fixture('three_axis')
        led = RunLedger(_Est(fx, EstimatorConfig(), is_running=True))
        _feed(led, np.zeros(int(1800 * RATE_HZ)), seed)
        raised += led.est.raised is not None
    assert raised <= 3, raised

def _start(n_g: float, n_a: float, walk_g: float = 0.0, walk_a: float = 0.0) -> CoarseStart:
    z = np.zeros(3)
    return CoarseStart(z, z, z, z, z, 0.0, 0.0, 0.0, n_g, n_a, walk_g, walk_a, 8, 600.0)


def test_the_file_says_where_the_bias_walk_came_from() -> None:
    """The walk the sigmas assume, and its source: a grade's Gauss-Markov instability
    (2 sigma^2 / tau), the data's walk where larger, else a unit without a grade gets the
    floors; a navigation gyro (noise below the aiding threshold) none. The instability a
    walk covers inverts the grade's: a MEMS grade's 10 deg/h over 100 s is covered by exactly
    its own walk."""
    mems_threshold = EstimatorConfig().aiding_gyro_noise_rad_s_rt_hz
    mems = _start(1.2e-4, 1.2e-3)
    q_g, q_a = bias_random_walk(None, mems, mems_threshold)
    assert bias_walk_sources(None, mems, mems_threshold) == ('MEMS floor', 'MEMS floor')
    assert math.sqrt(q_g) == pytest.approx(MEMS_BIAS_WALK[0] * 1.2e-4, rel=1e-12)
    assert math.sqrt(q_a) == pytest.approx(MEMS_BIAS_WALK[1] * 1.2e-3, rel=1e-12)
    # the data's walk above the floor wins; below it, the floor stays
    big = _start(1.2e-4, 1.2e-3, 10 * MEMS_BIAS_WALK[0] * 1.2e-4, 0.1 * MEMS_BIAS_WALK[1] * 1.2e-3)
    assert bias_walk_sources(None, big, mems_threshold) == ('stationary windows', 'MEMS floor')
    # a navigation gyro without a grade: no gyro walk assumed, the accelerometer floor
    nav = _start(1e-7, 2e-5)
    assert bias_walk_sources(None, nav, mems_threshold) == ('none', 'accelerometer floor')
    # with a grade: the grade's walk; a 10 deg/h instability over 100 s is what it covers
    grade = load_grade('mems_mti1')
    assert bias_walk_sources(grade, mems, mems_threshold)[0] == 'grade'
    q_grade = bias_random_walk(grade, mems, mems_threshold)[0]
    assert grade.gyro_bias_correlation_s == MEMS_INSTABILITY_CORRELATION_S
    assert instability_covered(q_grade - grade.gyro_bias_random_walk_rad_s2_rt_hz ** 2) == \
        pytest.approx(grade.gyro_bias_instability_rad_s, rel=1e-12)


def test_the_command_names_the_instability_an_assumed_mems_walk_covers() -> None:
    """The note a MEMS unit without a grade gets when no drift showed: 0.022 N per sqrt(s) at
    N = 1.2e-4 rad/s/sqrt(Hz) is 2.64e-6 rad/s/sqrt(s) = 32.7 deg/h/sqrt(h), and covers a
    Gauss-Markov instability of 2.64e-6 sqrt(50) = 1.87e-5 rad/s = 3.85 deg/h over 100 s."""
    from types import SimpleNamespace

    from imu_calib_ros.cli.replay import _walk_note
    q = MEMS_BIAS_WALK[0] * 1.2e-4
    walk = {'gyro_bias_random_walk_rad_s2_rt_hz': q, 'gyro_source': 'MEMS floor',
            'gyro_instability_covered_rad_s': instability_covered(q * q)}
    note = _walk_note(SimpleNamespace(extra={'estimator': {'bias_walk': walk}}))
    assert note is not None and '(33 deg/h/sqrt(h))' in note and 'up to 3.9 deg/h' in note
    for source in ('grade', 'stationary windows', "raised by the run's data"):
        calib = SimpleNamespace(extra={'estimator': {'bias_walk': {**walk,
                                                                   'gyro_source': source}}})
        assert _walk_note(calib) is None
    assert _walk_note(SimpleNamespace(extra={})) is None  # a file from another method


def test_the_command_names_the_walk_the_innovations_chose() -> None:
    """After a replay's walk profile the note gives the walk, the likelihood's bound and the
    passes it compared: raised to 0.05 x 1.2e-4 = 6e-6 rad/s/sqrt(s) = 74 deg/h/sqrt(h),
    covering 6e-6 sqrt(50) = 4.24e-5 rad/s = 8.8 deg/h over 100 s; or the floor kept, when
    the bound is below it, said so without the advice to give a grade."""
    from types import SimpleNamespace

    from imu_calib_ros.cli.replay import _walk_note
    from imu_calib_ros.core.estimator.noise import LIKELIHOOD_SOURCE, MEMS_FLOOR_SOURCE
    profile = [[0.011, 3.0], [0.022, 1.0], [0.044, 0.0], [0.088, 2.5]]
    q = 0.05 * 1.2e-4
    walk = {'gyro_bias_random_walk_rad_s2_rt_hz': q, 'gyro_source': LIKELIHOOD_SOURCE,
            'gyro_instability_covered_rad_s': instability_covered(q * q),
            'gyro_walk_to_noise_per_s': 0.05, 'gyro_walk_likelihood_bound_per_s': 0.05,
            'gyro_walk_profile': profile}
    note = _walk_note(SimpleNamespace(extra={'estimator': {'bias_walk': walk}}))
    assert note is not None, note
    assert 'raised the gyro bias walk above the MEMS floor to 74 deg/h/sqrt(h)' in note, note
    assert 'over 4 passes: 0.05 of the white noise' in note and 'up to 8.8 deg/h' in note
    q = MEMS_BIAS_WALK[0] * 1.2e-4
    walk = {**walk, 'gyro_bias_random_walk_rad_s2_rt_hz': q, 'gyro_source': MEMS_FLOOR_SOURCE,
            'gyro_instability_covered_rad_s': instability_covered(q * q),
            'gyro_walk_to_noise_per_s': MEMS_BIAS_WALK[0],
            'gyro_walk_likelihood_bound_per_s': 0.012}
    note = _walk_note(SimpleNamespace(extra={'estimator': {'bias_walk': walk}}))
    assert note is not None and 'assume the MEMS floor (33 deg/h/sqrt(h)' in note, note
    assert 'ask for no more' in note and '0.012 of the white noise' in note, note
    assert '--imu' not in note


def test_a_walk_profile_with_a_diverged_pass_still_makes_a_calibration_file(tmp_path) -> None:
    """A walk profile's pass that diverged counts as infinitely unlikely
    (``replay.profile_gyro_walk``); the file keeps the passes that ran: with the infinite one
    the calibration file was refused ('gyro_walk_profile[0][1]: value inf is not finite'),
    and the plain command exited 2 on 4 of the grid's runs with receipt-stamped streams."""
    import dataclasses

    from imu_calib_ros.core.calibration import _check_finite
    from imu_calib_ros.core.estimator import CalibrationEstimator
    fx = load_fixture('three_axis')
    est = CalibrationEstimator(fx, None, EstimatorConfig())
    est.start = dataclasses.replace(
        _start(1.2e-4, 1.2e-3), gyro_walk_profile=((0.011, math.inf), (0.022, 0.0),
                                                   (0.044, 2.5)),
        gyro_walk_bound_per_s=0.03)
    walk = est.bias_walk_summary()
    assert walk['gyro_walk_profile'] == [[0.022, 0.0], [0.044, 2.5]]
    _check_finite(walk, None, 'bias_walk')
