"""``imu-calib replay`` end to end: simulate a bag, replay it, check against truth.yaml."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imu_calib_ros.cli import main
from imu_calib_ros.core.calibration import CalibrationResult


@pytest.fixture(scope='module')
def bag(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp('replay')
    assert main(['simulate', '--fixture', 'three_axis', '--plan', 'demo_short', '--imu',
                 'nav_grade', '--rate', '100', '--seed', '4', '--frame-id', 'imu_front',
                 '--output', str(d / 'bag')]) == 0
    return d


def test_replay_matches_truth_within_sigma(bag: Path) -> None:
    out = bag / 'calib.yaml'
    assert main(['replay', str(bag / 'bag'), '--fixture', 'three_axis', '--output', str(out),
                 '--iterations', '1', '--quiet']) == 0
    calib = CalibrationResult.load(out)
    truth = CalibrationResult.load(bag / 'truth.yaml')
    # the calibration belongs to the frame of the bag's IMU messages
    assert calib.frame_id == truth.frame_id == 'imu_front'
    est = calib.errors.as_vector()
    tru = truth.errors.as_vector()
    sig = calib.sigma.as_vector()
    # the filter tracks the total bias: compare the biases with the turn-on value plus the
    # simulated drift at the end of the run (truth.yaml extra.bias_at_end)
    from imu_calib_ros.core.sensor_model import PARAMETER_SLICES
    at_end = truth.extra['bias_at_end']
    tru = tru.copy()
    tru[PARAMETER_SLICES['gyroscope.bias']] = at_end['gyro_rad_s']
    tru[PARAMETER_SLICES['accelerometer.bias']] = at_end['accel_m_s2']
    free = sig > 0
    z = (est - tru)[free] / sig[free]
    # consistency check: every parameter within 4 sigma (40+ parameters, see test_estimator)
    assert np.abs(z).max() < 4.0, np.abs(z).max()
    # no grade hint: nothing is assumed known; G (zero in the truth) is measured, not fixed
    assert calib.fixed == ()


def test_topics_without_leading_slash_find_the_bag_topics(bag: Path) -> None:
    """``--imu-topic imu/data_raw`` is the bag's ``/imu/data_raw`` (ROS 2 bags store absolute
    names); it failed with "missing topic" before."""
    out = bag / 'relative_topics.yaml'
    assert main(['replay', str(bag / 'bag'), '--fixture', 'three_axis', '--output', str(out),
                 '--imu-topic', 'imu/data_raw', '--joint-topic', 'joint_states',
                 '--quiet']) == 0
    assert CalibrationResult.load(out).frame_id == 'imu_front'


@pytest.mark.parametrize('args, words', [
    (['--fixture', 'three_axis'], 'does not exist'),
    (['--fixture', 'no_such_fixture'], 'no_such_fixture'),
    (['--fixture', 'three_axis', '--imu-topic', '/nope'], '/nope'),
    (['--fixture', 'three_axis', '--iterations', '0'], 'iterations'),
    (['--fixture', 'three_axis', '--max-passes', '0'], 'max-passes'),
    (['--fixture', 'three_axis', '--method', 'oscillation'], 'oscillation'),
])
def test_bad_arguments_one_line_no_output(bag: Path, capsys, args, words) -> None:
    out = bag / 'bad.yaml'
    src = str(bag / ('missing' if words == 'does not exist' else 'bag'))
    assert main(['replay', src, '--output', str(out), '--quiet'] + args) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err, err
    assert not out.exists()


def test_unknown_method_is_an_argparse_choice(bag: Path, capsys) -> None:
    out = bag / 'bad.yaml'
    with pytest.raises(SystemExit) as exc:
        main(['replay', str(bag / 'bag'), '--output', str(out), '--fixture', 'three_axis',
              '--method', 'magic'])
    assert exc.value.code != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert 'magic' in err[-1] and 'oscillation' in err[-1], err
    assert not out.exists()


@pytest.mark.parametrize('method', ['srt', 'oscillation'])
@pytest.mark.parametrize('exc', [RuntimeError('compensate did not converge in 50 iterations'),
                                 np.linalg.LinAlgError('Singular matrix'),
                                 ValueError('kozlov_c: period must be > 0')])
def test_method_failure_one_line_no_output(bag: Path, capsys, monkeypatch, method,
                                           exc) -> None:
    """CONTRACT 5: whatever a method raises on data it cannot use ends as one line naming
    the method and the cause, a non-zero exit, and no output file."""
    from imu_calib_ros.core.methods import oscillation, srt

    def fail(*_a, **_k):
        raise exc

    monkeypatch.setattr({'srt': srt, 'oscillation': oscillation}[method], 'calibrate', fail)
    out = bag / f'fail_{method}.yaml'
    assert main(['replay', str(bag / 'bag'), '--fixture', 'three_axis', '--output', str(out),
                 '--method', method, '--quiet']) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert method in err and str(exc) in err and 'plan' in err, err
    assert not out.exists()


def test_every_sub_command_is_registered() -> None:
    """The dispatcher imports every sub-command module (none is skipped silently)."""
    import argparse

    from imu_calib_ros.cli import SUBCOMMANDS, build_parser
    sub = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    assert list(sub[0].choices) == list(SUBCOMMANDS)
    assert {'simulate', 'replay', 'report', 'modulate'} <= set(SUBCOMMANDS)
