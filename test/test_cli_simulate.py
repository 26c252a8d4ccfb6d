"""``imu-calib simulate`` end to end: bag + truth.yaml, bit-exact round trip, bad input.

The fast matrix runs every shipped plan on every shipped fixture that can run it at 10 Hz;
the same matrix at the default 200/100 Hz is marked slow.
"""
from __future__ import annotations

import functools
import math
import os
from pathlib import Path

import numpy as np
import pytest

from imu_calib_ros.cli import main
from imu_calib_ros.core import simulator
from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.config import share_dir
from imu_calib_ros.core.errors import PlanError
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.plans import build_profile, load_plan
from imu_calib_ros.core.types import ImuBatch, JointBatch
from msg_adapters import bag

EARTH_RATE_RAD_S = 7.2921151467e-5
PLANS = sorted(p.stem for p in (share_dir() / 'config' / 'plans').glob('*.yaml'))
FIXTURES = sorted(p.stem for p in (share_dir() / 'config' / 'fixtures').glob('*.yaml'))
PAIRS = [(f, p) for f in FIXTURES for p in PLANS]


@functools.lru_cache(maxsize=None)
def profile_or_error(fixture: str, plan: str) -> object:
    """The plan's profile on the fixture, or the PlanError saying why it cannot run it."""
    try:
        return build_profile(load_plan(plan), load_fixture(fixture))
    except PlanError as exc:
        return exc


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(['simulate', *argv])
    out, err = capsys.readouterr()
    return rc, out, err


def base_args(out: Path, plan: str = 'demo_short', fixture: str = 'savage_2axis',
              rate: float = 20.0, joint_rate: float = 10.0) -> list[str]:
    return ['--fixture', fixture, '--plan', plan, '--imu', 'nav_grade', '--rate', str(rate),
            '--joint-rate', str(joint_rate), '--seed', '7', '--output', str(out)]


def direct_simulation(plan: str, fixture: str, rate: float, joint_rate: float,
                      seed: int = 7, noise: bool = True) -> simulator.SimResult:
    fx = load_fixture(fixture)
    cfg = simulator.SimConfig(imu_rate_hz=rate, joint_rate_hz=joint_rate, seed=seed,
                              noise=noise)
    return simulator.simulate(fx, build_profile(load_plan(plan), fx), load_grade('nav_grade'),
                              cfg)


def assert_bitwise(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape and a.dtype == b.dtype == np.float64
    assert np.array_equal(a.view(np.int64), b.view(np.int64))


@pytest.mark.parametrize('name,storage', [('run', 'mcap'), ('run', 'sqlite3'),
                                          ('run.mcap', 'mcap')])
def test_simulate_write_read_is_bit_exact(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          name: str, storage: str) -> None:
    out = tmp_path / name
    rc, stdout, err = run_cli(base_args(out) + ['--storage', storage], capsys)
    assert rc == 0, err
    assert err == ''  # not a tty: no progress bar, no chatter
    assert 'wrote' in stdout and sorted(os.listdir(tmp_path)) == sorted([name, 'truth.yaml'])
    imu, joints = bag.read_bag(out)
    ref = direct_simulation('demo_short', 'savage_2axis', 20.0, 10.0)
    np.testing.assert_array_equal(imu.stamps_ns, ref.imu.stamps_ns)
    assert_bitwise(imu.gyro_rad_s, ref.imu.gyro_rad_s)
    assert_bitwise(imu.accel_m_s2, ref.imu.accel_m_s2)
    np.testing.assert_array_equal(joints.stamps_ns, ref.joints.stamps_ns)
    assert joints.names == ref.joints.names
    assert_bitwise(joints.positions_rad, ref.joints.positions_rad)
    if ref.joints.velocities_rad_s is not None:
        assert joints.velocities_rad_s is not None
        assert_bitwise(joints.velocities_rad_s, ref.joints.velocities_rad_s)
    truth = CalibrationResult.load(tmp_path / 'truth.yaml')
    assert truth.frame_id == 'imu_link'
    np.testing.assert_array_equal(truth.errors.as_vector(), ref.truth.errors.as_vector())
    assert truth.extra['mounting'] == ref.truth.extra['mounting']
    prov = truth.extra['provenance']
    assert prov['seed'] == 7 and prov['imu_rate_hz'] == 20.0 and prov['plan'] == 'demo_short'
    assert prov['imu_samples'] == len(imu) and prov['bag'] == name


def test_bag_carries_si_physics_at_rest(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """Error- and noise-free: at rest |f| = local gravity, |omega| = earth rate (SI units)."""
    out = tmp_path / 'clean'
    rc, _, err = run_cli(base_args(out, rate=50.0) + ['--no-noise', '--no-errors'], capsys)
    assert rc == 0, err
    imu, joints = bag.read_bag(out)
    fx = load_fixture('savage_2axis')
    # the first dwell: IMU intervals that end before the joints first leave their start
    moved = np.any(joints.positions_rad != joints.positions_rad[0], axis=1)
    t_move_ns = joints.stamps_ns[np.argmax(moved) - 1]
    rest = imu.stamps_ns <= t_move_ns
    assert 100 <= rest.sum() <= 260  # demo_short starts with a 5 s dwell (250 samples)
    g = fx.site.gravity
    np.testing.assert_allclose(np.linalg.norm(imu.accel_m_s2[rest], axis=1), g, rtol=0,
                               atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(imu.gyro_rad_s[rest], axis=1), EARTH_RATE_RAD_S,
                               rtol=1e-9)
    # header stamps: 50 Hz -> 20 ms steps exactly
    assert set(np.diff(imu.stamps_ns).tolist()) == {20_000_000}


@pytest.mark.parametrize('fixture,plan', PAIRS)
def test_every_shipped_plan_on_every_fixture_that_can_run_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], fixture: str, plan: str) -> None:
    fx = load_fixture(fixture)
    profile = profile_or_error(fixture, plan)
    if isinstance(profile, PlanError):
        pytest.skip(f'{fixture} cannot run {plan}: {profile}')
    out = tmp_path / 'b.mcap'
    rc, _, err = run_cli(base_args(out, plan, fixture, 10.0, 5.0), capsys)
    assert rc == 0, err
    check_bag(out, fx.joint_names, profile.duration_s, 10.0, 5.0)


