"""A lab's own tables and schedules under the PLAIN command (CONTRACT 5).

    python bench/bench_lab.py [CASE ...] [--seeds N] [--units U,..] [--fixtures F,..]
                              [--out DIR] [--repo PATH] [--jobs J] [--list]

The robustness grid and the corners run our plans (``core.plans``: quintic moves, SRT
sequences mapped by our builder) on our two shipped fixtures at 55.7 deg north. A lab writes its
own: :mod:`imu_calib_ros.testing.lab_motion` gives trapezoidal rate profiles (the joint
acceleration jumps at every corner), poses at multiples of 90 deg (some at 45) written in joint
space, rate tests of each joint in both directions, and fixtures of other axis orders and IMU
mountings at other sites (Sydney, the equator at 2,800 m, Svalbard with a measured gravity,
Cape Town). The unit, its mounting error, the timing and the joint-message form are drawn per
seed as the grid draws them (:func:`bench_robustness.draw_case`, every timing level, large
mounting: 1-10 deg, 5-50 mm, encoder zeros; and, session 18, the table's base off level:
0.05-2 mrad under navigation and tactical units, 1-20 mrad under MEMS), the bag is written by
the world
(:mod:`imu_calib_ros.testing.world_sim`) and the command is exactly what a user types.

Case names are ``UNIT@FIXTURE_sSEED``. Per case: exit status, the command's last stderr line
when it is not 0, max |error/sigma| with its parameter, the count beyond 3 sigma, and the
diagonal NEES over the estimated parameters; then ``SUMMARY``: cases passed (exit 0, nothing
beyond 4 sigma, no held parameter beyond 3 assumed sigma; on a table that cannot calibrate a
raw unit, :data:`EXPECT_REFUSAL`, a refusal naming why: the self-check's, or a
divergence's), exits non-zero, tracebacks, beyond 3 sigma against what an honest filter
gives. Not a test: it prints figures.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'bench'))
import bench_corners as bc  # noqa: E402
import bench_robustness as br  # noqa: E402

from imu_calib_ros.testing import lab_motion, world_sim  # noqa: E402

UNITS = ('nav', 'tactical', 'industrial_mems', 'consumer_mems')
#: tables that cannot calibrate an uncalibrated unit, and the refusal expected (exit 3, the
#: self-check's line): a vertical outer axis with a horizontal inner one never stands the inner
#: axis up, so the accelerometers' response along it is never seen, however the IMU is mounted
EXPECT_REFUSAL = {'south_2axis_vh': 'never stands the IMU direction'}
TIMINGS = ('nominal', 'latency', 'point', 'slow_joints')


def parse(name: str) -> tuple[str, str, int]:
    """``UNIT@FIXTURE_sSEED`` -> (unit, fixture, seed)."""
    unit, rest = name.split('@')
    fixture, _, seed = rest.rpartition('_s')
    return unit, fixture, int(seed)


def draw(unit: str, fixture: str, seed: int) -> br.Drawn:
    """The grid's draws for a case of this unit (timing level and size from the seed)."""
    timing = TIMINGS[seed % len(TIMINGS)]
    size = (0.2, 1.0)[(seed // len(TIMINGS)) % 2]
    case = br.Case(unit, 0, 200 + seed, size, 'large', timing)
    drawn = br.draw_case(case)
    n = len(lab_motion.LAB_FIXTURES[fixture]['joints'])
    rng = np.random.default_rng([case.seed, n])
    zeros = tuple(float(v) for v in rng.choice([-1.0, 1.0], n) * rng.uniform(0.5e-3, 5e-3, n))
    # the table's base off level (session 18, drawn after the zeros so that they stay): a
    # rate table levelled to 0.05-2 mrad for navigation and tactical units, a bench or a
    # desk 1-20 mrad (up to 1.1 deg) for MEMS, about a random horizontal axis
    lo, hi = (0.05e-3, 2e-3) if unit in ('nav', 'tactical') else (1e-3, 20e-3)
    az, mag = rng.uniform(0.0, 2.0 * np.pi), rng.uniform(lo, hi)
    tilt = (float(mag * np.cos(az)), float(mag * np.sin(az)))
    return br.Drawn(drawn.unit, drawn.mounting,
                    dataclasses.replace(drawn.config, encoder_zero_rad=zeros,
                                        base_tilt_rad=tilt), drawn.plan_seed)


def run(name: str, out_root: str, repo: str) -> dict[str, Any]:
    """Generate the case's bag (kept for a re-run) and replay it with the plain command."""
    unit, fixture, seed = parse(name)
    drawn = draw(unit, fixture, seed)
    d = Path(out_root) / name
    d.mkdir(parents=True, exist_ok=True)
    fx = lab_motion.write_fixture(fixture, d)
    t0 = time.perf_counter()
    if not ((d / 'truth.yaml').exists() and (d / 'bag' / 'metadata.yaml').exists()):
        if (d / 'bag').exists():
            shutil.rmtree(d / 'bag')
        profile = lab_motion.lab_schedule(lab_motion.LAB_FIXTURES[fixture], drawn.plan_seed)
        world_sim.simulate_to_files(d, fx, profile, drawn.unit, drawn.mounting, drawn.config,
                                    seed, provenance={'case': name,
                                                      'described': drawn.describe()})
    gen_s = time.perf_counter() - t0
    return bc.replay_and_score(d, fx, name, drawn.describe(), gen_s, repo)


def plan_reach(name: str) -> float:
    """The least share of gravity the case's schedule brings any IMU direction to at its
    dwells, on the nominal fixture (:func:`coarse.least_reach`): below
    :data:`coarse.MIN_ACCEL_REACH` the plan is too weak for a raw unit, and the self-check's
    refusal is the expected outcome (a table whose IMU is turned 37 deg on its inner axis need
    not stand every direction up in 14 poses)."""
    from imu_calib_ros.core.estimator.coarse import least_reach
    from imu_calib_ros.core.fixture import Fixture
    unit, fixture, seed = parse(name)
    fx = lab_motion.LAB_FIXTURES[fixture]
    prof = lab_motion.lab_schedule(fx, draw(unit, fixture, seed).plan_seed)
    mid = [0.5 * (a + b) for a, b in prof.stationary_windows(1.0)]
    return least_reach(Fixture.from_dict(fx).R_enu_imu(prof.evaluate(mid)[0])[:, 2])[0]


@functools.lru_cache(maxsize=None)
def expected_refusal(name: str) -> str | None:
    """The refusal a case should end in (the self-check's words), or None."""
    from imu_calib_ros.core.estimator.coarse import MIN_ACCEL_REACH
    fixture = parse(name)[1]
    if fixture in EXPECT_REFUSAL:
        return EXPECT_REFUSAL[fixture]
    return 'never stands' if plan_reach(name) < MIN_ACCEL_REACH else None


def passed(r: dict[str, Any]) -> bool:
    """Exit 0, nothing beyond 4 sigma, nothing held beyond 3; on a table of
    :data:`EXPECT_REFUSAL` or a plan too weak for a raw unit (:func:`plan_reach`), the
    refusal (exit 3 naming why)."""
    refusal = expected_refusal(r['name'])
    if refusal:  # the self-check's refusal, or a divergence's line naming the plan
        return r['status'] in (2, 3) and refusal in r['last_stderr']
    return r['status'] == 0 and r.get('beyond4', 1) == 0 and not r.get('held_bad')


def line(r: dict[str, Any], k: int, n: int) -> str:
    head = f'[{k:2d}/{n}] {r["name"]:34s} exit {r["status"]}  {r["wall_s"]:5.1f} s'
    if r['status'] == 0:
        return (f'{head}  max|z| {r["max_z"]:.2f} ({r["max_z_param"]})  beyond 3 sigma '
                f'{r["beyond3"]}/{r["n_est"]}  NEES {r["nees"]:.0f}/{r["n_est"]}  '
                f'{"PASS" if passed(r) else "FAIL"}  [{r["described"]}]')
    return (f'{head}  {"REFUSED as expected" if passed(r) else "FAIL"}: {r["last_stderr"]}  '
            f'[{r["described"]}]')


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('cases', nargs='*', help='case names UNIT@FIXTURE_sSEED (default: all)')
    ap.add_argument('--seeds', type=int, default=2, help='seeds per unit and fixture')
    ap.add_argument('--units', default=','.join(UNITS))
    ap.add_argument('--fixtures', default=','.join(lab_motion.LAB_FIXTURES))
    ap.add_argument('--list', action='store_true', help='print the case names and exit')
    ap.add_argument('--out', default='/tmp/imu_calib_lab', help='bags and results')
    ap.add_argument('--repo', default=str(REPO), help='checkout the command runs')
    ap.add_argument('--jobs', type=int, default=1)
    a = ap.parse_args()
    names = a.cases or [f'{u}@{f}_s{s}' for s in range(a.seeds) for f in a.fixtures.split(',')
                        for u in a.units.split(',')]
    if a.list:
        print('\n'.join(names))
        return 0
    t0 = time.perf_counter()
    results: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        futs = [ex.submit(run, nm, a.out, a.repo) for nm in names]
        for k, f in enumerate(futs, 1):
            r = f.result()
            results.append(r)
            print(line(r, k, len(names)), flush=True)
    ok = [r for r in results if r['status'] == 0]
    n_est = sum(r['n_est'] for r in ok)
    print(f'SUMMARY lab: passed {sum(passed(r) for r in results)}/{len(results)}, exits non-zero '
          f'{sum(r["status"] != 0 for r in results)} (refused as expected '
          f'{sum(r["status"] != 0 and passed(r) for r in results)}), tracebacks '
          f'{sum(r["status"] == 1 for r in results)}, beyond 3 sigma '
          f'{sum(r["beyond3"] for r in ok)}/{n_est} (honest: {0.0027 * n_est:.1f}), '
          f'wall {(time.perf_counter() - t0) / 60:.1f} min')
    return 0 if all(passed(r) for r in results) else 1


if __name__ == '__main__':
    sys.exit(main())
