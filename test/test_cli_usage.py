"""``imu-calib`` as a user meets it (issue 16, items 6 and 7): ``--version`` from the one
version in package.xml, ``python -m`` entry points, help for every option, a fast ``--help``,
topics without the leading slash, and the external contract inside the repository."""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from imu_calib_ros.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _version_in_package_xml() -> str:
    m = re.search(r'<version>\s*([^<\s]+)\s*</version>', (ROOT / 'package.xml').read_text())
    assert m
    return m.group(1)


def test_version_has_one_source() -> None:
    """``imu-calib --version`` (and ``python -m imu_calib_ros.cli --version``) print the
    version of package.xml; setup.py and the package read it from there."""
    want = _version_in_package_xml()
    exe = shutil.which('imu-calib', path=str(BIN))
    assert exe
    for cmd in ([exe, '--version'], [sys.executable, '-m', 'imu_calib_ros.cli', '--version'],
                [sys.executable, '-m', 'imu_calib_ros', '--version']):
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip() == f'imu-calib {want}', (cmd, out.stdout)
    import imu_calib_ros
    assert imu_calib_ros.__version__ == want
    setup = (ROOT / 'setup.py').read_text()
    assert not re.search(r"version\s*=\s*['\"]", setup), 'a second copy of the version'
    assert '__version__ =' not in (ROOT / 'imu_calib_ros' / '__init__.py').read_text()


@pytest.mark.parametrize('module, words', [
    ('imu_calib_ros.cli', 'usage: imu-calib'),
    ('imu_calib_ros.cli.replay', 'usage: imu-calib replay'),
    ('imu_calib_ros.cli.simulate', 'usage: imu-calib simulate'),
    ('imu_calib_ros.cli.report', 'usage: imu-calib report'),
    ('imu_calib_ros.cli.modulate', 'usage: imu-calib modulate'),
])
def test_python_m_entry_points(module: str, words: str) -> None:
    out = subprocess.run([sys.executable, '-m', module, '--help'], capture_output=True,
                         text=True, timeout=60, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(words), out.stdout[:300]
    assert 'docs/CONTRACT.md' in out.stdout


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for a in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(a, argparse._SubParsersAction):  # noqa: SLF001
            return dict(a.choices)
    return {}


def test_every_option_has_help() -> None:
    """Every option and positional of every sub-command explains itself; defaults of
    ``report --output`` and the topics are stated."""
    parser = build_parser()
    subs = _subparsers(parser)
    assert set(subs) >= {'simulate', 'replay', 'report', 'modulate'}
    missing = []
    for name, sub in {'': parser, **subs}.items():
        for a in sub._actions:  # noqa: SLF001
            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):  # noqa
                continue
            if not a.help or a.help == argparse.SUPPRESS:
                missing.append(f'{name} {"/".join(a.option_strings) or a.dest}')
    assert not missing, missing
    report = subs['report'].format_help()
    assert 'default report.html' in report
    for name in ('replay', 'report', 'modulate', 'simulate'):
        text = ' '.join(subs[name].format_help().split())
        assert 'default /imu/data_raw' in text and 'default /joint_states' in text, name
    mode = ' '.join(subs['modulate'].format_help().split())
    assert 'continuous (default)' in mode and '4 outputs per revolution' in mode


def test_help_imports_no_numerics() -> None:
    """``imu-calib --help`` stays fast: building the parser imports neither numpy nor scipy
    nor rclpy (the sub-commands import the core when they run)."""
    code = ('import sys; from imu_calib_ros.cli import build_parser; build_parser(); '
            "print(sorted(m for m in ('numpy', 'scipy', 'rclpy', 'yaml') if m in sys.modules))")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=60, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '[]', out.stdout


def test_topic_without_leading_slash_is_the_absolute_name() -> None:
    from imu_calib_ros.cli import absolute_topic
    assert absolute_topic('imu/data_raw') == '/imu/data_raw'
    assert absolute_topic('/imu/data_raw') == '/imu/data_raw'
    args = build_parser().parse_args(['replay', 'b', '--fixture', 'f', '--output', 'o',
                                      '--imu-topic', 'imu/data_raw', '--joint-topic', 'js'])
    assert (args.imu_topic, args.joint_topic) == ('/imu/data_raw', '/js')


def test_contract_is_in_the_repository() -> None:
    """docs/CONTRACT.md holds the external contract (the same numbers as the team's
    specification); README and DESIGN point there, nothing points outside the clone."""
    text = ' '.join((ROOT / 'docs' / 'CONTRACT.md').read_text().split())
    for needed in ('## 1. Inputs', '## 2. Fixture file', '## 3. Sensor model',
                   '## 4. Calibration file', '## 5. Command line', '1.5 nominal periods',
                   '+-50 ms', 'format_version: 1', 'orientation_covariance[0] = -1',
                   'R_rpy     = Rz(yaw) * Ry(pitch) * Rx(roll)', 'about 1 mrad',
                   '`/imu/data_raw` and `/joint_states`', '**any unit**',
                   'raw scale errors up to percents', 'misalignments up to tens of mrad',
                   'imu-calib --version', 'imu-calib noise BAG --output NOISE.yaml',
                   'w_meas_i = omega_i + sum_j Kg[i][j] * omega_j + ag_i * |omega_i| + '
                   'sum_j G[i][j] * f_j + bg_i + noise',
                   'a_meas_i  = f_i_at_ri + sum_j Ka[i][j] * f_j + aa_i * |f_i| + '
                   'qa_i * f_i^2 + ba_i + noise'):
        assert ' '.join(needed.split()) in text, needed
    assert 'docs/CONTRACT.md' in (ROOT / 'README.md').read_text()
    assert '(CONTRACT.md)' in (ROOT / 'docs' / 'DESIGN.md').read_text()
    tracked = subprocess.run(['git', 'ls-files'], capture_output=True, text=True,
                             cwd=ROOT).stdout.split()
    if not tracked:
        pytest.skip('not a git checkout')
    offenders = []
    for name in tracked:
        path = ROOT / name
        if path.suffix in ('.md', '.py', '.yaml', '.txt', '.cfg', '.xml') and path.is_file():
            if 'shared/' + 'spec' in path.read_text(errors='replace'):
                offenders.append(name)
    assert offenders == [], offenders
    assert "'docs/CONTRACT.md'" in (ROOT / 'setup.py').read_text()  # installed to share/


def test_run_directory_is_ignored() -> None:
    """The README's walk-through writes into run/: never committed by accident."""
    lines = (ROOT / '.gitignore').read_text().split()
    assert 'run/' in lines
