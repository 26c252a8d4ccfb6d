"""Issue 11 item 5 for a MEMS unit without a grade: the gyro bias walk chosen by the data.

Real MEMS gyros' in-run walks span a factor 10 around the floor a grade-less run assumes
(``noise.MEMS_BIAS_WALK``); a plan's stationary windows cannot show a 100 s instability. An
offline replay compares whole passes at walks a factor 2 apart by their innovations' negative
log-likelihood and takes the likelihood's one-sided 95 % upper bound
(``replay.profile_gyro_walk``), when that is above the floor. First the search on known
likelihood curves, then units from the world simulator whose walks lie 4x below and 3x above
the floor.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import yaml

from imu_calib_ros.core.estimator import load_estimator_config
from imu_calib_ros.core.estimator.noise import (LIKELIHOOD_SOURCE, MEMS_BIAS_WALK,
                                                MEMS_FLOOR_SOURCE)
from imu_calib_ros.core.estimator.replay import (WALK_PROFILE_RANGE, WALK_PROFILE_RISE,
                                                 profile_gyro_walk, replay_run)
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.testing.world_cases import compare_calibration, make_case
from msg_adapters.bag import iter_bag

FLOOR = MEMS_BIAS_WALK[0]


def _curve(nll: Callable[[float], float], updates: Callable[[float], int] = lambda r: 1000
           ) -> tuple[Callable[[float], tuple[float, int] | None], list[float]]:
    """A known NLL curve as the passes' results (inf: the pass diverged), and the walks asked."""
    asked: list[float] = []

    def nll_at(r: float) -> tuple[float, int] | None:
        asked.append(r)
        v = nll(r)
        return None if math.isinf(v) else (v, updates(r))
    return nll_at, asked


def test_the_bound_is_where_the_likelihood_has_risen_by_the_one_sided_quantile() -> None:
    # NLL linear in log2 r on either side of a minimum at the floor x 2: the crossing is
    # exact under the log-linear interpolation
    assert WALK_PROFILE_RISE == pytest.approx(2.7055 / 2.0, rel=1e-4)  # chi2(0.90, 1) / 2
    best = 2.0 * FLOOR
    slope = 3.0  # nats per factor 2
    nll_at, asked = _curve(lambda r: 100.0 + slope * abs(math.log2(r / best)))
    chosen, profile = profile_gyro_walk(nll_at, FLOOR)
    assert chosen == pytest.approx(best * 2.0 ** (WALK_PROFILE_RISE / slope), rel=1e-9)
    assert sorted(asked) == pytest.approx([FLOOR / 2, FLOOR, 2 * FLOOR, 4 * FLOOR])
    assert [r for r, _ in profile] == sorted(asked) and min(d for _, d in profile) == 0.0


def test_a_flat_likelihood_towards_small_walks_is_followed_to_the_range_end() -> None:
    knee = FLOOR / 4.0
    nll_at, asked = _curve(lambda r: 50.0 + 10.0 * max(0.0, math.log2(r / knee)))
    chosen, _ = profile_gyro_walk(nll_at, FLOOR)
    assert min(asked) >= WALK_PROFILE_RANGE[0] and min(asked) < 2 * WALK_PROFILE_RANGE[0]
    # equal NLLs below the knee: the largest of them is the most likely, the bound its rise
    assert chosen == pytest.approx(knee * 2.0 ** (WALK_PROFILE_RISE / 10.0), rel=1e-9)
    # below the walk the stationary windows showed, the passes would be the same: not asked
    nll_at, asked = _curve(lambda r: 50.0 + 10.0 * max(0.0, math.log2(r / knee)))
    profile_gyro_walk(nll_at, FLOOR, least=FLOOR / 3.0)
    assert min(asked) == FLOOR / 2.0


def test_a_likelihood_that_never_rises_takes_the_range_top() -> None:
    nll_at, asked = _curve(lambda r: 10.0)
    chosen, _ = profile_gyro_walk(nll_at, FLOOR)
    assert chosen == max(asked) and max(asked) * 2 > WALK_PROFILE_RANGE[1]


