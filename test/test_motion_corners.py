"""Corners of the motion: a table whose joint acceleration jumps (a trapezoidal rate profile)
steps the specific force of a point off its axes by ``alpha x r``; a point sample cannot say
where in its interval the step fell (propagation.corner_variance).

Found by bench/bench_lab.py (a navigation unit at Svalbard, point samples: 10 of 7,500
velocity updates gated at ramp corners, refused). At a lab's 400 deg/s^2 and 9 cm from the
axes the plain command re-aligned after a cascade of gated updates and refused the bag (118 of
6,842 updates gated); with --force its size effect was 17 sigma off.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from imu_calib_ros.cli import main
from imu_calib_ros.core.estimator.buffers import point_to_mean
from imu_calib_ros.core.estimator.propagation import CORNER_SIGMAS, corner_variance
from imu_calib_ros.testing import lab_motion, world_sim
from imu_calib_ros.testing.world_cases import compare_calibration

DT = 0.005


def _step_increment_errors(rng: np.random.Generator, J: float, n: int
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Point samples of a specific force stepping by ``J`` at a uniformly drawn instant of
    interval 10, as trapezoid means: (error of the summed increments, corner variance)."""
    err, var = [], []
    for _ in range(n):
        s = rng.uniform()  # where in interval 10 the step falls
        t = np.arange(21) * DT
        step_t = (9 + s) * DT
        f_pt = np.zeros((21, 3))
        f_pt[:, 0] = np.where(t >= step_t, J, 0.0)
        _, f_m = point_to_mean(np.zeros((21, 3)), f_pt, None)
        true_inc = J * (t[-1] - step_t)
        err.append(f_m[1:, 0].sum() * DT - true_inc)
        v = corner_variance(f_m, np.repeat(np.eye(3)[None], 19, axis=0), np.full(19, DT), 1,
                            19, 1e-4, trapezoid=True)
        assert v is not None
        var.append(v[:, 0].sum())
    return np.array(err), np.array(var)


def test_a_steps_increment_error_is_what_the_corner_variance_says() -> None:
    """Over step instants drawn uniformly, the trapezoid's increment error has the variance
    ``J^2 dt^2 / 12`` that the third differences give (within the sampling spread)."""
    J, n = 0.1, 4000
    err, var = _step_increment_errors(np.random.default_rng(0), J, n)
    assert np.all(var == pytest.approx(J ** 2 * DT ** 2 / 12.0, rel=1e-9))
    # sample variance of a uniform error: relative spread sqrt(0.8 / n) (kurtosis 1.8)
    assert np.mean(err ** 2) == pytest.approx(var[0], rel=4.0 * math.sqrt(0.8 / n))
    assert np.max(np.abs(err)) <= J * DT / 2.0 + 1e-15


def test_point_samples_read_as_means_get_the_same_variance() -> None:
    """The plain command reads point samples as interval means: a step is then a jump of
    one sample (third differences ``J (1, -2, 1)``), and after the half period the latency
    takes up, the increment is off by ``J dt (s - 1/2)``: the same ``J^2 dt^2 / 12``."""
    J = 0.1
    f = np.zeros((21, 3))
    f[10:, 0] = J
    v = corner_variance(f, np.repeat(np.eye(3)[None], 19, axis=0), np.full(19, DT), 1, 19,
                        1e-4)
    assert v is not None and v[:, 0].sum() == pytest.approx(J ** 2 * DT ** 2 / 12.0, rel=1e-9)


def test_smooth_motion_and_noise_add_next_to_nothing() -> None:
    """A quintic move's samples stay under the threshold (no variance); white noise adds
    next to nothing of the velocity variance it brings itself (sigma^2 dt^2 a sample):
    5.7e-7 of its third differences pass 5 sigmas, at ~27 of their variance (20 sigma^2) on
    average, over 12: 2.6e-5 (about 0.3 of the 600,000 here pass); bounded at 1e-3."""
    rng = np.random.default_rng(1)
    sigma_f = 2e-3
    n = 400
    t = np.arange(n) * DT
    tau = t / t[-1]
    rate = 1.0 * (10 * tau ** 3 - 15 * tau ** 4 + 6 * tau ** 5)  # 0 -> 1 rad/s in 2 s
    f = np.column_stack([0.05 * rate, 0.0 * rate, 9.8 + 0.0 * rate])
    R = np.repeat(np.eye(3)[None], n - 2, axis=0)
    dt = np.full(n - 2, DT)
    assert corner_variance(f, R, dt, 1, n - 2, sigma_f) is None
    noise = rng.normal(0, sigma_f, (200_000, 3))
    R_n = np.repeat(np.eye(3)[None], len(noise) - 2, axis=0)
    v = corner_variance(noise, R_n, np.full(len(noise) - 2, DT), 1, len(noise) - 2, sigma_f)
    added = 0.0 if v is None else float(v.sum())
    assert added < 1e-3 * 3 * len(noise) * sigma_f ** 2 * DT ** 2
    f = f + rng.normal(0, sigma_f, (n, 3))
    # a step of 2 x CORNER_SIGMAS x sqrt(20) sigmas is seen
    f[200:, 0] += 2.0 * CORNER_SIGMAS * math.sqrt(20.0) * sigma_f
    v = corner_variance(f, R, np.full(398, DT), 1, 398, sigma_f)
    assert v is not None and v[:, 0].sum() > 1e3 * v[:, 1:].sum()


