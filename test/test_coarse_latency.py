"""Issue 11 item 4: the joint-stamp latency measured without a bias from encoder noise.

The coarse start compares the gyro rate magnitude with the encoder rate magnitude shifted by
the latency. Encoders quantise or jitter at 5-20 urad (a 19-bit encoder: 12 urad); at 100 Hz
the derivative of the interpolated angles then has a noise whose variance depends on where
the shifted instant falls between two joint stamps, which biased the old estimate by 1-3 ms:
a milliradian of attitude at 1 rad/s, ten times the encoder attitude aiding's sigma (MEMS
runs re-aligned 4-10 times and were refused by the self-check). Tolerance: 0.3 ms, i.e.
0.3 mrad at 1 rad/s, three encoder-attitude sigmas (``attitude_sigma_rad`` 1e-4).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imu_calib_ros.core.estimator.coarse import coarse_start
from imu_calib_ros.core.fixture import load_fixture
from msg_adapters.bag import read_bag
from imu_calib_ros.testing.world_cases import make_case

TOL_S = 3e-4


@pytest.mark.parametrize('latency_ms,encoder_noise_rad,joint_rate_hz', [
    (0.0, 13.5e-6, 100.0),   # the grid's refused industrial MEMS run: 1.2-2.5 ms before
    (-29.8, 13e-6, 100.0),
    (17.0, 20e-6, 50.0),
])
def test_latency_unbiased_by_encoder_noise(tmp_path: Path, latency_ms: float,
                                           encoder_noise_rad: float,
                                           joint_rate_hz: float) -> None:
    bag, truth = make_case(tmp_path, unit='industrial_mems', size=0.2, plan='savage_srt',
                           latency_ms=latency_ms, encoder_noise_rad=encoder_noise_rad,
                           joint_rate_hz=joint_rate_hz, joint_velocities=False, seed=0)
    fx = load_fixture(str(truth.fixture_path))
    imu, js = read_bag(bag)
    q = np.unwrap(js.positions_rad[:, [js.names.index(n) for n in fx.joint_names]], axis=0)
    n = 60_000  # what the estimator's readiness check looks at
    keep = js.stamps_ns <= imu.stamps_ns[n - 1] + 1_000_000_000
    st = coarse_start(imu.stamps_ns[:n], imu.gyro_rad_s[:n], imu.accel_m_s2[:n],
                      js.stamps_ns[keep], q[keep], fx)
    assert st.joint_latency_s == pytest.approx(latency_ms * 1e-3, abs=TOL_S)


def test_latency_windows_across_a_gap_are_left_out() -> None:
    """A window mean across a gap stands the sample after it in for the whole gap (CONTRACT 1:
    that sample is the mean over its own nominal period): such windows are not used."""
    from imu_calib_ros.core.estimator.coarse import whole_windows
    dt = 0.01
    t = np.arange(100) * dt
    t[50:] += 0.03  # three samples lost before sample 50
    dtk, i = whole_windows(t, dt, 4, np.arange(100))
    assert dtk[50] == pytest.approx(0.04) and dtk[49] == pytest.approx(dt)
    # windows ending at 50..53 hold the interval into sample 50; 4..49 and 54..99 do not
    assert list(i) == list(range(4, 50)) + list(range(54, 100))
    # a gap every few samples: too few whole windows, all are kept
    t2 = np.cumsum(np.where(np.arange(100) % 3 == 0, 2 * dt, dt))
    assert list(whole_windows(t2, dt, 4, np.arange(100))[1]) == list(range(4, 100))


@pytest.mark.parametrize('unit,size,plan,fixture,encoder_noise_rad,seed', [
    # refused before: latency -3.65 +- 0.13 ms (the industrial unit) and -4.24 +- 0.08 ms
    ('industrial_mems', 0.5, 'savage_srt', 'savage_2axis', 1e-4, 66),
    ('consumer_mems', 1.0, 'demo_short', 'three_axis', 4e-4, 21),
    # the fixed point of gyro fit and refinement crept 0.1-0.6 ms a round on this one
    # (-1.16 +- 0.04 ms after the phases alone)
    ('consumer_mems', 1.0, 'savage_srt', 'savage_2axis', 4e-4, 69),
])
def test_latency_within_its_sigma_on_noisy_encoders(tmp_path: Path, unit: str, size: float,
                                                    plan: str, fixture: str,
                                                    encoder_noise_rad: float,
                                                    seed: int) -> None:
    """Encoders with 0.1-0.4 mrad of noise, IMU and joints at 100 Hz on one clock: the
    window ends' phases spread evenly (``coarse.window_means``), the gyro fit on 0.2 s
    windows without an encoder derivative (``window_rates``), and the refinement's
    Gauss-Newton steered by the gyros' own rate of change (an instrument free of the
    encoders' noise): the latency within 3 of its sigmas of the truth (0) and within 0.5 ms
    (half a milliradian at 1 rad/s, five encoder-attitude sigmas; it was 3.7-4.2 ms off),
    the sigma under 1 ms."""
    from imu_calib_ros.core.estimator.alignment import still_tolerance_rad
    bag, truth = make_case(tmp_path, unit=unit, size=size, mount_deg=3.0, plan=plan,
                           fixture=fixture, encoder_noise_rad=encoder_noise_rad, seed=seed)
    fx = load_fixture(str(truth.fixture_path))
    imu, js = read_bag(bag)
    q = np.unwrap(js.positions_rad[:, [js.names.index(n) for n in fx.joint_names]], axis=0)
    tol = still_tolerance_rad(js.stamps_ns, q, 2.0, 1e-4)
    st = coarse_start(imu.stamps_ns, imu.gyro_rad_s, imu.accel_m_s2, js.stamps_ns, q, fx,
                      tol_rad=tol)
    assert st is not None
    assert abs(st.joint_latency_s) < min(3 * st.joint_latency_sigma_s, 5e-4), (
        st.joint_latency_s, st.joint_latency_sigma_s)
    assert st.joint_latency_sigma_s < 1e-3


def test_window_means_are_the_integral_means() -> None:
    """``window_means`` against the exact mean of a known rate, 1.1 + sin(5 t), over its
    windows (interval means as input, ends at sub-sample phases; the Hermite interpolation
    of the integral with slopes from the neighbouring means: within 2e-6 rad/s here, where
    linear interpolation is off by up to 3e-4), none across a gap, and
    the hand-written Hermite evaluation held to scipy's ``CubicHermiteSpline``."""
    from scipy.interpolate import CubicHermiteSpline

    from imu_calib_ros.core.estimator.coarse import _hermite_at, window_means
    dt = 0.01
    t = np.arange(1, 3001) * dt
    t[1500:] += 0.05  # five samples lost before sample 1500
    F = lambda x: 1.1 * x - np.cos(5 * x) / 5  # noqa: E731  (the rate's integral)
    w = ((F(t) - F(t - dt)) / dt)[:, None] * np.ones((1, 3))
    t_a, t_b, (m,) = window_means(t, dt, np.arange(3000), w)
    exact = (F(t_b) - F(t_a)) / (t_b - t_a)
    np.testing.assert_allclose(m[:, 0], exact, atol=2e-6)
    assert not np.any((t_a < t[1500] - dt) & (t_b > t[1499]))  # none holds the gap
    rng = np.random.default_rng(0)
    nodes = np.cumsum(rng.uniform(0.5, 1.5, 50))
    c, sl = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    x = rng.uniform(nodes[0], nodes[-1], 500)
    np.testing.assert_allclose(_hermite_at(nodes, c, sl, x),
                               CubicHermiteSpline(nodes, c, sl, axis=0)(x), atol=1e-12)
