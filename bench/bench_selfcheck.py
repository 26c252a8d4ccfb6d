"""False-alarm rate and detection of the replay self-check (issue 17, docs/ESTIMATOR.md).

    python bench/bench_selfcheck.py [--seeds N] [--first S] [--cases honest,wrong]
                                    [--units nav,tactical,...] [--keep DIR]

``honest``: ``--seeds`` seeds of every unit: the world oracle's classes
(:mod:`imu_calib_ros.testing.world_cases`: ``nav``, ``tactical``, ``industrial_mems``,
``consumer_mems``; mounting error U(0, 5) deg, joint latency U(-20, 20) ms per seed) and our
simulator's grades (``sim_nav``: nav_grade, ``sim_mems``: mems_mti1; ``imu-calib
simulate``), plan demo_short (185 s), IMU 100 Hz, replayed the CLI's way with no grade and
the default config (``core.estimator.replay.replay_run``). Each run is classed by its truth:
*honest* when every estimated parameter is within 4 sigma of the truth (bias at the end),
else *dishonest*. A refused honest run is a false alarm; a refused dishonest run a
detection; a passed dishonest run a silent error.

``wrong``: the inputs the self-check must refuse, on world units (seeds 1..``--seeds``, at
most 5): ``axis0.3``/``axis1`` (the fixture file's middle axis tilted by 0.3/1 deg),
``flip_ax`` (accelerometer x sign), ``swap_axy`` (accelerometer x and y swapped),
``grade`` (a wrong grade hint: mems_mti1 for a nav unit, nav_grade for a MEMS unit),
``drop10`` (10 % of the IMU samples lost in bursts of mean 5). A run is *refused* when replay
raised (CONTRACT 5's one-line errors, before any self-check) or the self-check failed.

Prints one line per run (verdict, max |z|, the failed checks) and SUMMARY lines.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation
from scipy.stats import beta

from imu_calib_ros.core.errors import ImuCalibError
from imu_calib_ros.core.estimator import load_estimator_config
from imu_calib_ros.core.estimator.replay import replay_run
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from msg_adapters.bag import iter_bag, read_bag, write_bag
from imu_calib_ros.testing.world_cases import compare_calibration, make_case

WORLD = ('nav', 'tactical', 'industrial_mems', 'consumer_mems')
SIM = {'sim_nav': 'nav_grade', 'sim_mems': 'mems_mti1'}
WRONG = ('axis0.3', 'axis1', 'flip_ax', 'swap_axy', 'grade', 'drop10')
HONEST_Z = 4.0
COUNTED = {'restarts', 'realignments', 'input.rejected', 'input.lost'}


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact binomial confidence interval of k/n."""
    a = 1.0 - level
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def world_case(root: Path, unit: str, seed: int, **extra: Any) -> tuple[Path, Any, str]:
    """A world bag with the per-seed mounting and latency draws; (bag, truth, fixture)."""
    rng = np.random.default_rng(10_000 + seed)
    out = root / f'{unit}-{seed}-{len(extra)}'
    shutil.rmtree(out, ignore_errors=True)
    bag, truth = make_case(out, unit=unit, seed=seed, mount_deg=float(rng.uniform(0, 5)),
                           latency_ms=float(rng.uniform(-20, 20)), **extra)
    return bag, truth.data, str(truth.fixture_path)


def sim_case(root: Path, grade: str, seed: int) -> tuple[Path, Any, str]:
    """A bag of our simulator (``imu-calib simulate``); (bag, truth, fixture)."""
    from imu_calib_ros.cli import main
    out = root / f'{grade}-{seed}'
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    rc = main(['simulate', '--fixture', 'three_axis', '--plan', 'demo_short', '--imu', grade,
               '--rate', '100', '--seed', str(seed), '--output', str(out / 'bag')])
    assert rc == 0
    truth = yaml.safe_load((out / 'truth.yaml').read_text())
    from imu_calib_ros.core.config import share_dir
    return out / 'bag', truth, str(share_dir() / 'config' / 'fixtures' / 'three_axis.yaml')


def run_one(bag: Path, fixture: str, truth: Any, grade: Any = None) -> dict[str, Any]:
    """Replay like the CLI; the verdict and the truth comparison."""
    fx = load_fixture(fixture)
    t0 = time.process_time()
    try:
        run = replay_run(lambda: iter_bag(str(bag)), fx, grade, load_estimator_config(None))
    except ImuCalibError as exc:
        return {'refused': True, 'raised': str(exc).splitlines()[0], 'max_z': math.nan,
                'cpu_s': time.process_time() - t0}
    rows = compare_calibration(run.estimator.estimate().to_dict(), truth)
    z = [(abs(r.z), r.name) for r in rows if r.sigma > 0 and not r.fixed]
    zmax, where = max(z)
    v = run.verdict
    return {'refused': not v.passed, 'raised': '', 'max_z': zmax, 'max_z_at': where,
            'failed': [c.name for c in v.failed], 'line': v.line,
            'figures': {c.name: c.value for c in v.checks},
            'cpu_s': time.process_time() - t0}


def _print(tag: str, r: dict[str, Any]) -> None:
    if r['raised']:
        print(f'{tag:34s} REFUSED(replay) {r["raised"][:120]}', flush=True)
        return
    fig = ' '.join(f'{k}={v:.3g}' for k, v in r['figures'].items())
    print(f'{tag:34s} {"FAIL" if r["refused"] else "pass"} max|z| {r["max_z"]:6.2f} '
          f'({r["max_z_at"]}) failed [{", ".join(r["failed"])}] {fig} '
          f'cpu {r["cpu_s"]:.1f} s', flush=True)


