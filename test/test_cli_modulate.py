"""``imu-calib modulate`` end to end: a spinning simulated IMU, body-frame bag out."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imu_calib_ros.cli import main


@pytest.fixture(scope='module')
def bag(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp('mod')
    plan = d / 'spin.yaml'
    plan.write_text('name: spin\nsteps:\n  - dwell: {duration_s: 2}\n'
                    '  - spin: {joint: outer, rate_deg_s: 90, duration_s: 24}\n')
    assert main(['simulate', '--fixture', 'three_axis', '--plan', str(plan), '--imu',
                 'mems_mti1', '--rate', '50', '--seed', '3', '--output', str(d / 'in')]) == 0
    return d


@pytest.mark.parametrize('mode', ['continuous', 'four'])
def test_modulate_writes_the_core_demodulation(bag: Path, mode: str) -> None:
    """The command is a thin shell: the bag it writes holds exactly what
    ``methods.modulation.demodulate`` gives for the input (the physics is tested there and
    in bench/bench_modulation.py), with the input's joint states and stamps."""
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.methods.modulation import demodulate
    from msg_adapters.bag import read_bag
    out = bag / f'body_{mode}'
    assert main(['modulate', str(bag / 'in'), '--fixture', 'three_axis', '--output',
                 str(out), '--mode', mode]) == 0
    imu_in, joints_in = read_bag(bag / 'in')
    ref = demodulate(imu_in, joints_in, load_fixture('three_axis'), mode)
    imu, joints = read_bag(out)
    np.testing.assert_array_equal(imu.stamps_ns, ref.stamps_ns)
    np.testing.assert_array_equal(imu.gyro_rad_s, ref.gyro_rad_s)
    np.testing.assert_array_equal(imu.accel_m_s2, ref.accel_m_s2)
    np.testing.assert_array_equal(joints.positions_rad, joints_in.positions_rad)
    assert np.abs(imu.gyro_rad_s - imu_in.gyro_rad_s[:len(imu)] if len(imu) == len(imu_in)
                  else 1.0).max() > 0  # it did change the stream


def test_modulate_bad_options_one_line(bag: Path, capsys) -> None:
    out = bag / 'body2'
    assert main(['modulate', str(bag / 'in'), '--fixture', 'three_axis', '--output',
                 str(out), '--mode', 'one', '--causal']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and '--causal' in err[0], err
    assert not out.exists()
    assert main(['modulate', str(bag / 'in'), '--fixture', 'three_axis', '--output',
                 str(out)]) == 0
    assert main(['modulate', str(bag / 'in'), '--fixture', 'three_axis', '--output',
                 str(out)]) == 2  # exists
    assert 'force' in capsys.readouterr().err
    assert main(['modulate', str(bag / 'in'), '--fixture', 'three_axis', '--output',
                 str(out), '--force']) == 0


def test_modulate_takes_a_urdf_fixture(bag: Path) -> None:
    """``--fixture robot.urdf --base-link --imu-link`` as replay takes it (issue 15): the
    shipped three_axis.urdf demodulates the bag as three_axis.yaml does."""
    from msg_adapters.bag import read_bag
    a, b = bag / 'body_yaml', bag / 'body_urdf'
    assert main(['modulate', str(bag / 'in'), '--fixture', 'three_axis', '--output',
                 str(a), '--mode', 'four']) == 0
    assert main(['modulate', str(bag / 'in'), '--fixture', 'three_axis.urdf', '--base-link',
                 'base_link', '--imu-link', 'imu_link', '--output', str(b), '--mode',
                 'four']) == 0
    (ia, _), (ib, _) = read_bag(a), read_bag(b)
    np.testing.assert_array_equal(ia.stamps_ns, ib.stamps_ns)
    np.testing.assert_allclose(ib.gyro_rad_s, ia.gyro_rad_s, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ib.accel_m_s2, ia.accel_m_s2, rtol=0, atol=1e-12)
