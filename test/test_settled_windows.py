"""Stationary windows cut to where the gyros show rest (``coarse.settled``, session 22).

A window is still when every joint stays within a tolerance, and the tolerance rises with the
encoders' own noise (six sigmas: 1.2 mrad at 0.2 mrad of noise). The last 1.2 mrad of a
move then reads as rest: on srt_then_kozlov the windows took 0.1-0.4 s of the moves' tails,
up to 0.24 mrad of rotation inside a 10 s window, several deg/h in a navigation gyro's mean,
and the self-check refused a calibration within 1.3 sigma of the truth (windows' chi2/dof
7.5). The gyros see those tails (a navigation gyro's 0.1 s mean is good to 2e-6 rad/s), so
a window's leading and trailing 0.1 s bins that stand out from its median are cut, for the
coarse start's windows and the self-check's alike.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imu_calib_ros.core.estimator.coarse import SETTLE_SIGMAS, settled, static_windows


def test_a_tail_is_cut_and_rest_is_kept() -> None:
    """A decaying rate over the first 0.4 s (12 noise sigmas halving each 0.1 s) is cut, one
    bin of margin included, so that what is left of it in the window's mean is under half
    the mean's own noise, in each of 2000 noise draws; the same windows without the tail
    keep every bin (a standing-out end bin at rest: 3 x 5.7e-7 a bin at 5 sigmas)."""
    rng = np.random.default_rng(4)
    sigma = 1e-6
    tail = 12 * sigma * 0.5 ** np.arange(4)
    for _ in range(2000):
        g = rng.normal(0.0, sigma, (100, 3))
        assert settled(g) == (0, 100)
        g[:4, 2] += tail
        lo, hi = settled(g)
        assert lo >= 2 and hi == 100
        assert tail[lo:].sum() / (hi - lo) < 0.5 * sigma / np.sqrt(hi - lo)
    assert SETTLE_SIGMAS == 5.0


def test_short_windows_are_left_alone() -> None:
    """Fewer than five bins give no median to judge by."""
    assert settled(np.ones((4, 3))) == (0, 4)


@pytest.mark.parametrize('encoder_noise_rad', [2e-4])
def test_coarse_windows_hold_no_move_tail(tmp_path: Path, encoder_noise_rad: float) -> None:
    """A world bag with 0.2 mrad of encoder noise (tolerance 1.2 mrad): every coarse
    stationary window lies where the same plan's noise-free joint record stands still
    (within 1 urad); before, windows took up to 0.24 mrad of the moves."""
    from msg_adapters.bag import read_bag

    from imu_calib_ros.core.estimator.alignment import still_tolerance_rad
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.testing.world_cases import make_case
    kw = dict(unit='nav', size=1.0, mount_deg=3.0, seed=81, plan='demo_short')
    bag, truth = make_case(tmp_path / 'noisy', encoder_noise_rad=encoder_noise_rad, **kw)
    clean, _ = make_case(tmp_path / 'clean', encoder_noise_rad=0.0, noise=False, **kw)
    fx = load_fixture(str(truth.fixture_path))
    imu, js = read_bag(bag)
    _, js0 = read_bag(clean)
    order = [js.names.index(n) for n in fx.joint_names]
    q = np.unwrap(js.positions_rad[:, order], axis=0)
    q0 = np.unwrap(js0.positions_rad[:, order], axis=0)
    tol = still_tolerance_rad(js.stamps_ns, q, 2.0, 1e-4)
    assert tol > 1e-3  # the raised tolerance this is about
    wins = static_windows(js.stamps_ns, q, imu.stamps_ns, imu.gyro_rad_s, imu.accel_m_s2,
                          1.0, tol)
    assert len(wins) >= 5
    for win in wins:
        k = (js0.stamps_ns >= win.t0_ns) & (js0.stamps_ns <= win.t1_ns)
        assert np.ptp(q0[k], axis=0).max() < 1e-6, (win.t0_ns, np.ptp(q0[k], axis=0))