def honest(root: Path, units: list[str], seeds: range) -> None:
    """The false-alarm runs."""
    res: list[tuple[str, dict[str, Any]]] = []
    for seed in seeds:
        for unit in units:
            if unit in SIM:
                bag, truth, fx = sim_case(root, SIM[unit], seed)
            else:
                bag, truth, fx = world_case(root, unit, seed)
            r = run_one(bag, fx, truth)
            _print(f'honest {unit} seed {seed}', r)
            res.append((unit, r))
            shutil.rmtree(bag.parent, ignore_errors=True)
    done = [r for _, r in res if not r['raised']]
    ok = [r for r in done if r['max_z'] <= HONEST_Z]
    bad = [r for r in done if r['max_z'] > HONEST_Z]
    # the design rate is that of the statistical checks on runs whose filter kept to its
    # model: no counted evidence (restarts, re-alignments, lost or rejected input)
    clean = [r for r in ok if not set(r['failed']) & COUNTED]
    fa = sum(r['refused'] for r in clean)
    lo, hi = clopper_pearson(fa, len(clean))
    counted = sum(1 for r in ok if set(r['failed']) & COUNTED)
    det = sum(r['refused'] for r in bad)
    raised = len(res) - len(done)
    for unit in units:
        u = [r for n, r in res if n == unit and not r['raised']]
        print(f'  {unit:16s} runs {len(u):3d}  refused {sum(r["refused"] for r in u):3d}  '
              f'dishonest {sum(r["max_z"] > HONEST_Z for r in u):3d}  silent dishonest '
              f'{sum(r["max_z"] > HONEST_Z and not r["refused"] for r in u):3d}')
    checks: dict[str, int] = {}
    for r in done:
        for c in r['failed']:
            checks[c] = checks.get(c, 0) + 1
    print('  failed checks: ' + ', '.join(f'{k} {v}' for k, v in sorted(checks.items())))
    print(f'SUMMARY selfcheck honest: {len(res)} runs ({raised} refused by replay itself); '
          f'false alarms of the statistical checks {fa}/{len(clean)} = '
          f'{100 * fa / max(len(clean), 1):.1f} % (95 % CI {100 * lo:.1f}-{100 * hi:.1f} %, '
          f'design 1 %) on honest calibrations without counted evidence; honest calibrations '
          f'refused on counted evidence (the filter re-aligned/restarted, input lost) '
          f'{counted}/{len(ok)}; dishonest calibrations (max|z| > {HONEST_Z:g}) {len(bad)}: '
          f'refused {det}, silent {len(bad) - det}')


def _tilted_fixture(path: str, deg: float, out: Path) -> str:
    d = yaml.safe_load(Path(path).read_text())
    a = np.array(d['joints'][1]['axis'], float)
    c = np.cross(a, [0.0, 0.0, 1.0])
    d['joints'][1]['axis'] = [float(x) for x in Rotation.from_rotvec(
        math.radians(deg) * c / np.linalg.norm(c)).apply(a)]
    p = out / f'fixture_tilt{deg:g}.yaml'
    p.write_text(yaml.safe_dump(d))
    return str(p)


def wrong(root: Path, units: list[str], seeds: range) -> None:
    """The detection runs."""
    res: list[tuple[str, dict[str, Any]]] = []
    for seed in seeds:
        for unit in units:
            if unit in SIM:
                continue
            bag, truth, fx = world_case(root, unit, seed)
            imu, js = read_bag(str(bag))
            for var in WRONG:
                b, f, grade = bag, fx, None
                if var.startswith('axis'):
                    f = _tilted_fixture(fx, float(var[4:]), bag.parent)
                elif var == 'grade':
                    grade = load_grade('mems_mti1' if unit in ('nav', 'tactical')
                                       else 'nav_grade')
                elif var == 'drop10':
                    b, truth_d, f = world_case(root, unit, seed, drop_fraction_imu=0.1)
                elif var in ('flip_ax', 'swap_axy'):
                    acc = imu.accel_m_s2.copy()
                    if var == 'flip_ax':
                        acc[:, 0] *= -1.0
                    else:
                        acc = acc[:, [1, 0, 2]]
                    b = bag.parent / f'{var}.mcap'
                    write_bag(b, dataclasses.replace(imu, accel_m_s2=acc), js, overwrite=True)
                r = run_one(b, f, truth_d if var == 'drop10' else truth, grade)
                _print(f'wrong {var} {unit} seed {seed}', r)
                res.append((var, r))
            shutil.rmtree(bag.parent, ignore_errors=True)
    for var in WRONG:
        rs = [r for v, r in res if v == var]
        ref = sum(r['refused'] for r in rs)
        raised = sum(1 for r in rs if r['raised'])
        silent = sum(1 for r in rs if not r['refused'] and r['max_z'] > HONEST_Z)
        print(f'SUMMARY selfcheck wrong {var}: refused {ref}/{len(rs)} ({raised} by replay '
              f'itself, {ref - raised} by the self-check); passed with max|z| > {HONEST_Z:g}: '
              f'{silent}')


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seeds', type=int, default=20)
    ap.add_argument('--first', type=int, default=1)
    ap.add_argument('--cases', default='honest,wrong')
    ap.add_argument('--units', default=','.join(WORLD + tuple(SIM)))
    ap.add_argument('--keep', default=None, metavar='DIR', help='work directory (kept)')
    a = ap.parse_args(argv)
    logging.disable(logging.WARNING)
    root = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix='bench_selfcheck_'))
    root.mkdir(parents=True, exist_ok=True)
    units = a.units.split(',')
    try:
        if 'honest' in a.cases:
            honest(root, units, range(a.first, a.first + a.seeds))
        if 'wrong' in a.cases:
            wrong(root, units, range(a.first, a.first + min(a.seeds, 5)))
    finally:
        if not a.keep:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
