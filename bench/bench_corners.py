"""Corners of issue 11's envelope that bench_robustness's grid does not reach: the PLAIN command.

    python bench/bench_corners.py [CASE ...] [--all] [--list] [--out DIR] [--repo PATH]

Each case is a grid case (:func:`bench_robustness.draw_case`: the unit, its errors and noise,
the per-seed draws of joint-message form and drops) with one or more factors set to the edge
of what issue 11 promises, or past the grid's levels: IMU at 50-2000 Hz, joint states at
exactly 10 Hz or at 250-1000 Hz, a joint rate that is not a divisor of the IMU rate, latency
at exactly +-50 ms with point samples, mounting exactly 10 deg about x, y or z with a 50 mm
offset, a sqlite3 bag, rosbag2-like log-time jitter with slow joints, and everything at once.
Names are ``FACTOR@PLAN[_sSEED]``, PLAN one of ``srt3`` (savage_srt@three_axis), ``srt2``
(savage_srt@savage_2axis), ``kozlov3`` (srt_then_kozlov@three_axis), ``random3``
(random@three_axis); seeds count from 100 (no grid seed). The bag comes from the world
simulator (``imu_calib_ros.testing.world_sim``), and the command is exactly what a user types
(``imu-calib replay BAG --fixture F --output C``, ``--repo`` first on PYTHONPATH).

Prints per case: exit status, the command's last stderr line when it is not 0, max
|error/sigma| with its parameter and the count beyond 3 sigma (of the estimated parameters);
then ``SUMMARY``: cases passed (exit 0, nothing beyond 4 sigma), exits non-zero, tracebacks
(exit 1: never acceptable, CONTRACT 5 wants one line). Per case ``DIR/CASE`` keeps the bag,
truth, fixture, calibration, stderr and a ``reproduce.sh``. Not a test: it prints figures.

Found on 2026-11-25 (ec088d9, 82 cases): 1 kHz joint states on a navigation unit failed
(``nav_joints1000@srt3``: refused by the self-check, with --force g-sensitivity 7-9 sigma
off; 500 Hz already 3.5 sigma: the alignment window, 400fadf), and consumer/industrial MEMS
and tactical units with 10 Hz joint states and bursts of both streams lost diverged
(``cmems_all_at_once@kozlov3``: the latency's sigma, 807312a) or ended in a traceback
(``cmems_p_j10_drops@kozlov3``, 93caf65). The default set: 16/23 passed at 93caf65, 23/23 at
807312a (docs/WORLD.md, session 12).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'bench'))
import bench_robustness as br  # noqa: E402

from imu_calib_ros.testing import world_sim  # noqa: E402
from imu_calib_ros.testing.world_cases import compare_calibration  # noqa: E402
from imu_calib_ros.testing.world_sim import Mounting  # noqa: E402

NO_DROPS = dict(drop_fraction_imu=0.0, drop_fraction_joint=0.0)
DROPS = dict(drop_fraction_imu=0.02, drop_fraction_joint=0.05)


@dataclasses.dataclass(frozen=True)
class Factor:
    """A corner: the unit class, error size, mounting, the grid's timing level it starts from,
    WorldConfig fields set on top, and a mounting of exactly 10 deg about this axis."""

    unit: str
    base_timing: str = 'nominal'
    config: dict[str, Any] = dataclasses.field(default_factory=dict)
    mount_axis: int | None = None
    size: float = 1.0
    mount: str = 'large'


FACTORS: dict[str, Factor] = {
    # IMU rates the grid does not draw
    'indmems_imu1000': Factor('industrial_mems', config=dict(imu_rate_hz=1000.0)),
    'indmems_imu400': Factor('industrial_mems', config=dict(imu_rate_hz=400.0)),
    'indmems_imu50': Factor('industrial_mems', config=dict(imu_rate_hz=50.0)),
    'cmems_imu1000': Factor('consumer_mems', config=dict(imu_rate_hz=1000.0)),
    'tac_imu2000_point': Factor('tactical', 'point', dict(imu_rate_hz=2000.0, block=2048)),
    'tac_imu250_joints60': Factor('tactical', config=dict(imu_rate_hz=250.0,
                                                          joint_rate_hz=60.0)),
    # joint rates at the ends of 10 Hz .. 1 kHz
    'nav_joints10': Factor('nav', config=dict(joint_rate_hz=10.0)),
    'nav_joints10_lat+50': Factor('nav', config=dict(joint_rate_hz=10.0,
                                                     joint_latency_s=0.05)),
    'nav_point_joints10_lat-50': Factor('nav', 'point', dict(joint_rate_hz=10.0,
                                                             joint_latency_s=-0.05)),
    'nav_joints250': Factor('nav', config=dict(joint_rate_hz=250.0)),
    'nav_joints500': Factor('nav', config=dict(joint_rate_hz=500.0)),
    'nav_joints1000': Factor('nav', config=dict(joint_rate_hz=1000.0)),
    'nav_joints1000_none': Factor('nav', config=dict(joint_rate_hz=1000.0), mount='none'),
    'nav_joints1000_enc0': Factor('nav', config=dict(joint_rate_hz=1000.0,
                                                     encoder_noise_rad=0.0)),
    'indmems_joints1000': Factor('industrial_mems', config=dict(joint_rate_hz=1000.0)),
    'tac_joints500': Factor('tactical', config=dict(joint_rate_hz=500.0)),
    'tac_joints1000': Factor('tactical', config=dict(joint_rate_hz=1000.0)),
    # latency at the edge, with point samples
    'tac_lat-50_point': Factor('tactical', 'point', dict(joint_latency_s=-0.05)),
    'tac_lat+50_point': Factor('tactical', 'point', dict(joint_latency_s=0.05)),
    # mounting at the edge about each axis
    'cmems_mount10x': Factor('consumer_mems', mount_axis=0),
    'cmems_mount10y': Factor('consumer_mems', mount_axis=1),
    'cmems_mount10z': Factor('consumer_mems', mount_axis=2),
    # 10 Hz joint states with bursts of lost messages, alone and with everything else
    'cmems_j10': Factor('consumer_mems', config=dict(joint_rate_hz=10.0, **NO_DROPS)),
    'cmems_p_j10_drops': Factor('consumer_mems', 'point', dict(joint_rate_hz=10.0, **DROPS)),
    'cmems_j10_drops_im': Factor('consumer_mems', 'point', dict(
        joint_rate_hz=10.0, sample_type='interval_mean', **DROPS)),
    'cmems_p_j20_drops': Factor('consumer_mems', 'point', dict(joint_rate_hz=20.0, **DROPS)),
    'cmems_all_at_once': Factor('consumer_mems', 'point', dict(
        joint_rate_hz=10.0, joint_latency_s=0.05, **DROPS)),
    'cmems_all_at_once_l-50': Factor('consumer_mems', 'point', dict(
        joint_rate_hz=10.0, joint_latency_s=-0.05, **DROPS)),
    'indmems_all_at_once': Factor('industrial_mems', 'point', dict(
        joint_rate_hz=10.0, joint_latency_s=0.05, **DROPS)),
    'tac_all_at_once': Factor('tactical', 'point', dict(
        joint_rate_hz=10.0, joint_latency_s=0.05, **DROPS)),
    # other bag forms
    'nav_sqlite3': Factor('nav', config=dict(storage='sqlite3')),
    'cmems_logjitter_slow': Factor('consumer_mems', config=dict(
        joint_rate_hz=15.0, receipt_delay_s=(1.5e-3, 2.5e-3))),
    # a simulator's clock (use_sim_time): stamps from zero
    'nav_simtime': Factor('nav', config=dict(start_stamp_ns=0)),
    'cmems_simtime': Factor('consumer_mems', 'point', dict(start_stamp_ns=0)),
    # header stamps taken on receipt by the host: IMU and/or joints late by U(0, jitter)
    'nav_imujitter': Factor('nav', config=dict(imu_stamp_jitter_s=2e-3)),
    'nav_ctl': Factor('nav'),  # the nav cases above without their factor
    'tac_imujitter_point': Factor('tactical', 'point', dict(imu_stamp_jitter_s=3e-3)),
    'indmems_imujitter1000': Factor('industrial_mems', config=dict(
        imu_rate_hz=1000.0, imu_stamp_jitter_s=2e-3)),
    'nav_jointjitter': Factor('nav', config=dict(joint_stamp_jitter_s=5e-3)),
    'nav_jointjitter1': Factor('nav', config=dict(joint_stamp_jitter_s=1e-3)),
    'tac_jointjitter1': Factor('tactical', config=dict(joint_stamp_jitter_s=1e-3)),
    'cmems_jointjitter2': Factor('consumer_mems', config=dict(joint_stamp_jitter_s=2e-3)),
    'cmems_jointjitter2_ctl': Factor('consumer_mems'),  # the same case without the jitter
    'cmems_bothjitter': Factor('consumer_mems', 'point', dict(
        imu_stamp_jitter_s=4e-3, joint_stamp_jitter_s=8e-3)),
    # a driver that publishes joint states only when a joint moved (silent at the dwells)
    'nav_onchange': Factor('nav', config=dict(joint_on_change_rad=1e-4)),
    'cmems_onchange': Factor('consumer_mems', config=dict(joint_on_change_rad=1e-3)),
    # receipt delays over half a period with bursts of joint states lost (session 18)
    'tac_jointjitter_drops': Factor('tactical', config=dict(
        joint_rate_hz=14.4, joint_stamp_jitter_s=0.036, **DROPS)),
    'nav_joints1000_jitter_drops': Factor('nav', config=dict(
        joint_rate_hz=1000.0, joint_stamp_jitter_s=4.8e-3, **DROPS)),
    # the same joint states under encoder aiding (session 19: the filter's joint record
    # averages scattered joint states in groups)
    'cmems_joints1000_jitter_drops': Factor('consumer_mems', config=dict(
        joint_rate_hz=1000.0, joint_stamp_jitter_s=4.8e-3, **DROPS)),
    # the table's base off level (session 18): a desk 1.15 deg, a bench 2 mrad, with all else
    'cmems_tilt20': Factor('consumer_mems', config=dict(base_tilt_rad=(0.012, -0.016))),
    'tac_tilt2': Factor('tactical', config=dict(base_tilt_rad=(-0.0012, 0.0016))),
    'indmems_tilt_all_at_once': Factor('industrial_mems', 'point', dict(
        joint_rate_hz=10.0, joint_latency_s=0.05, base_tilt_rad=(0.006, 0.008), **DROPS)),
}
PLAN_TAG = {0: 'srt3', 1: 'srt2', 2: 'kozlov3', 3: 'random3'}

#: run when no case is named: one or two per family, the failures found included
DEFAULT = ('indmems_imu1000@srt3', 'indmems_imu50@srt3', 'tac_imu2000_point@srt3',
           'tac_imu250_joints60@srt3', 'nav_joints10@srt3', 'nav_point_joints10_lat-50@srt3',
           'nav_joints250@srt3', 'nav_joints500@srt3', 'nav_joints1000@srt3',
           'nav_joints1000@kozlov3', 'tac_joints1000@srt3', 'tac_lat-50_point@srt3',
           'tac_lat+50_point@kozlov3', 'cmems_mount10x@srt2', 'cmems_mount10y@srt3',
           'cmems_mount10z@kozlov3', 'cmems_p_j10_drops@kozlov3', 'cmems_j10_drops_im@srt2',
           'cmems_all_at_once@kozlov3', 'cmems_all_at_once_l-50@kozlov3',
           'tac_all_at_once@kozlov3', 'nav_sqlite3@srt3', 'cmems_logjitter_slow@srt3',
           'tac_jointjitter_drops@random3', 'nav_joints1000_jitter_drops@kozlov3',
           'cmems_tilt20@kozlov3', 'tac_tilt2@srt3', 'indmems_tilt_all_at_once@srt3',
           'cmems_joints1000_jitter_drops@srt3', 'cmems_joints1000_jitter_drops@kozlov3')


def parse(name: str) -> tuple[Factor, int, int]:
    """``FACTOR@PLANTAG[_sSEED]`` -> (factor, plan index, seed index >= 100)."""
    factor, rest = name.split('@')
    tag, _, seed = rest.partition('_s')
    return FACTORS[factor], {v: k for k, v in PLAN_TAG.items()}[tag], 100 + int(seed or 0)


def replay_and_score(d: Path, fixture: Path, name: str, described: str, gen_s: float,
                     repo: Path | str) -> dict[str, Any]:
    """The plain command on ``d/bag`` (a ``reproduce.sh`` beside it), scored against
    ``d/truth.yaml``: exit status, the last stderr line, max |error/sigma|, counts beyond 3
    and 4 sigma, the diagonal NEES, held parameters beyond 3 assumed sigma; written to
    ``d/result.json`` (bench_corners and bench_lab)."""
    out = d / 'calib.yaml'
    if out.exists():
        out.unlink()
    cmd = br.replay_command(sys.executable, d / 'bag', fixture, out)
    env = dict(os.environ, PYTHONPATH=str(repo), OPENBLAS_NUM_THREADS='1')
    (d / 'reproduce.sh').write_text(f'#!/bin/sh\ncd {d}\nOPENBLAS_NUM_THREADS=1 '
                                    f'PYTHONPATH={repo} {" ".join(map(str, cmd))}\n')
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=d, timeout=3000)
    (d / 'stderr.txt').write_text(proc.stderr)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and 'replay x' not in ln]
    res: dict[str, Any] = {'name': name, 'described': described,
                           'status': proc.returncode, 'wall_s': time.perf_counter() - t0,
                           'gen_s': gen_s, 'last_stderr': lines[-1][:300] if lines else ''}
    if proc.returncode == 0 and out.exists():
        rows = compare_calibration(yaml.safe_load(out.read_text()),
                                   yaml.safe_load((d / 'truth.yaml').read_text()))
        est = [r for r in rows if not r.fixed and r.sigma > 0.0]
        z = np.array([r.z for r in est])
        i = int(np.argmax(np.abs(z)))
        res.update(n_est=len(est), max_z=float(abs(z[i])), max_z_param=est[i].name,
                   beyond3=int(np.sum(np.abs(z) > 3)), beyond4=int(np.sum(np.abs(z) > 4)),
                   nees=float(np.sum(z ** 2)),
                   held_bad=[r.name for r in rows if (r.fixed or r.sigma == 0.0)
                             and abs(r.z) > 3])
    (d / 'result.json').write_text(json.dumps(res, indent=1))
    return res


def run(name: str, out_root: Path, repo: Path) -> dict[str, Any]:
    """Generate the case's bag (kept for a re-run), replay it with the plain command."""
    fac, p, seed_index = parse(name)
    case = br.Case(fac.unit, p, seed_index, fac.size, fac.mount, fac.base_timing)
    drawn = br.draw_case(case)
    cfg = dataclasses.replace(drawn.config, **fac.config)
    mounting = drawn.mounting
    if fac.mount_axis is not None:
        rv = np.zeros(3)
        rv[fac.mount_axis] = math.radians(10.0)
        mounting = Mounting(rv, 0.05 * np.array([1.0, -1.0, 1.0]) / math.sqrt(3.0))
    drawn = br.Drawn(drawn.unit, mounting, cfg, drawn.plan_seed)
    d = out_root / name
    d.mkdir(parents=True, exist_ok=True)
    fx_src = repo / 'config' / 'fixtures' / f'{case.fixture}.yaml'
    shutil.copy(fx_src, d / 'fixture.yaml')
    t0 = time.perf_counter()
    if not ((d / 'truth.yaml').exists() and (d / 'bag' / 'metadata.yaml').exists()):
        if (d / 'bag').exists():
            shutil.rmtree(d / 'bag')
        if case.plan == 'random':
            from imu_calib_ros.core.plans import random_plan
            plan: Any = random_plan(drawn.plan_seed, br.RANDOM_PLAN_MOVES)
        else:
            plan = case.plan
        world_sim.simulate_to_files(d, fx_src, world_sim.joint_profile(plan, fx_src),
                                    drawn.unit, drawn.mounting, cfg, case.seed,
                                    provenance={'case': name, 'described': drawn.describe()})
    gen_s = time.perf_counter() - t0
    return replay_and_score(d, d / 'fixture.yaml', name, drawn.describe(), gen_s, repo)


