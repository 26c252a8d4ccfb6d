"""Issue 6, persistence: a crash during a save leaves the previous calibration file intact."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imu_calib_ros.core import calibration
from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.errors import ConfigError
from imu_calib_ros.core.sensor_model import SensorErrors


def result(bias: float) -> CalibrationResult:
    return CalibrationResult.exact(
        SensorErrors.zeros().replace(gyro_bias_rad_s=np.array([bias, 0.0, 0.0])))


@pytest.mark.parametrize('where', ['fsync', 'replace', 'interrupt'])
def test_failure_during_save_keeps_the_previous_file(tmp_path: Path, monkeypatch,
                                                     where: str) -> None:
    path = tmp_path / 'calib.yaml'
    result(1e-6).save(path)
    before = path.read_bytes()

    def boom(*a, **k):  # noqa: ANN002, ANN003, ANN202
        if where == 'interrupt':
            raise KeyboardInterrupt
        raise OSError(5, 'Input/output error')
    monkeypatch.setattr(calibration.os, 'fsync' if where != 'replace' else 'replace', boom)
    with pytest.raises(KeyboardInterrupt if where == 'interrupt' else ConfigError):
        result(2e-6).save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ['calib.yaml']  # no temporary file left
    assert CalibrationResult.load(path).errors.gyro_bias_rad_s[0] == 1e-6


def test_killed_process_mid_save_keeps_the_previous_file(tmp_path: Path) -> None:
    """SIGKILL a process that is inside save() (stopped just before the rename)."""
    path = tmp_path / 'calib.yaml'
    result(1e-6).save(path)
    before = path.read_bytes()
    code = f'''
import os, sys, time
import numpy as np
from imu_calib_ros.core import calibration
from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.sensor_model import SensorErrors
def stall(*a):
    print('in save', flush=True)
    time.sleep(60)
calibration.os.replace = stall
CalibrationResult.exact(SensorErrors.zeros().replace(
    gyro_bias_rad_s=np.array([2e-6, 0, 0]))).save({str(path)!r})
'''
    proc = subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == 'in save'
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    assert path.read_bytes() == before
    CalibrationResult.load(path)
