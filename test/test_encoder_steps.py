"""Quantised table encoders in the self-check's stationary windows (session 21).

An encoder reads whole steps, so a joint at rest is off by up to half a step however long the
window: 0.1 mrad steps (the size of a 16-bit encoder's) leave each pose's attitude 29 urad rms
off, and the gravity a navigation unit sees there 28 ug off, where its 20 s window mean is
good to 1 ug. The windows' chi2 assumed the white noise alone and came out 5.56 per dof,
refusing a navigation calibration within 2.4 sigma of the truth. (Where every pose is a whole
number of steps, as quarter turns are of 2^16 steps per turn, each joint is off by one
constant that its zero takes up.) The step is read from the joint record
(``buffers.encoder_quantum_rad``) and its attitude error enters each window's covariance
(``run_ledger.step_attitude_variance``).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imu_calib_ros.core.fixture import Fixture, load_fixture

STEP_16_BIT = 2 * np.pi / 2 ** 16
#: a step of the same size that a quarter turn is no whole number of (a 62,832-count
#: encoder): each pose of a plan is then off by its own fraction of a step
STEP = 1e-4


def test_the_step_is_read_from_the_record() -> None:
    """Whole steps (an oscillation, a turn starting from rest, dithering at rest) give the
    step; continuous noise gives none (its spacings are no multiples of one step)."""
    from imu_calib_ros.core.estimator.buffers import encoder_quantum_rad
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 10.0, 1001)
    q = np.column_stack([0.3 * np.sin(t), 0.01 * t ** 2, 0.0 * t]) \
        + rng.normal(0.0, 2e-5, (1001, 3))
    steps = np.array([STEP_16_BIT, 4 * STEP_16_BIT, STEP_16_BIT])
    got = encoder_quantum_rad(np.round(q / steps) * steps)
    np.testing.assert_allclose(got, steps, rtol=1e-9)
    assert np.all(encoder_quantum_rad(q) == 0.0)  # no lattice
    assert np.all(encoder_quantum_rad(np.zeros((5, 3))) == 0.0)  # never moved
    assert encoder_quantum_rad(np.zeros(0)).shape == (1,)  # one joint, no samples
    # a wrapped 16-bit encoder turning for 24 rad, its record unwrapped by whole turns (2 pi
    # is no whole number of its steps): read on the wrapped angles; the visited angles are
    # 8 steps apart or more, and the step is the largest fraction of that they all share
    t2 = np.linspace(0.0, 60.0, 6001)
    wrapped = np.round((np.mod(0.4 * t2 + np.pi, 2 * np.pi) - np.pi) / STEP_16_BIT) * STEP_16_BIT
    np.testing.assert_allclose(encoder_quantum_rad(np.unwrap(wrapped)), [STEP_16_BIT],
                               rtol=1e-9)


def test_step_attitude_variance_by_hand() -> None:
    """One joint about IMU x at rest with gravity along IMU z: ``dtheta x f`` has only a y
    component, ``-g dtheta_x``: variance ``g^2 step^2 / 12`` on y, none on x and z."""
    from imu_calib_ros.core.estimator.run_ledger import step_attitude_variance
    fx = Fixture.from_dict({'site': {'latitude_deg': 45.0, 'height_m': 0.0},
                            'joints': [{'name': 'a', 'axis': [1.0, 0.0, 0.0]}],
                            'imu': {'rpy_deg': [0.0, 0.0, 0.0], 'xyz_m': [0.0, 0.0, 0.0]}})
    g = 9.8
    var = step_attitude_variance(fx, np.zeros((2, 1)), np.array([[0.0, 0.0, g]] * 2),
                                 np.array([1e-4 ** 2 / 12]))
    np.testing.assert_allclose(var, [[0.0, g ** 2 * 1e-8 / 12, 0.0]] * 2, rtol=1e-12,
                               atol=1e-24)


@pytest.mark.parametrize('seed', [31])
def test_plain_command_on_a_table_with_coarse_steps(tmp_path: Path, seed: int) -> None:
    """A navigation unit's world bag with the joint states rounded to 0.1 mrad steps (and no
    velocities, as an encoder count gives none): exit 0,
    every estimated parameter within 4 sigma (refused before: windows' chi2/dof 5.56)."""
    from imu_calib_ros.testing.world_cases import plain_command_worst
    # (with 2^16 steps per turn the plan's poses, quarter turns apart, are whole steps:
    # one constant error per joint, which the joints' zeros take up)
    bag, truth = _stepped(tmp_path, STEP, 'nav', seed)
    rc, err, worst = plain_command_worst(bag, truth.fixture_path, truth.data,
                                         tmp_path / 'c.yaml')
    assert rc == 0 and worst is not None, err
    assert abs(worst.z) < 4.0, (worst.name, worst.z)


def _stepped(tmp_path: Path, step: float, unit: str, seed: int) -> tuple[Path, Any]:
    """A world bag (demo_short) whose joint positions are rounded to ``step`` [rad], without
    velocities (an encoder count gives none): (bag, truth)."""
    from msg_adapters.bag import read_bag, write_bag

    from imu_calib_ros.testing.world_cases import make_case
    bag, truth = make_case(tmp_path, unit=unit, size=1.0, mount_deg=3.0, seed=seed)
    imu, joints = read_bag(bag)
    joints.positions_rad[:] = np.round(joints.positions_rad / step) * step
    joints = dataclasses.replace(joints, velocities_rad_s=None)
    out = tmp_path / 'steps.mcap'
    write_bag(out, imu, joints)
    return out, truth


def test_plain_command_with_14_bit_steps(tmp_path: Path) -> None:
    """0.38 mrad steps (14 bits a turn) under a navigation unit: exit 0, every estimated
    parameter within 4 sigma. Refused until session 22: the coarse start's rate fit, on
    derivatives of the stepped record, left 2 % of the rates unexplained (against 2 % of the
    rates allowed); it now fits 0.2 s window rotations and allows for the encoders' own
    rate noise (``coarse.encoder_rate_noise``)."""
    from imu_calib_ros.testing.world_cases import plain_command_worst
    bag, truth = _stepped(tmp_path, 2 * np.pi / 2 ** 14, 'nav', 31)
    rc, err, worst = plain_command_worst(bag, truth.fixture_path, truth.data,
                                         tmp_path / 'c.yaml')
    assert rc == 0 and worst is not None, err
    assert abs(worst.z) < 4.0, (worst.name, worst.z)


def test_12_bit_steps_are_named_in_the_refusal(tmp_path: Path) -> None:
    """1.53 mrad steps (12 bits a turn) under a tactical unit: refused (updates gated in
    the turns), and the one line names the encoders' steps beside the failed check
    (``RunLedger.encoder_hint``: before, only the gated updates were named)."""
    from imu_calib_ros.testing.world_cases import plain_command_worst
    bag, truth = _stepped(tmp_path, 2 * np.pi / 2 ** 12, 'tactical', 37)
    out = tmp_path / 'c.yaml'
    rc, err, _ = plain_command_worst(bag, truth.fixture_path, truth.data, out)
    lines = err.strip().splitlines()
    assert rc == 3 and not out.exists() and len(lines) == 1, lines
    assert 'the joint encoders read 1.53 mrad steps' in lines[0], lines


def test_the_encoder_clause() -> None:
    """One wording for the coarse start's rate-fit line and the self-check's refusal: steps
    and noise named only past what the plain command is checked on."""
    from imu_calib_ros.core.estimator.buffers import (ENCODER_NOISE_CHECKED_RAD,
                                                      ENCODER_STEP_CHECKED_RAD, encoder_clause)
    assert encoder_clause(ENCODER_NOISE_CHECKED_RAD, ENCODER_STEP_CHECKED_RAD) == ''
    both = encoder_clause(1e-3, 1.5e-3)
    assert both.startswith('the joint encoders read 1.50 mrad steps and 1.00 mrad of noise'
                           ' at rest, more than the 0.40 mrad steps'), both
    assert 'steps' not in encoder_clause(1e-3, 0.0).split(', more')[0]


def test_the_ledgers_hint_names_noise_and_steps() -> None:
    """``RunLedger.encoder_hint`` (the self-check refusal's clause): the joint record's
    steps and the alignment window's noise at rest, each named past what is checked; a
    record within both gives no clause."""
    from dataclasses import dataclass

    from imu_calib_ros.core.estimator.config import EstimatorConfig
    from imu_calib_ros.core.estimator.run_ledger import RunLedger
    from imu_calib_ros.core.types import JointBatch

    @dataclass
    class _Est:
        fixture: Any
        config: EstimatorConfig
        encoder_noise_at_rest_rad: float
        is_running: bool = False

    fx = load_fixture('three_axis')
    t = (np.arange(2000) * 1e7).astype(np.int64) + 10 ** 18
    q = np.column_stack([0.3 * np.sin(np.arange(2000) / 300.0)] * 3)

    def hint(noise: float, step: float) -> str:
        led = RunLedger(_Est(fx, EstimatorConfig(), noise))
        led.joints(JointBatch(t, tuple(fx.joint_names),
                              np.round(q / step) * step if step else q))
        return led.encoder_hint()

    assert hint(1e-4, 0.0) == ''
    assert 'read 1.53 mrad steps and 1.00 mrad of noise at rest' in hint(1e-3, 2 * np.pi / 2 ** 12)
    assert 'read 0.60 mrad of noise at rest' in hint(6e-4, 0.0)
