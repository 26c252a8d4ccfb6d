"""Console scripts a ROS user can trust (issue 16): ``--help`` starts nothing, a misspelt or
unknown parameter is refused, a node that calibrates or drives a table has no default fixture,
an integer is a good float, and the bag player's exit lines are true.

Real processes (the installed console scripts, the worktree's package through PYTHONPATH),
localhost discovery and a random ROS_DOMAIN_ID; every wait is bounded.
"""
from __future__ import annotations

import dataclasses
import os
import random
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 200)))  # conftest's
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

BIN = Path(sys.executable).parent
NODES = ('calibration', 'compensator', 'modulation', 'turntable_driver', 'turntable_sim',
         'bag_player')


def script(name: str) -> str:
    path = shutil.which(name, path=str(BIN))
    assert path, f'console script {name} not installed in {BIN}'
    return path


def run(cmd: list[str], cwd: Path, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    """Run to the end; a node that keeps running instead of refusing fails the test."""
    try:
        return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired as exc:
        raise AssertionError(f'{cmd} still running after {timeout_s} s (it started instead '
                             f'of answering): {exc.stdout!r} {exc.stderr!r}') from None


def config_of(name: str) -> type:
    import importlib
    return importlib.import_module(f'imu_calib_ros.nodes.{name}').INTERFACE.config


def parameter_names(cls: type, prefix: str = '') -> list[str]:
    import typing
    hints = typing.get_type_hints(cls)
    out: list[str] = []
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            out += parameter_names(hints[f.name], f'{prefix}{f.name}.')
        else:
            out.append(f'{prefix}{f.name}')
    return out


@pytest.mark.parametrize('name', NODES)
@pytest.mark.parametrize('flag', ['--help', '-h'])
def test_help_prints_usage_and_starts_nothing(name: str, flag: str, tmp_path: Path) -> None:
    """``NODE --help``: usage with topics and every declared parameter (type, default), exit
    0, no node (no log line, nothing published). Before: ``turntable_driver --help`` waited
    10 s and sent demo_short to /joint_trajectory; ``calibration --help`` calibrated."""
    out = run([script(name), flag], tmp_path, 30.0)
    assert out.returncode == 0, out.stderr
    text = out.stdout
    assert text.startswith(f'usage: {name} '), text[:200]
    assert 'publishes:' in text and 'parameters' in text
    assert '[INFO]' not in text + out.stderr and '[WARN]' not in text + out.stderr
    for pname in parameter_names(config_of(name)):
        assert f'\n  {pname} (' in text, pname
    assert 'docs/CONTRACT.md' in text
    if name == 'calibration':
        assert '  imu/data_raw (sensor_msgs/msg/Imu)' in text
        assert '  imu_rate_hz (double, default 0.0; range [0.0, 100000.0])' in text
        assert '  fixture (string, required)' in text
        assert '  estimator.gate_probability (double, default 0.99999' in text
    if name == 'turntable_driver':
        assert '  joint_trajectory (trajectory_msgs/msg/JointTrajectory)' in text


def test_help_never_calls_rclpy_init(monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """Every node's main(): ``--help`` (also after ROS arguments) returns 0 without
    ``rclpy.init``; the help text is generated from the node's config dataclass."""
    import importlib

    import rclpy

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError('rclpy.init called for --help')
    monkeypatch.setattr(rclpy, 'init', refuse)
    for name in NODES:
        main = importlib.import_module(f'imu_calib_ros.nodes.{name}').main
        assert main([name, '--help']) == 0
        assert main([name, '--ros-args', '-p', 'x:=1', '--', '-h']) == 0
        assert f'usage: {name}' in capsys.readouterr().out
    from imu_calib_ros.nodes.common import help_requested
    assert not help_requested(['x', '--ros-args', '-p', 'a:=1'])
    assert not help_requested(['x', '--ros-args', '--params-file', '-h'])  # a ROS argument


@pytest.mark.parametrize('name, params, nearest', [
    ('calibration', ['fixture:=three_axis', 'fixtur:=my_table.yaml'], 'fixture'),
    ('calibration', ['fixture:=three_axis', 'estimator.noise_scal:=2.0'],
     'estimator.noise_scale'),
    ('calibration', ['fixture:=three_axis', 'estimator.bogus:=1'], 'estimator.'),
    ('turntable_driver', ['fixture:=three_axis', 'plan:=demo_short', 'pln:=savage_srt'],
     'plan'),
    ('compensator', ['calibration_file:=c.yaml', 'imu_grad:=nav_grade'], 'imu_grade'),
    ('turntable_sim', ['plan:=demo_short', 'sped:=4.0'], 'speed'),
    ('modulation', ['fixture:=three_axis', 'jiont:=inner'], 'joint'),
    ('bag_player', ['bag:=b', 'rat:=4.0'], 'rate'),
    # the URDF fixture parameters (issue 15), in the three nodes that take a fixture
    ('calibration', ['fixture:=arm6.urdf', 'imu_lnk:=imu_link'], 'imu_link'),
    ('turntable_driver', ['fixture:=arm6.urdf', 'plan:=demo_short', 'base_lnk:=base_link'],
     'base_link'),
    ('turntable_sim', ['fixture:=arm6.urdf', 'site_latitude:=10.0'], 'site_latitude_deg'),
])
def test_unknown_parameter_is_refused_naming_the_nearest(name: str, params: list[str],
                                                         nearest: str, tmp_path: Path) -> None:
    """One line, exit status 2, the nearest declared name. Before: ignored, and the default
    (the demo fixture, the demo plan) used."""
    cmd = [script(name), '--ros-args']
    for p in params:
        cmd += ['-p', p]
    out = run(cmd, tmp_path)
    bad = params[-1].split(':=')[0]
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert f'unknown parameter {bad} (did you mean {nearest}' in lines[0], lines[0]


def test_unknown_parameter_in_a_params_file_is_refused(tmp_path: Path) -> None:
    """The shipped params file plus a misspelt key: refused (the shipped file alone passes
    the check and stops at the missing fixture)."""
    root = Path(__file__).resolve().parents[1]
    shipped = root / 'config' / 'calibration_node.yaml'
    text = shipped.read_text().replace("    fixture: ''\n", '    fixtur: three_axis\n')
    assert text != shipped.read_text()
    params = tmp_path / 'params.yaml'
    params.write_text(text)
    out = run([script('calibration'), '--ros-args', '--params-file', str(params)], tmp_path)
    assert out.returncode == 2, out.stdout + out.stderr
    assert 'unknown parameter fixtur (did you mean fixture?)' in out.stderr, out.stderr
    nested = tmp_path / 'nested.yaml'
    nested.write_text('/**:\n  ros__parameters:\n    fixture: three_axis\n    estimator:\n'
                      '      gate_probabilty: 0.999\n')
    out = run([script('calibration'), '--ros-args', '--params-file', str(nested)], tmp_path)
    assert out.returncode == 2, out.stdout + out.stderr
    assert ('unknown parameter estimator.gate_probabilty (did you mean '
            'estimator.gate_probability?)') in out.stderr, out.stderr
    out = run([script('calibration'), '--ros-args', '--params-file', str(shipped)], tmp_path)
    assert out.returncode == 2 and 'fixture is required' in out.stderr, out.stderr


@pytest.mark.parametrize('name, params, missing', [
    ('calibration', [], 'fixture'),
    ('calibration', ["fixture:=''"], 'fixture'),
    ('turntable_driver', ['plan:=demo_short'], 'fixture'),
    ('turntable_driver', ['fixture:=three_axis'], 'plan'),
    ('modulation', [], 'fixture'),
    ('compensator', [], 'calibration_file'),
    ('bag_player', [], 'bag'),
])
def test_no_silent_default_for_the_table(name: str, params: list[str], missing: str,
                                         tmp_path: Path) -> None:
    """A node that calibrates against or moves a real table refuses to start without its
    fixture (and the driver without its plan): one line, exit 2. Before, ``calibration``
    calibrated against the shipped three_axis and ``turntable_driver`` drove demo_short."""
    cmd = [script(name), '--ros-args']
    for p in params:
        cmd += ['-p', p]
    out = run(cmd, tmp_path)
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert f'{missing} is required: set -p {missing}:=' in lines[0], lines[0]


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.plans import build_profile, plan_from_dict
    from imu_calib_ros.core.simulator import SimConfig, simulate
    from msg_adapters.bag import write_bag
    fx = load_fixture('three_axis')
    plan = plan_from_dict({'name': 't', 'steps': [{'dwell': {'duration_s': 1.0}}]}, 'test')
    sim = simulate(fx, build_profile(plan, fx), load_grade('nav_grade'),
                   SimConfig(imu_rate_hz=100, joint_rate_hz=50, seed=2))
    path = tmp_path_factory.mktemp('bag') / 'b'
    write_bag(path, sim.imu, sim.joints)
    return path


def test_bag_player_integer_rate_relative_topics_and_true_exit_lines(small_bag: Path,
                                                                     tmp_path: Path) -> None:
    """``-p rate:=4`` (an integer for a float) is 4.0; topics given without the leading
    slash find the bag's absolute names; the player says how many messages it published
    only when it played, and never "Failed to publish log message to rosout". Before:
    "Wrong parameter type", exit 2; after an error it still said "published 0 messages"."""
    out = run([script('bag_player'), '--ros-args', '-p', f'bag:={small_bag}', '-p', 'rate:=4',
               '-p', 'bag_imu_topic:=imu/data_raw', '-p', 'bag_joint_topic:=joint_states'],
              tmp_path)
    log = out.stdout + out.stderr
    assert out.returncode == 0, log
    from msg_adapters.bag import read_bag
    imu, joints = read_bag(small_bag)
    assert f'bag_player: published {len(imu) + len(joints)} messages' in log, log
    assert 'Failed to publish log message' not in log, log
    out = run([script('bag_player'), '--ros-args', '-p', f'bag:={tmp_path / "nope"}'], tmp_path)
    log = out.stdout + out.stderr
    assert out.returncode == 2, log
    assert 'no such bag' in log and 'published' not in log, log
    assert len(out.stderr.strip().splitlines()) == 1, log


@pytest.mark.parametrize('name, params', [
    ('calibration', ['fixture:=three_axis', 'imu_rate_hz:=200', 'estimator.noise_scale:=2']),
    ('compensator', ['imu_rate_hz:=200', 'diagnostics_rate_hz:=2']),
    ('turntable_sim', ['speed:=4', 'imu_rate_hz:=100']),
])
def test_integer_for_a_float_parameter_is_accepted(name: str, params: list[str],
                                                   tmp_path: Path) -> None:
    """The node starts (integers taken as floats) and stops cleanly on SIGINT. Before:
    "invalid value (Wrong parameter type, expected 'Type.DOUBLE' got 'Type.INTEGER')"."""
    import signal
    if name == 'compensator':
        from imu_calib_ros.core.calibration import CalibrationResult
        from imu_calib_ros.core.sensor_model import SensorErrors
        calib = tmp_path / 'c.yaml'
        CalibrationResult(SensorErrors.zeros(), SensorErrors.zeros(), 'imu_link').save(calib)
        params = [f'calibration_file:={calib}', *params]
    cmd = [script(name), '--ros-args']
    for p in params:
        cmd += ['-p', p]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        try:
            proc.wait(8.0)  # a refused parameter ends the node within a second or two
        except subprocess.TimeoutExpired:
            pass
        assert proc.poll() is None, proc.communicate()[0]
        proc.send_signal(signal.SIGINT)
        log = proc.communicate(timeout=30)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, log
    assert 'error:' not in log and 'Failed to publish log message' not in log, log


def test_declare_config_takes_integers_as_floats() -> None:
    """In process: the declared parameters hold floats (``ros2 param get`` shows a double)."""
    import rclpy
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from imu_calib_ros.nodes.calibration import CalibrationNodeConfig
    from imu_calib_ros.nodes.common import declare_config
    rclpy.init(args=['x'])
    try:
        node = Node('int_floats', parameter_overrides=[
            Parameter('fixture', value='three_axis'), Parameter('imu_rate_hz', value=400),
            Parameter('estimator.update_rate_hz', value=5)])
        cfg = declare_config(node, CalibrationNodeConfig)
        assert cfg.imu_rate_hz == 400.0 and isinstance(cfg.imu_rate_hz, float)
        assert cfg.estimator.update_rate_hz == 5.0
        p = node.get_parameter('imu_rate_hz')
        assert p.type_ == Parameter.Type.DOUBLE and p.value == 400.0
        node.destroy_node()
    finally:
        rclpy.try_shutdown()


@pytest.mark.parametrize('name', ['bag_player', 'modulation', 'calibration', 'compensator',
                                  'turntable_sim'])
def test_no_rosout_error_when_stopped_by_a_signal(name: str, small_bag: Path,
                                                  tmp_path: Path) -> None:
    """SIGINT while running: exit 0 and no "Failed to publish log message to rosout" (a log
    line after the signal had shut the context down: bag_player's count, modulation's
    counters; they go to stderr now)."""
    import signal
    params = {'bag_player': [f'bag:={small_bag}', 'rate:=0.05'],
              'modulation': ['fixture:=three_axis'],
              'calibration': ['fixture:=three_axis', 'estimator_mode:=thread'],
              'compensator': [],
              'turntable_sim': ['plan:=demo_short']}[name]
    if name == 'compensator':
        from imu_calib_ros.core.calibration import CalibrationResult
        from imu_calib_ros.core.sensor_model import SensorErrors
        calib = tmp_path / 'c.yaml'
        CalibrationResult(SensorErrors.zeros(), SensorErrors.zeros(), 'imu_link').save(calib)
        params = [f'calibration_file:={calib}']
    cmd = [script(name), '--ros-args']
    for p in params:
        cmd += ['-p', p]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        try:
            proc.wait(6.0)
        except subprocess.TimeoutExpired:
            pass
        assert proc.poll() is None, proc.communicate()[0]
        proc.send_signal(signal.SIGINT)
        log = proc.communicate(timeout=30)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, log
    assert 'Failed to publish log message' not in log, log
    if name == 'bag_player':
        assert 'bag_player: published' in log, log
    if name == 'modulation':
        assert 'modulation: counters:' in log, log
