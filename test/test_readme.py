"""The README's examples run: the calibration walk-through, the fixture and the plan example."""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.fixture import Fixture, load_fixture
from imu_calib_ros.core.plans import build_profile

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / 'README.md').read_text()


def _block(after_heading: str, lang: str) -> str:
    section = README.split(after_heading, 1)[1]
    m = re.search(rf'```{lang}\n(.*?)```', section, re.S)
    assert m, f'no {lang} block after {after_heading!r}'
    return m.group(1)


def _commands(block: str) -> list[list[str]]:
    joined = re.sub(r'\\\n\s*', ' ', block)
    cmds = []
    for line in joined.splitlines():
        line = line.split('#', 1)[0].strip()
        if line and not line.startswith('source '):
            cmds.append(shlex.split(line))
    return cmds


def _run_all(cmds: list[list[str]], cwd: Path) -> None:
    """Run the README's commands with the venv's console scripts first on PATH; each exits 0."""
    bindir = Path(sys.executable).parent
    env = dict(os.environ, PATH=f'{bindir}{os.pathsep}{os.environ["PATH"]}')
    for cmd in cmds:
        out = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True,
                             timeout=600)
        assert out.returncode == 0, f'{shlex.join(cmd)}: {out.stderr[-2000:]}'


def test_walkthrough_calibrates_a_simulated_bag(tmp_path: Path) -> None:
    cmds = _commands(_block('## A complete calibration of a simulated bag', 'bash'))
    assert cmds[0] == ['mkdir', '-p', 'run']
    cmds = cmds[1:]
    (tmp_path / 'run').mkdir()
    assert [c[:2] for c in cmds] == [['imu-calib', 'simulate'], ['imu-calib', 'replay'],
                                     ['imu-calib', 'replay'], ['imu-calib', 'report']]
    _run_all(cmds, tmp_path)
    truth = CalibrationResult.load(tmp_path / 'run' / 'truth.yaml')
    calib = CalibrationResult.load(tmp_path / 'run' / 'calib.yaml')
    # The walk-through's EKF result is consistent with the truth: accelerometer scale and
    # misalignment (well excited by demo_short) within 4 reported sigmas.
    err = calib.errors.accel_scale_misalignment - truth.errors.accel_scale_misalignment
    sig = calib.sigma.accel_scale_misalignment
    assert np.all(sig > 0)
    assert np.all(np.abs(err) <= 4 * sig), (err / sig)
    html = (tmp_path / 'run' / 'report.html').read_text()
    assert html.count('data:image/png;base64,') >= 2


def test_fixture_example_is_the_shipped_three_axis_table() -> None:
    doc = yaml.safe_load(_block('## File formats', 'yaml'))
    example = Fixture.from_dict(doc, source='README')
    shipped = load_fixture('three_axis')
    q = np.radians([[10.0, -35.0, 120.0], [0.0, 90.0, -90.0]])
    np.testing.assert_allclose(example.R_enu_imu(q), shipped.R_enu_imu(q), atol=1e-15)


def test_plan_example_builds_on_the_three_axis_table() -> None:
    section = README.split('Motion plans (`config/plans/*.yaml`)', 1)[1]
    doc = yaml.safe_load(re.search(r'```yaml\n(.*?)```', section, re.S).group(1))
    from imu_calib_ros.core.plans import plan_from_dict
    profile = build_profile(plan_from_dict(doc, source='README'), load_fixture('three_axis'))
    labels = {s.label for s in profile.segments}
    assert any(lbl.startswith('srt:4') for lbl in labels), labels
    assert profile.duration_s > 60.0


def test_plain_command_calibrates_the_readme_mems_bag(tmp_path: Path) -> None:
    """Issue 11: the README's MEMS example uses the plain command (no --imu, no --config);
    the data choose the start, encoder aiding switches itself on, and the result is honest:
    every estimated parameter within 4 sigma of the simulator's truth (biases at the end)."""
    section = README.split('The same for a consumer/industrial MEMS unit', 1)[1]
    m = re.search(r'```bash\n(.*?)```', section, re.S)
    assert m
    cmds = _commands(m.group(1))
    assert [c[:2] for c in cmds] == [['imu-calib', 'simulate'], ['imu-calib', 'replay']]
    assert '--imu' not in cmds[1] and '--config' not in cmds[1]
    (tmp_path / 'run').mkdir()
    _run_all(cmds, tmp_path)
    truth = CalibrationResult.load(tmp_path / 'run' / 'mems_truth.yaml')
    calib = CalibrationResult.load(tmp_path / 'run' / 'mems_calib.yaml')
    from imu_calib_ros.core.sensor_model import PARAMETER_SLICES
    t = truth.errors.as_vector().copy()
    t[PARAMETER_SLICES['gyroscope.bias']] = truth.extra['bias_at_end']['gyro_rad_s']
    t[PARAMETER_SLICES['accelerometer.bias']] = truth.extra['bias_at_end']['accel_m_s2']
    s = calib.sigma.as_vector()
    z = (calib.errors.as_vector() - t)[s > 0] / s[s > 0]
    assert np.abs(z).max() < 4.0, np.abs(z).max()
    assert calib.extra['estimator']['attitude_aiding'] is True
