"""The coarse start's joint record: groups of joint states long enough for scattered stamps.

:func:`~imu_calib_ros.core.estimator.coarse.thin_joint_states` averages joint states faster
than 100 Hz in groups. Stamps taken on receipt that the joint clock could not put back (1 kHz
joint states 0-4.8 ms late with drops: its counting gave up) scatter about their instants;
the spline's rates through 10 ms groups then carried ~3 % of the rates in timing noise, and
the plain command refused the fixture ("the gyro rates do not follow ..."). With the stamps'
scatter given, each group is long enough that its mean stamp's scatter is at most
``JOINT_RATE_TIMING_SHARE`` of a rate over the group.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import CubicSpline

from imu_calib_ros.core.estimator.coarse import (JOINT_RATE_TIMING_SHARE, thin_joint_states)


def _rates_error(timing_sigma_s: float, seed: int = 3) -> float:
    """rms error of the spline's joint rate (relative to the rate's rms) through 1 kHz joint
    states stamped U(0, 4.8 ms) late, kept increasing, 3 % dropped, on a 0.5 Hz sine of
    1 rad (a table swinging at up to 3.1 rad/s)."""
    rng = np.random.default_rng(seed)
    n = 60_000
    t_true = np.arange(n) * 1e-3
    q = np.sin(2 * math.pi * 0.5 * t_true)[:, None]
    late = t_true + rng.uniform(0.0, 4.8e-3, n)
    us = np.arange(n) * 1e-6
    stamps = np.maximum.accumulate(late - us) + us
    keep = rng.random(n) > 0.03
    t_ns = np.round(stamps[keep] * 1e9).astype(np.int64)
    tb, qb = thin_joint_states(t_ns, q[keep], timing_sigma_s=timing_sigma_s)
    sp = CubicSpline(tb * 1e-9, qb, axis=0)
    t_eval = np.linspace(1.0, 59.0, 20_000)
    lag = float(np.mean(stamps[keep] - t_true[keep]))  # the mean delay: a latency, measured
    rate = 2 * math.pi * 0.5 * np.cos(2 * math.pi * 0.5 * (t_eval - lag))
    err = sp(t_eval, 1)[:, 0] - rate
    return float(np.sqrt(np.mean(err ** 2)) / np.sqrt(np.mean(rate ** 2)))


def test_scattered_joint_stamps_are_grouped_by_their_scatter() -> None:
    """The stamps' own scatter (the intervals' std / sqrt 2, what the joint clock reports):
    the rates' error falls from several per cent (10 ms groups) to about the share the
    grouping is for (x2: the groups' means are correlated by the increasing stamps, and the
    spline's derivative mixes neighbours); a regular stream (no scatter) keeps its 10 ms
    groups, as before."""
    rng = np.random.default_rng(3)
    late = rng.uniform(0.0, 4.8e-3, 60_000) + np.arange(60_000) * 1e-3
    sigma = float(np.std(np.diff(np.maximum.accumulate(late)))) / math.sqrt(2.0)
    before, after = _rates_error(0.0), _rates_error(sigma)
    assert before > 0.02
    assert after < 2.0 * JOINT_RATE_TIMING_SHARE
    t = np.arange(1000, dtype=np.int64) * 1_000_000
    tb, _ = thin_joint_states(t, np.zeros((1000, 1)))
    assert len(tb) == 100