def test_gravity_turning_fast_through_the_imu_is_not_a_corner() -> None:
    """A turn at 3 rad/s curves the specific force by 9e-3 m/s^2 per sample squared at
    100 Hz (seven navigation-grade sigmas of a second difference: the first version, on second
    differences, widened every fast turn); the trapezoid holds that curvature, and the third
    differences see none of it."""
    dt, n = 0.01, 600
    t = np.arange(n) * dt
    ang = 3.0 * t
    f = np.column_stack([9.8 * np.sin(ang), np.zeros(n), 9.8 * np.cos(ang)])
    R = np.repeat(np.eye(3)[None], n - 2, axis=0)
    sigma_f = 5e-6 * 9.8 / math.sqrt(dt)  # 5 ug/sqrt(Hz)
    assert np.abs(np.diff(f, 2, axis=0)).max() > 7 * math.sqrt(6.0) * sigma_f
    assert corner_variance(f, R, np.full(n - 2, dt), 1, n - 2, sigma_f) is None


def test_the_variance_is_rotated_into_enu() -> None:
    """diag(R diag(v) R^T): a body-x variance lands on the ENU axis body x points along."""
    f = np.zeros((5, 3))
    f[3:, 0] = 1.0
    R = np.repeat(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])[None], 3, 0)
    v = corner_variance(f, R, np.full(3, DT), 1, 3, 1e-4)
    assert v is not None
    assert v[:, 0].sum() == 0.0 and v[:, 1].sum() > 0.0 and v[:, 2].sum() == 0.0


def test_point_samples_on_a_lab_trapezoid_profile(tmp_path: Path, capsys) -> None:
    """A navigation unit on the lab's Svalbard table (IMU 4 cm off the axes, 5 cm more off
    its nominal point), 400 deg/s^2 ramps, point samples at 200 Hz: the plain command
    calibrates it honestly (before: refused, 118 updates gated; with --force the size effect
    17 sigma off, NEES 875 over 45)."""
    rng = np.random.default_rng(1)
    fx = lab_motion.write_fixture('arctic_3axis', tmp_path)
    unit = world_sim.draw_unit('nav', 0.2, rng)
    mounting = world_sim.draw_mounting(3.0, 0.05, rng, min_angle_deg=1.0,
                                       min_offset_m=0.0495)
    profile = lab_motion.lab_schedule(lab_motion.LAB_FIXTURES['arctic_3axis'], 1001,
                                      accel_limit_deg_s2=400.0)
    bag, truth, _ = world_sim.simulate_to_files(
        tmp_path, fx, profile, unit, mounting,
        world_sim.WorldConfig(imu_rate_hz=200.0, sample_type='point'), 1)
    out = tmp_path / 'calib.yaml'
    rc = main(['replay', str(bag), '--fixture', str(fx), '--output', str(out), '--quiet'])
    err = capsys.readouterr().err
    assert rc == 0, err
    rows = [r for r in compare_calibration(yaml.safe_load(out.read_text()),
                                           yaml.safe_load(Path(truth).read_text()))
            if not r.fixed and r.sigma > 0.0]
    z = np.array([r.z for r in rows])
    worst = rows[int(np.argmax(np.abs(z)))]
    assert abs(worst.z) < 4.0, worst
    # the diagonal NEES of an honest filter: below chi^2's 99.9 % point (correlated
    # estimates: the diagonal sum has the same mean, a wider spread; 45 values)
    assert float(np.sum(z ** 2)) < chi2.ppf(0.999, len(z)), float(np.sum(z ** 2))
