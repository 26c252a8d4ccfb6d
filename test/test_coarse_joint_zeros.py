"""A turntable's encoder zeros and its base's tilt from the stationary windows' gravity
(coarse.fit_joint_zeros): the middle joint's zero of a three-axis table and the tilt of its
base are recovered within their sigmas whatever the accelerometer's raw errors; the outer
(heading) and inner (mounting) zeros are not fitted; a level table without zero errors gets
none."""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core.config import resolve_config_file
from imu_calib_ros.core.estimator.coarse import StaticWindow, fit_joint_zeros
from imu_calib_ros.core.fixture import Fixture

DT, N, NOISE_A = 0.01, 1000, 1e-3  # 10 s windows at 100 Hz, 100 ug/sqrt(Hz)


def windows(zero: np.ndarray, rng: np.random.Generator, tilt: tuple[float, float] = (0.0, 0.0)
            ) -> tuple[list[StaticWindow], Fixture]:
    fx = Fixture.from_yaml(resolve_config_file('three_axis', 'fixtures'))
    true = fx.with_base_tilt(tilt)
    # raw accelerometer errors: scale/misalignment 1 %, bias 10 mg
    A = np.eye(3) + rng.normal(0.0, 0.01, (3, 3))
    b = rng.normal(0.0, 0.1, 3)
    g = np.array([0.0, 0.0, fx.site.gravity])
    out = []
    for k in range(24):  # the poses of a plan: every joint at multiples of 90 deg
        q = np.radians(90.0 * rng.integers(0, 4, 3))
        R = true.R_enu_imu(q + zero)
        f = A @ (R.T @ g) + b + rng.normal(0.0, NOISE_A / np.sqrt(N * DT), 3)
        out.append(StaticWindow(k * 20_000_000_000, k * 20_000_000_000 + 10_000_000_000,
                                q, np.zeros(3), f, N))
    return out, fx


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_the_middle_zero_is_recovered(seed: int) -> None:
    rng = np.random.default_rng(seed)
    zero = np.array([4e-3, -3e-3, 2e-3])
    wins, fx = windows(zero, rng)
    z, s, t, ts = fit_joint_zeros(fx, wins, NOISE_A, DT)
    assert np.all(t == 0.0), (t, ts)  # a level base
    assert abs(z[1] - zero[1]) < 4 * s[1] and s[1] < 1e-4, (z, s)
    assert z[0] == 0.0 and z[2] == 0.0  # heading (outer) and mounting (inner): not gravity's


def test_no_zero_error_gives_none() -> None:
    for seed in range(10):
        wins, fx = windows(np.zeros(3), np.random.default_rng(100 + seed))
        z, s, t, ts = fit_joint_zeros(fx, wins, NOISE_A, DT)
        # 3 sigma: 0.27 % per value and seed by chance
        assert np.all(z == 0.0) and np.all(t == 0.0), (seed, z, s, t, ts)


def test_too_few_windows_leave_the_zeros_unknown_not_absent() -> None:
    """On fewer than six windows the zeros are not fitted, and their sigma is the prior's (a
    start is then not determined: CoarseStart.determined), not inf (which means "gravity does
    not show this zero" and let a start on three windows go with 4.4 mrad of zeros unfitted)."""
    from imu_calib_ros.core.estimator.coarse import BASE_TILT_PRIOR_RAD, JOINT_ZERO_PRIOR_RAD
    wins, fx = windows(np.array([4e-3, -3e-3, 2e-3]), np.random.default_rng(4))
    z, s, t, ts = fit_joint_zeros(fx, wins[:5], NOISE_A, DT)
    assert np.all(z == 0.0) and np.all(t == 0.0)
    assert np.all(s[:2] == JOINT_ZERO_PRIOR_RAD) and np.isinf(s[2])  # the last: the mounting
    assert np.all(ts == BASE_TILT_PRIOR_RAD)
    z, s, t, ts = fit_joint_zeros(fx, wins, NOISE_A, DT)
    assert s[1] < 1e-4  # enough windows: the middle zero is fitted


@pytest.mark.parametrize('seed,tilt', [(5, (1e-3, -2e-3)), (6, (-1.5e-2, 4e-3)), (7, (2e-4, 0.0))])
def test_a_base_off_level_is_recovered_with_the_zeros(seed: int, tilt: tuple[float, float]
                                                      ) -> None:
    """A base 0.2-16 mrad off level (a levelled rate table to a desk): its tilt about east
    and north within 4 of its sigmas (0.04-0.15 mrad on these windows), the middle
    zero still within 4 of its own."""
    rng = np.random.default_rng(seed)
    zero = np.array([4e-3, -3e-3, 2e-3])
    wins, fx = windows(zero, rng, tilt)
    z, s, t, ts = fit_joint_zeros(fx, wins, NOISE_A, DT)
    assert np.all(np.abs(t - np.array(tilt)) < 4 * ts) and np.all(ts < 5e-4), (t, ts)
    assert abs(z[1] - zero[1]) < 4 * s[1], (z, s)


def test_a_tilt_about_a_horizontal_outer_axis_is_that_joints_zero() -> None:
    """A table whose outer axis points north (other axis orders: roll, pitch, yaw): a tilt
    about north is a zero error of the outer joint, fitted as such, and the tilt about east
    as a tilt. Fitted as two things, each cancelled the other's significance and neither was
    applied (a lab's navigation run: accel_scale 5.2 sigma off). The fitted zeros and tilt
    put every window's attitude within 0.02 mrad of the truth."""
    fx = Fixture.from_dict({
        'site': {'latitude_deg': -33.87, 'height_m': 40.0},
        'joints': [{'name': 'roll', 'axis': [0.0, 1.0, 0.0]},
                   {'name': 'pitch', 'axis': [0.0, 0.0, 1.0]},
                   {'name': 'yaw', 'axis': [1.0, 0.0, 0.0]}],
        'imu': {'rpy_deg': [180.0, 0.0, 90.0], 'xyz_m': [0.0, 0.0, 0.0]}})
    rng = np.random.default_rng(8)
    zero, tilt = np.array([4e-3, -3e-3, 2e-3]), (0.3e-3, 1.8e-3)
    true = fx.with_base_tilt(tilt)
    g = np.array([0.0, 0.0, fx.site.gravity])
    wins = []
    for k in range(24):
        q = np.radians(90.0 * rng.integers(0, 4, 3))
        f = true.R_enu_imu(q + zero).T @ g + rng.normal(0.0, NOISE_A / np.sqrt(N * DT), 3)
        wins.append(StaticWindow(k * 20_000_000_000, k * 20_000_000_000 + 10_000_000_000,
                                 q, np.zeros(3), f, N))
    z, s, t, ts = fit_joint_zeros(fx, wins, NOISE_A, DT)
    assert t[1] == 0.0 and np.isinf(ts[1])  # about north: the outer joint's zero
    assert abs(t[0] - tilt[0]) < 4 * ts[0]
    fitted = fx.with_base_tilt(t)
    for w in wins:  # the mounting (the last joint's zero) aside: gravity's directions
        d = fitted.R_enu_imu(w.q_rad + z).T @ g - true.R_enu_imu(w.q_rad + zero).T @ g
        d_mount = np.cross(fitted.joint_axes_imu(w.q_rad + z)[2], true.R_enu_imu(
            w.q_rad + zero).T @ g)
        resid = d - d_mount * (d @ d_mount) / max(d_mount @ d_mount, 1e-30)
        assert np.linalg.norm(resid) / fx.site.gravity < 2e-5
