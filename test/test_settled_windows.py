"""Stationary windows cut to where the gyros show rest (``coarse.settled``, session 22).

A window is still when every joint stays within a tolerance, and the tolerance rises with the
encoders' own noise (six sigmas: 1.2 mrad at 0.2 mrad of noise). The last 1.2 mrad of a
move then reads as rest: on srt_then_kozlov the windows took 0.1-0.4 s of the moves' tails,
up to 0.24 mrad of rotation inside a 10 s window, several deg/h in a navigation gyro's mean,
and the self-check refused a calibration within 1.3 sigma of the truth (windows' chi2/dof
7.5). The gyros see those tails (a navigation gyro's 0.1 s mean is good to 2e-6 rad/s), so
a window's leading and trailing 0.1 s bins that stand out from its median (6 sigmas) are
cut, for the coarse start's windows and the self-check's alike.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imu_calib_ros.core.estimator.coarse import settled, static_windows


def test_a_tail_is_cut_and_rest_is_kept() -> None:
    """A decaying rate over the first 0.4 s (12 noise sigmas halving each 0.1 s) is cut past
    its first bin with one bin of margin in each of 2000 noise draws; the same windows
    without it keep every bin but in a few (a bin standing out at rest: 6 sigmas against a
    MAD read off 100 bins, ~1e-4 a window; 5 sigmas cut 17 of 3000 such windows)."""
    rng = np.random.default_rng(4)
    sigma = 1e-6
    tail = 12 * sigma * 0.5 ** np.arange(4)
    rest_cut = 0
    for _ in range(2000):
        g = rng.normal(0.0, sigma, (100, 3))
        rest_cut += settled(g) != (0, 100)
        g[:4, 2] += tail
        lo, hi = settled(g)
        assert lo >= 2 and hi >= 99, (lo, hi)
    assert rest_cut <= 5


def test_a_ringing_tail_and_long_tails() -> None:
    """A tail that rings (its first bin crosses zero) is cut to its last standing-out bin,
    not kept whole; tails on both sides that leave less than half the window are cut all the
    same (the caller's least length drops what is left, instead of keeping the tails)."""
    rng = np.random.default_rng(0)
    g = rng.normal(0.0, 1e-6, (100, 3))
    g[:5, 2] += np.array([0, -20, 15, -8, 6]) * 1e-6
    assert settled(g)[0] >= 5
    g = rng.normal(0.0, 1.0, (10, 3))
    g[:2] += 50.0
    g[-2:] += 50.0
    assert settled(g) == (3, 7)


def test_quantised_rest_is_kept() -> None:
    """Gyro bins on a lattice (0.3 steps of noise: most bins on the median, the MAD zero):
    one step off is no motion (the MAD alone cut 66 % of such windows)."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        assert settled(np.round(rng.normal(0.0, 0.3, (100, 3))) * 1e-3) == (0, 100)


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


def test_the_ledgers_windows_are_cut_alike() -> None:
    """The self-check's windows (``RunLedger.windows``, pushed in chunks as a live run
    would) hold no creep the joints cannot see: every 20 s a 2 s move, then 0.6 s creeping
    80 urad (within the 0.1 mrad tolerance), then rest. The gyro shows the creep
    (1.3e-4 rad/s against 3e-6 of noise in a 0.1 s bin): every window starts after it, as
    ``static_windows``' do on the same record."""
    from dataclasses import dataclass
    from typing import Any

    from imu_calib_ros.core.estimator.config import EstimatorConfig
    from imu_calib_ros.core.estimator.run_ledger import RunLedger
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.types import ImuBatch, JointBatch

    @dataclass
    class _Est:
        fixture: Any
        config: EstimatorConfig
        is_running: bool = False

        @property
        def still_tolerance_rad(self) -> float:
            return self.config.stationary_joint_tolerance_rad

    fx = load_fixture('three_axis')
    rate = 100.0
    ts = np.arange(int(120 * rate)) / rate
    ph = ts % 20.0
    cycle = np.floor(ts / 20.0)
    move = np.clip(ph / 2.0, 0.0, 1.0)
    move = 0.5 * (move - np.sin(2 * np.pi * move) / (2 * np.pi))  # 0.5 rad, smooth
    creep = 8e-5 * np.clip((ph - 2.0) / 0.6, 0.0, 1.0)
    q0 = 0.5 * cycle + move + creep
    q = np.column_stack([q0, np.zeros_like(ts), np.zeros_like(ts)])
    rng = np.random.default_rng(7)
    w = np.zeros((len(ts), 3))
    w[:, 2] = np.gradient(q0, ts)
    w += rng.normal(0.0, 1e-6 * np.sqrt(rate), w.shape)
    f = np.tile([0.0, 0.0, 9.8], (len(ts), 1)) + rng.normal(0.0, 1e-4, (len(ts), 3))
    t = (ts * 1e9).astype(np.int64) + 10 ** 18
    led = RunLedger(_Est(fx, EstimatorConfig()))
    for k in range(0, len(ts), 700):
        sl = slice(k, k + 700)
        led.joints(JointBatch(t[sl][::2], tuple(fx.joint_names), q[sl][::2]))
        led.imu(ImuBatch(t[sl], w[sl], f[sl]))
    def creep_end(t0: int) -> int:  # the end of the creep before a window starting at t0
        return 10 ** 18 + int((np.floor((t0 - 10 ** 18) * 1e-9 / 20.0) * 20.0 + 2.6) * 1e9)
    wins = led.windows()
    assert len(wins) >= 4
    assert all(x[0] >= creep_end(x[0]) for x in wins), [(x[0] - 10 ** 18) * 1e-9 for x in wins]
    coarse = static_windows(t[::2], q[::2], t, w, f, 1.0, 1e-4)
    assert len(coarse) >= 4 and all(x.t0_ns >= creep_end(x.t0_ns) for x in coarse)
