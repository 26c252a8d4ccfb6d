"""Issue 13 item 3: `imu-calib batch` on a two-worker local Dask cluster, and the fleet summary."""
from __future__ import annotations

import csv
import io

import numpy as np
import pytest

from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.fleet import UnitOutcome, spreads, spreads_csv
from imu_calib_ros.core.sensor_model import PARAMETER_NAMES, SensorErrors


def test_fleet_spread_flags_the_odd_unit() -> None:
    rng = np.random.default_rng(1)
    outs = []
    for i in range(7):
        v = rng.normal(0, 1e-3, len(PARAMETER_NAMES))
        if i == 4:
            v[0] += 0.02  # gyroscope.bias[x] far off
        e = SensorErrors.from_vector(v)
        s = SensorErrors.from_vector(np.full(len(PARAMETER_NAMES), 1e-5))
        outs.append(UnitOutcome(f'u{i}', f'b{i}', 'ok', calib=CalibrationResult(e, s, 'imu')))
    outs.append(UnitOutcome('bad', 'b', 'failed', 'no such topic'))
    sp = spreads(outs, 3.0)
    assert len(sp) == len(PARAMETER_NAMES)
    bx = sp[0]
    assert bx.name == 'gyroscope.bias[x]' and bx.n == 7
    assert [u for u, _ in bx.outliers] == ['u4'] and bx.outliers[0][1] > 3
    # the fleet sigma is robust (MAD): the outlier does not inflate it
    assert bx.sigma < 3e-3
    # a unit's own sigma counts: a spread below the calibration noise flags nobody
    loud = [UnitOutcome(o.unit, o.bag, o.status, calib=CalibrationResult(
        o.calib.errors, SensorErrors.from_vector(np.full(len(PARAMETER_NAMES), 0.1)), 'imu'))
        for o in outs if o.calib is not None]
    assert not any(p.outliers for p in spreads(loud, 3.0))
    rows = list(csv.reader(io.StringIO(spreads_csv(sp, 3.0))))
    assert rows[1][0] == 'gyroscope.bias[x]' and rows[1][-1].startswith('u4(+')


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    from imu_calib_ros.cli import main
    d = tmp_path_factory.mktemp('fleet')
    out = []
    for seed in (1, 2, 3):
        b = d / f'unit{seed}'
        assert main(['simulate', '--fixture', 'three_axis', '--plan', 'demo_short', '--imu',
                     'mems_mti1', '--rate', '50', '--seed', str(seed), '--output', str(b),
                     '--truth', str(d / f'unit{seed}_truth.yaml')]) == 0
        out.append(b)
    broken = d / 'unit4'
    broken.mkdir()  # not a bag: its failure must not stop the others
    out.append(broken)
    return d, out


def test_batch_two_workers_one_failure(bags, tmp_path, capsys) -> None:
    from imu_calib_ros.cli import main
    d, paths = bags
    od = tmp_path / 'out'
    status = main(['batch', *map(str, paths), '--fixture', 'three_axis', '--output-dir',
                   str(od), '--workers', '2', '--quiet'])
    assert status == 1  # one bag failed, the three others calibrated
    err = capsys.readouterr().err
    fail_lines = [ln for ln in err.splitlines() if 'imu-calib batch: failed:' in ln]
    assert len(fail_lines) == 1 and fail_lines[0].startswith('imu-calib batch: failed: unit4: ')
    rows = list(csv.DictReader(io.StringIO((od / 'fleet_units.csv').read_text())))
    assert [r['unit'] for r in rows] == ['unit1', 'unit2', 'unit3', 'unit4']
    assert [r['status'] for r in rows] == ['ok', 'ok', 'ok', 'failed']
    assert rows[3]['reason'] and '\n' not in rows[3]['reason']
    for r in rows[:3]:
        calib = CalibrationResult.load(od / f"{r['unit']}.yaml")
        truth = CalibrationResult.load(d / f"{r['unit']}_truth.yaml").tracked_truth()
        # the batch ran the real replay: gyro biases within 4 sigma of the truth
        z = (calib.errors.gyro_bias_rad_s - truth.gyro_bias_rad_s) / \
            calib.sigma.gyro_bias_rad_s
        assert np.all(np.abs(z) < 4), z
        assert float(r['gyroscope.bias[x]']) == calib.errors.gyro_bias_rad_s[0]
    params = list(csv.DictReader(io.StringIO((od / 'fleet_parameters.csv').read_text())))
    assert params[0]['parameter'] == 'gyroscope.bias[x]' and params[0]['units'] == '3'
    html = (od / 'fleet.html').read_text()
    assert '3 of 4 bags calibrated' in html and 'unit4' in html
