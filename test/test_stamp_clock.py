"""Stamps taken on receipt, back on the sender's clock (core.stamp_clock.StampClock).

A receipt delay is never negative, so the sender's instants are the lower envelope of the
stamps: what is left of a uniform delay U(0, j) over a window of W samples is its least value
(a constant, ~ j / W) and a spread of the same order. Regular stamps pass bit for bit; a
stream that is not periodic (published on change, delays beyond half a period) passes as
given.
"""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core.stamp_clock import LEARN_SAMPLES, REFIT_SAMPLES, WINDOW, StampClock

START = 1_715_000_000_123_456_789


def _stream(rate_hz: float, jitter_s: float, n: int, seed: int = 0, drop: float = 0.0
            ) -> tuple[np.ndarray, np.ndarray]:
    """(true instants, receipt stamps U(0, jitter) late, increasing) with drops."""
    rng = np.random.default_rng(seed)
    P = int(round(1e9 / rate_hz))
    true = START + np.arange(1, n + 1, dtype=np.int64) * P
    late = true + np.round(rng.uniform(0.0, jitter_s, n) * 1e9).astype(np.int64)
    us = np.arange(n, dtype=np.int64) * 1000
    stamps = np.maximum.accumulate(late - us) + us
    keep = rng.random(n) >= drop
    return true[keep], stamps[keep]


def _run(clock: StampClock, stamps: np.ndarray, batch: int) -> np.ndarray:
    return np.concatenate([clock(stamps[i:i + batch]) for i in range(0, len(stamps), batch)])


@pytest.mark.parametrize('rate_hz,batch', [(200.0, 1), (200.0, 4096), (1000.0 / 3.0, 700)])
def test_regular_stamps_pass_unchanged(rate_hz: float, batch: int) -> None:
    """A sender's own clock (ns-rounded periods of 1/3 kHz, 2 % of the samples dropped)."""
    n = 6000 if batch > 1 else 2500
    true, _ = _stream(rate_hz, 0.0, n, drop=0.02)
    c = StampClock()
    out = _run(c, true, batch)
    assert np.array_equal(out, true)
    assert c.decided and not c.smoothing and not c.irregular


@pytest.mark.parametrize('rate_hz,jitter_s,drop', [(200.0, 2e-3, 0.0), (200.0, 2e-3, 0.02),
                                                   (100.0, 1e-3, 0.05), (1000.0, 0.3e-3, 0.01)])
def test_receipt_stamps_come_back_to_the_senders_clock(rate_hz: float, jitter_s: float,
                                                       drop: float) -> None:
    """After the learning and one window, stamp - instant is what the envelope line leaves:
    its offset at the window's centroid is a minimum of delays (excess ~ j / W over the
    least delay), its slope rests on two such minima half a window apart (~ 4 j / W^2), and
    it is evaluated up to half a window and a refit beyond the centroid: a mean within
    3 j / W, a spread within 5 j / W, and every stamp within 5 ln(refits) j / W (the largest
    of that many exponential-tailed minima); the stamps as given scatter over j (j / sqrt(12)
    rms)."""
    true, stamps = _stream(rate_hz, jitter_s, int(rate_hz * 600), seed=1, drop=drop)
    c = StampClock()
    out = _run(c, stamps, 500)
    # one batch holding the whole record (a bag reader's): the same stamps after the learnt
    # ones (the first version returned the whole batch as given: 58 s of a bag unchanged)
    assert np.array_equal(_run(StampClock(), stamps, len(stamps)), out)
    assert c.smoothing and not c.irregular
    assert c.period_ns == pytest.approx(1e9 / rate_hz, abs=1.0)  # ns: the crystal's period
    settled = slice(LEARN_SAMPLES + WINDOW, None)
    err = (out - true)[settled].astype(float)
    j_ns, scale = jitter_s * 1e9, jitter_s * 1e9 / WINDOW
    assert 0.0 <= err.mean() < 3.0 * scale
    assert err.std() < 5.0 * scale
    refits = len(err) / REFIT_SAMPLES
    assert np.abs(err - err.mean()).max() < 5.0 * np.log(refits) * scale
    assert (stamps - true)[settled].std() == pytest.approx(j_ns / np.sqrt(12.0), rel=0.05)
    assert np.all(np.diff(out) > 0)


def test_streams_that_are_not_periodic_pass_as_given() -> None:
    """Delays beyond half a period (1 kHz, 2 ms) cannot be told from a dropped sample; an
    event-driven publisher (intervals anywhere in 5-15 ms) has no period."""
    _, stamps = _stream(1000.0, 2e-3, 20_000, seed=2)
    c = StampClock()
    assert np.array_equal(_run(c, stamps, 500), stamps) and c.irregular
    rng = np.random.default_rng(3)
    events = START + np.cumsum(rng.integers(5_000_000, 15_000_000, 5000))
    c = StampClock()
    assert np.array_equal(_run(c, events, 300), events) and c.irregular


def test_joint_states_on_change_from_a_regular_controller_pass_unchanged() -> None:
    """Published only while the table turns, on the controller's 100 Hz ticks: regular stamps
    with long silences (many periods at once), not jitter."""
    ticks = START + 10_000_000 * np.arange(20_000, dtype=np.int64)
    moving = (np.arange(20_000) // 1500) % 2 == 0
    c = StampClock()
    assert np.array_equal(_run(c, ticks[moving], 200), ticks[moving]) and not c.smoothing


def test_a_new_time_base_restarts_the_record() -> None:
    """After reset() (a backward time jump: a looping bag), the stamps that follow are mapped
    on the same period from a new start, within the same bounds one window later."""
    true, stamps = _stream(200.0, 2e-3, 30_000, seed=4)
    c = StampClock()
    _run(c, stamps[:15_000], 500)
    c.reset()
    shift = true[15_000] - START  # the recording again from the same start
    out = _run(c, stamps[15_000:] - shift, 500)
    err = (out - (true[15_000:] - shift))[WINDOW:].astype(float)
    scale = 2e6 / WINDOW
    assert c.smoothing
    assert 0.0 <= err.mean() < 3.0 * scale
    assert np.abs(err - err.mean()).max() < 5.0 * np.log(len(err) / REFIT_SAMPLES) * scale
