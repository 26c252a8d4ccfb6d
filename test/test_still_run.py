"""The stationary window the filter aligns on (``alignment.still_run``) at any joint rate.

A run of joint samples that each move less than the stationary tolerance (1e-4 rad) from the
previous one is rest only at low rates: at 1 kHz a table at 0.1 rad/s moves 1e-4 rad per
sample. A world bag whose plan starts in motion, with joint states at 1 kHz, was aligned on
the last half second of its first move (the IMU read 0.0095 rad/s), and a navigation unit's
g-sensitivity came out 8.7 sigma off (bench_corners ``nav_joints1000@srt3``); at 250 Hz the
same bag passed. The window is now the first 2 s in which every joint stays within the
tolerance of its mean, judged on that window's samples alone: the same window whether the
samples came in 50 ms pushes (the live node) or in one batch (replay).
"""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core.estimator.alignment import still_run

TOL = 1e-4


def _record(rate_hz: float, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """A move that slows down into rest (exponential approach, 0.4 s time constant, from
    0.5 rad/s), then 6 s at rest; encoder noise 2 urad. Returns stamps, angles (n, 2) and the
    instant from which the angle stays within TOL / 2 of its rest value."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 9.0, 1.0 / rate_hz)
    tau = 0.4
    q1 = 1.0 - 0.5 * tau * np.exp(-t / tau)
    settled = -tau * np.log((TOL / 2) / (0.5 * tau))
    q = np.column_stack([q1, np.full_like(t, 0.3)]) + rng.normal(0.0, 2e-6, (len(t), 2))
    return (t * 1e9).astype(np.int64), q, settled


@pytest.mark.parametrize('rate_hz', [10.0, 100.0, 250.0, 1000.0])
def test_the_alignment_window_is_at_rest_whatever_the_joint_rate(rate_hz: float) -> None:
    jt, jq, settled = _record(rate_hz, 1)
    start, stop = still_run(jt, jq, int(2e9), TOL)
    assert stop is not None
    rest = jq[-1]
    window = jq[start:stop + 1]
    # every sample of the window within the tolerance of the window's mean, so within twice
    # it of the rest position: the step test alone started it where the table still turned
    # at up to TOL x rate (at 1 kHz 14 mrad from rest)
    assert np.abs(window - window.mean(axis=0)).max() <= TOL
    assert np.abs(window - rest).max() <= 2 * TOL, np.abs(window - rest).max()
    assert jt[start] * 1e-9 >= settled - 0.5
    assert (jt[stop] - jt[start]) >= 2e9


@pytest.mark.parametrize('rate_hz, push_s', [(1000.0, 0.05), (100.0, 0.05), (10.0, 0.5),
                                              (1000.0, 1.3)])
def test_the_window_does_not_depend_on_how_the_samples_arrive(rate_hz: float,
                                                               push_s: float) -> None:
    """As the estimator calls it: after each push, on the joint record it kept (from the
    returned start while no window is found), until a window is found. The same window as
    one call on the whole record (a median over the run so far drifted with the pushes: at
    1 kHz in 50 ms pushes it began 0.27 s earlier, in the move's tail, 1.9e-4 rad off)."""
    jt, jq, _ = _record(rate_hz, 3)
    whole = still_run(jt, jq, int(2e9), TOL)
    assert whole[1] is not None
    kept, n, step = 0, 0, max(1, int(round(push_s * rate_hz)))
    while n < len(jt):
        n = min(n + step, len(jt))
        start, stop = still_run(jt[kept:n], jq[kept:n], int(2e9), TOL)
        if stop is not None:
            assert (kept + start, kept + stop) == whole
            return
        kept += start  # what the estimator keeps (keep_from) while it waits
    raise AssertionError('no window in pushes')
