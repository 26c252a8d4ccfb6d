"""HTML report: self-contained, real PNG plots, methods-vs-truth table; renders in Chromium."""
import base64
import re
import shutil
import subprocess

import numpy as np
import pytest


@pytest.fixture(scope='module')
def srt_result():
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.methods import srt
    from imu_calib_ros.core.plans import build_profile, plan_from_dict
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fx = load_fixture('savage_2axis')
    plan = plan_from_dict({'name': 't', 'steps': [
        {'srt_sequence': {'id': i, 'dwell_s': 5, 'rotation_s': 6}} for i in ('1', '4', '7')]})
    sim = simulate(fx, build_profile(plan, fx), load_grade('nav_grade'),
                   SimConfig(imu_rate_hz=100, joint_rate_hz=50, seed=1))
    return srt.calibrate(sim.imu, sim.joints, fx, load_grade('nav_grade')), sim.truth


def test_report_has_plots_and_table(srt_result, tmp_path):
    from imu_calib_ros.core.calibration import CalibrationResult
    from imu_calib_ros.report import build_report
    calib, truth = srt_result
    p = tmp_path / 'c.yaml'
    calib.save(p)
    loaded = CalibrationResult.load(p)  # the extra block survives the file round trip
    page = build_report(loaded, truth)
    imgs = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert imgs, 'no embedded plot'
    for b in imgs:
        assert base64.b64decode(b)[:8] == b'\x89PNG\r\n\x1a\n'
    assert 'err/&sigma;' in page and 'gyro Kg[y,y]' in page
    assert 'convergence plot skipped' in page  # SRT has no history
    assert 'http://' not in page and 'https://' not in page  # self-contained


def test_report_renders_in_chromium(srt_result, tmp_path):
    exe = shutil.which('chromium') or shutil.which('chromium-browser')
    if exe is None:
        pytest.skip('chromium not installed (/usr/bin/chromium missing): render check skipped')
    from imu_calib_ros.report import build_report
    calib, truth = srt_result
    html_path = tmp_path / 'r.html'
    html_path.write_text(build_report(calib, truth))
    shot = tmp_path / 'r.png'
    subprocess.run([exe, '--headless', '--no-sandbox', '--disable-gpu',
                    f'--screenshot={shot}', '--window-size=1200,2000', html_path.as_uri()],
                   check=True, timeout=60, capture_output=True)
    data = shot.read_bytes()
    assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 20000
