"""omega_dot for the size effect over +-5 ms (propagation.OMEGA_DOT_SPAN_S), not neighbours.

Neighbour differences of a 1 kHz industrial MEMS gyro carry 1.1 rad/s^2 of noise, as much as
the table's angular accelerations: the size effect's regressor drowned and its z offsets came
out 5 sigma off (the 1 kHz case of test_robustness_grid.py). The wide difference must be the
exact interval derivative where the neighbour one is (rates quadratic in time), and its noise
must fall by ``2 / ((h + 1) sqrt(h))``.
"""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core.estimator.propagation import _wide_differences, omega_dot_half_span


def _interval_means(t: np.ndarray, a: float, b: float, c: float) -> np.ndarray:
    """Mean of a + b t + c t^2 over each (t[k-1], t[k]] (exact antiderivative)."""
    F = a * t + b * t ** 2 / 2 + c * t ** 3 / 3
    return np.diff(F) / np.diff(t)


def test_half_span_is_one_at_200_hz_and_below() -> None:
    assert [omega_dot_half_span(dt) for dt in (0.01, 0.005, 0.0025, 0.001, 0.0005)] == \
        [1, 1, 2, 5, 10]


@pytest.mark.parametrize('h', [1, 2, 5, 10])
def test_wide_difference_is_the_interval_derivative_of_a_quadratic_rate(h: int) -> None:
    dt, m = 1e-3, 200
    t = np.arange(m + 2 * h + 1) * dt + 0.3
    rates = np.stack([_interval_means(t, a, b, c) for a, b, c in
                      ((0.1, 2.0, -3.0), (0.0, -1.0, 5.0), (1.0, 0.0, 0.5))], axis=1)
    dt_all = np.diff(t[1:])
    wd, fd = _wide_differences(rates, 2 * rates, dt_all, h, m)
    mid = 0.5 * (t[h:h + m] + t[h + 1:h + 1 + m])  # the mid-point of each block interval
    truth = np.stack([b + 2 * c * mid for b, c in ((2.0, -3.0), (-1.0, 5.0), (0.0, 0.5))],
                     axis=1)
    assert np.max(np.abs(wd - truth)) < 1e-6
    assert np.max(np.abs(fd - 2 * truth)) < 2e-6
    if h == 1:  # the neighbour difference, as before
        nb = (rates[2:] - rates[:-2]) / (dt_all[:-1] + dt_all[1:])[:, None]
        assert np.max(np.abs(wd - nb[:m])) < 1e-9


def test_wide_difference_noise_falls_as_predicted() -> None:
    rng = np.random.default_rng(0)
    dt, m, h = 1e-3, 200_000, 5
    x = rng.normal(size=(m + 2 * h, 3))
    wd, _ = _wide_differences(x, x, np.full(m + 2 * h - 1, dt), h, m)
    expected = 2.0 / ((h + 1) * np.sqrt(h)) * (np.sqrt(2) / (2 * dt))
    # the standard deviation of a sample standard deviation over 600,000 values: 0.1 %
    assert np.std(wd) == pytest.approx(expected, rel=0.01)