def test_passes_that_diverged_or_lost_updates_count_as_unlikely() -> None:
    # every pass below 0.01 diverged: the bound comes from the ones that ran
    nll_at, _ = _curve(lambda r: math.inf if r < 0.01 else 20.0 * math.log2(r / 0.01))
    chosen, _ = profile_gyro_walk(nll_at, FLOOR)
    assert 0.011 <= chosen <= 0.022
    # the pass above the most likely diverged: the largest walk that ran, not the diverged one
    nll_at, _ = _curve(lambda r: math.inf if r > 0.03 else 100.0 - math.log2(r))
    chosen, profile = profile_gyro_walk(nll_at, FLOOR)
    assert chosen == FLOOR and math.isinf(profile[-1][1])
    # a small walk that re-aligned (fewer updates, fewer NLL terms, a smaller sum) is not
    # the most likely
    nll_at, _ = _curve(lambda r: 40.0 if r < FLOOR else 100.0 + 10 * math.log2(r / FLOOR),
                       updates=lambda r: 900 if r < FLOOR else 1000)
    chosen, _ = profile_gyro_walk(nll_at, FLOOR)
    assert chosen == pytest.approx(FLOOR * 2.0 ** (WALK_PROFILE_RISE / 10.0), rel=1e-9)
    nll_at, _ = _curve(lambda r: math.inf)
    assert profile_gyro_walk(nll_at, FLOOR) == (FLOOR, ())


@pytest.mark.parametrize('walk', [FLOOR / 4.0, FLOOR * 3.0])
def test_the_data_raise_the_walk_of_a_drifting_unit_and_keep_the_floor_for_a_steady_one(
        tmp_path: Path, walk: float) -> None:
    """A consumer unit whose gyro bias is a 100 s Gauss-Markov process of walk ``walk`` x its
    white noise: the likelihood's bound falls on the same side of the floor as the truth; the
    drifting unit's walk is raised to it, the steady unit keeps the floor (never lowered:
    a random walk's likelihood under-rates a Gauss-Markov instability), the file says which,
    and the gyro biases are within 3 sigma (with the floor alone, the drifting unit's sigmas
    rest on a walk 3x too small)."""
    n_g = 3e-4
    tau = 100.0
    bag, truth = make_case(tmp_path, unit='consumer_mems', seed=4, plan='savage_srt',
                           unit_noise={'gyro_noise_rad_s_rt_hz': n_g,
                                       'gyro_bias_instability_rad_s':
                                           walk * n_g * math.sqrt(tau / 2.0),
                                       'gyro_bias_correlation_s': tau,
                                       'gyro_bias_random_walk_rad_s2_rt_hz': 0.0})
    run = replay_run(lambda: iter_bag(bag), load_fixture(str(truth.fixture_path)), None,
                     load_estimator_config(None))
    calib = run.estimator.estimate()
    bw = calib.extra['estimator']['bias_walk']
    bound = bw['gyro_walk_likelihood_bound_per_s']
    assert (bound < FLOOR) == (walk < FLOOR), (bound, walk, bw['gyro_walk_profile'])
    if walk > FLOOR:
        assert bw['gyro_source'] in (LIKELIHOOD_SOURCE, "raised by the run's data"), bw
        assert bw['gyro_walk_to_noise_per_s'] == bound
    else:
        assert bw['gyro_source'] in (MEMS_FLOOR_SOURCE, "raised by the run's data"), bw
        assert bw['gyro_walk_to_noise_per_s'] == FLOOR
    out = tmp_path / 'calib.yaml'
    calib.save(out)
    rows = [r for r in compare_calibration(yaml.safe_load(out.read_text()),
                                           yaml.safe_load(truth.path.read_text()))
            if r.group == 'gyro_bias']
    z = np.array([r.z for r in rows])
    assert np.abs(z).max() < 3.0, [(r.name, r.error, r.sigma) for r in rows]