def passed(r: dict[str, Any]) -> bool:
    return r['status'] == 0 and r.get('beyond4', 1) == 0 and not r.get('held_bad')


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('cases', nargs='*', help='case names (default: DEFAULT; --list)')
    ap.add_argument('--all', action='store_true', help='every factor on srt3 and kozlov3')
    ap.add_argument('--list', action='store_true', help='print the factors and exit')
    ap.add_argument('--out', default='/tmp/imu_calib_corners', help='bags and results')
    ap.add_argument('--repo', default=str(REPO), help='checkout the command runs')
    a = ap.parse_args()
    if a.list:
        print('\n'.join(f'{k}: {v}' for k, v in FACTORS.items()))
        return 0
    names = a.cases or ([f'{f}@{p}' for f in FACTORS for p in ('srt3', 'kozlov3')]
                        if a.all else list(DEFAULT))
    t0 = time.perf_counter()
    results = []
    for k, name in enumerate(names, 1):
        r = run(name, Path(a.out), Path(a.repo))
        results.append(r)
        head = f'[{k:2d}/{len(names)}] {name:34s} exit {r["status"]}  {r["wall_s"]:5.1f} s'
        if r['status'] == 0:
            print(f'{head}  max|z| {r["max_z"]:.2f} ({r["max_z_param"]})  beyond 3 sigma '
                  f'{r["beyond3"]}/{r["n_est"]}  {"PASS" if passed(r) else "FAIL"}', flush=True)
        else:
            print(f'{head}  FAIL: {r["last_stderr"]}', flush=True)
    n_pass = sum(passed(r) for r in results)
    n_bad = sum(r['status'] != 0 for r in results)
    n_tb = sum(r['status'] == 1 for r in results)
    print(f'SUMMARY corners: passed {n_pass}/{len(results)}, exits non-zero {n_bad}, '
          f'tracebacks {n_tb}, wall {(time.perf_counter() - t0) / 60:.1f} min')
    return 0 if n_pass == len(results) else 1


if __name__ == '__main__':
    sys.exit(main())