def check_bag(path: Path, joint_names: tuple[str, ...], duration_s: float, rate: float,
              joint_rate: float) -> tuple[ImuBatch, JointBatch]:
    topics = bag.list_topics(path)
    assert set(topics) == {'/imu/data_raw', '/joint_states'}
    imu, joints = bag.read_bag(path)
    assert len(imu) == math.floor(duration_s * rate + 1e-9)
    assert abs(len(joints) - duration_s * joint_rate) <= 2
    assert np.all(np.diff(imu.stamps_ns) > 0) and np.all(np.diff(joints.stamps_ns) > 0)
    assert joints.names == joint_names
    assert np.all(np.isfinite(imu.gyro_rad_s)) and np.all(np.isfinite(imu.accel_m_s2))
    # specific force stays near 1 g on a turntable (slow rotations, small lever arm)
    f = np.linalg.norm(imu.accel_m_s2, axis=1)
    assert np.all(np.abs(f - 9.81) < 0.5)
    return imu, joints


def test_plan_the_fixture_cannot_run(tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A vertical-axis oscillation on the two-axis table: PlanError line, no output."""
    rc, _, err = run_cli(base_args(tmp_path / 'b', 'kozlov_oscillation', 'savage_2axis'),
                         capsys)
    assert rc == 2 and err.count('\n') == 1
    assert 'kozlov_oscillation.yaml step' in err and 'oscillate' in err
    assert os.listdir(tmp_path) == []


def test_every_shipped_plan_runs_on_some_shipped_fixture() -> None:
    from imu_calib_ros.core.urdf_fixture import UrdfOptions
    arms = [load_fixture(p.name, UrdfOptions('base_link', 'imu_link')) for p in
            (share_dir() / 'config' / 'fixtures').glob('*.urdf')]  # the shipped chains
    cannot = []
    for plan in PLANS:
        ok = False
        for fixture in FIXTURES:
            ok = ok or not isinstance(profile_or_error(fixture, plan), PlanError)
        for fx in arms:
            try:
                ok = ok or bool(build_profile(load_plan(plan), fx).duration_s)
            except PlanError:
                pass
        if not ok:
            cannot.append(plan)
    assert cannot == [], f'shipped plans no shipped fixture can run: {cannot}'


@pytest.mark.slow
@pytest.mark.parametrize('fixture,plan', PAIRS)
def test_full_rate_matrix(tmp_path: Path, capsys: pytest.CaptureFixture[str], fixture: str,
                          plan: str) -> None:
    fx = load_fixture(fixture)
    profile = profile_or_error(fixture, plan)
    if isinstance(profile, PlanError):
        pytest.skip(str(profile))
    out = tmp_path / 'b'
    rc, _, err = run_cli(base_args(out, plan, fixture, 200.0, 100.0), capsys)
    assert rc == 0, err
    check_bag(out, fx.joint_names, profile.duration_s, 200.0, 100.0)


# ------------------------------------------------------------------ bad input, no output

@pytest.mark.parametrize('extra,match', [
    (['--rate', '-5'], 'argument --rate: must be a positive number'),
    (['--rate', 'nan'], 'argument --rate: must be a positive number'),
    (['--joint-rate', '0'], 'argument --joint-rate: must be a positive number'),
    (['--rate', '1e9'], 'above the supported'),
    (['--seed', '-1'], 'argument --seed'),
    (['--imu-topic', '/joint_states'], 'must differ'),
    (['--frame-id', ''], 'argument --frame-id'),
    (['--joint-offset-sigma-rad=-1e-3'], 'argument --joint-offset-sigma-rad: must be a '
     'finite number >= 0'),
    (['--link-sigma-m', 'inf'], 'argument --link-sigma-m: must be a finite number >= 0'),
])
def test_bad_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str],
                       match: str) -> None:
    rc, _, err = run_cli(base_args(tmp_path / 'b') + extra, capsys)
    assert rc == 2 and match in err and err.count('\n') == 1
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize('which,value,match', [
    ('--plan', 'no_such_plan', 'no shipped plans of that name (shipped: '),
    ('--fixture', 'no_such_fixture', 'no shipped fixtures of that name'),
    ('--imu', 'no_such_grade', 'no shipped imus of that name'),
])
def test_unknown_names(tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str,
                       value: str, match: str) -> None:
    args = base_args(tmp_path / 'b')
    args[args.index(which) + 1] = value
    rc, _, err = run_cli(args, capsys)
    assert rc == 2 and match in err and value in err and err.count('\n') == 1
    assert os.listdir(tmp_path) == []


def test_malformed_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = tmp_path / 'plan.yaml'
    plan.write_text('steps: [ {dwell: {duration_s: 1}\n')
    out_dir = tmp_path / 'o'
    out_dir.mkdir()
    args = base_args(out_dir / 'b')
    args[args.index('--plan') + 1] = str(plan)
    rc, _, err = run_cli(args, capsys)
    assert rc == 2 and 'plan.yaml' in err and err.count('\n') == 1
    assert os.listdir(out_dir) == []


def test_output_checks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, _, err = run_cli(base_args(tmp_path / 'x.mcap') + ['--storage', 'sqlite3'], capsys)
    assert rc == 2 and 'needs --storage mcap' in err
    rc, _, err = run_cli(base_args(tmp_path / 'missing' / 'b'), capsys)
    assert rc == 2 and 'does not exist' in err
    assert os.listdir(tmp_path) == []


def test_existing_output_refused_then_forced(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'b'
    assert run_cli(base_args(out, rate=10.0, joint_rate=5.0), capsys)[0] == 0
    before = (tmp_path / 'truth.yaml').read_text()
    rc, _, err = run_cli(base_args(out, rate=10.0, joint_rate=5.0), capsys)
    assert rc == 2 and 'exists already (use --force' in err
    # only the truth file in the way is also refused
    other = tmp_path / 'c'
    rc, _, err = run_cli(base_args(other, rate=10.0, joint_rate=5.0), capsys)
    assert rc == 2 and 'argument --truth' in err and not other.exists()
    args = base_args(out, rate=10.0, joint_rate=5.0)
    args[args.index('--seed') + 1] = '8'
    rc, _, err = run_cli(args + ['--force'], capsys)
    assert rc == 0, err
    assert (tmp_path / 'truth.yaml').read_text() != before
    assert sorted(os.listdir(tmp_path)) == ['b', 'truth.yaml']
    assert len(bag.read_bag(out)[0]) == len(
        direct_simulation('demo_short', 'savage_2axis', 10.0, 5.0, seed=8).imu)


def test_failure_while_writing_leaves_no_partial_output(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A bag write that dies halfway (disk full) leaves neither bag nor truth file."""
    from msg_adapters import bag as bag_mod
    real = bag_mod.write_bag

    def dying_write(*a, **kw):  # type: ignore[no-untyped-def]
        def boom(n: int) -> None:
            raise OSError(28, 'No space left on device')
        kw['progress'] = boom
        return real(*a, **kw)
    monkeypatch.setattr(bag_mod, 'write_bag', dying_write)
    rc, _, err = run_cli(base_args(tmp_path / 'b', rate=100.0), capsys)
    assert rc == 2 and 'No space left on device' in err and err.count('\n') == 1
    assert os.listdir(tmp_path) == []


def test_truth_option_and_topics(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'b'
    truth = tmp_path / 'elsewhere.yaml'
    rc, _, err = run_cli(base_args(out, rate=10.0, joint_rate=5.0) + [
        '--truth', str(truth), '--imu-topic', '/imu/raw', '--joint-topic', '/table/joints',
        '--frame-id', 'my_imu'], capsys)
    assert rc == 0, err
    assert truth.is_file() and not (tmp_path / 'truth.yaml').exists()
    assert set(bag.list_topics(out)) == {'/imu/raw', '/table/joints'}
    imu, _ = bag.read_bag(out, '/imu/raw', '/table/joints')
    assert imu.frame_id == 'my_imu'
    assert CalibrationResult.load(truth).frame_id == 'my_imu'


def test_arm_errors_into_the_data_and_the_truth(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """``--joint-offset-sigma-rad``/``--link-sigma-m`` on a URDF arm: the bag's IMU comes from
    the perturbed chain (differs from the nominal arm's by more than the noise could), the
    joint states are the encoder readings (equal), and the truth file records the drawn
    errors (``chain_errors``: the simulator's, SimConfig's draw) and the estimator's
    last-link mounting and lever-arm truth."""
    plan = tmp_path / 'p.yaml'
    plan.write_text('name: p\nsteps:\n  - dwell: {duration_s: 1}\n  - move: {joint: '
                    'wrist_2_joint, by_deg: 90, duration_s: 2}\n')
    args = ['--fixture', 'arm6.urdf', '--base-link', 'base_link', '--imu-link', 'imu_link',
            '--plan', str(plan), '--imu', 'mems_mti1', '--rate', '50', '--seed', '4',
            '--no-noise']
    rc, _, err = run_cli(args + ['--output', str(tmp_path / 'nom'), '--truth',
                                 str(tmp_path / 'nom.yaml')], capsys)
    assert rc == 0, err
    rc, _, err = run_cli(args + ['--output', str(tmp_path / 'arm'), '--truth',
                                 str(tmp_path / 'arm.yaml'), '--joint-offset-sigma-rad',
                                 '1e-3', '--link-sigma-m', '2e-3'], capsys)
    assert rc == 0, err
    imu_n, joints_n = bag.read_bag(tmp_path / 'nom', '/imu/data_raw', '/joint_states')
    imu_a, joints_a = bag.read_bag(tmp_path / 'arm', '/imu/data_raw', '/joint_states')
    assert np.array_equal(joints_n.positions_rad, joints_a.positions_rad)
    assert np.abs(imu_a.accel_m_s2 - imu_n.accel_m_s2).max() > 1e-3
    nom = CalibrationResult.load(tmp_path / 'nom.yaml')
    arm = CalibrationResult.load(tmp_path / 'arm.yaml')
    assert 'chain_errors' not in nom.extra
    assert np.array_equal(nom.errors.as_vector(), arm.errors.as_vector())
    ce = arm.extra['chain_errors']
    assert ce['joint_offset_sigma_rad'] == 1e-3 and ce['link_sigma_m'] == 2e-3
    assert arm.extra['provenance']['joint_offset_sigma_rad'] == 1e-3
    from imu_calib_ros.core.urdf_fixture import UrdfOptions
    fx = load_fixture('arm6.urdf', UrdfOptions('base_link', 'imu_link'))
    res = simulator.simulate(fx, build_profile(load_plan(str(plan)), fx),
                             load_grade('mems_mti1'),
                             simulator.SimConfig(imu_rate_hz=50.0, seed=4, noise=False,
                                                 joint_offset_sigma_rad=1e-3,
                                                 link_sigma_m=2e-3))
    assert ce == res.truth.extra['chain_errors']
    assert list(ce['joint_zero_offsets_rad']) == list(fx.joint_names)
    assert np.array_equal(imu_a.accel_m_s2, res.imu.accel_m_s2)
