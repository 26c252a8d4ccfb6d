"""Replay speed of the calibration EKF (issue 3, items 4 and 7): samples/s, memory, P health.

    python bench/bench_speed.py [--minutes 60] [--rate 200] [--batch 4000] [--no-joints]
                                [--tracemalloc]

Simulates the ``demo_short`` plan, closed into a loop, once (nav grade, three-axis fixture)
and replays it again and again with shifted stamps until ``minutes`` of data have gone through
``CalibrationEstimator`` with every group estimated (46 states incl. the time offset): per
repetition the joint states (``push_joint_batch``, as a bag replay delivers them) and the IMU
samples in ``batch``-sample batches (``push_imu_batch``). Not a test: it prints figures.

Time is CPU time of this process (``time.process_time``; the machine is shared, so wall time
is printed too but is not the figure of merit). Memory: resident set size after the first
repetition and at the end (must not grow with the length of the data) and the peak RSS;
``--tracemalloc`` also traces Python allocations in a separate, untimed run of two
repetitions (tracemalloc slows numpy-heavy code ~3x: never time with it on).
Covariance health (issue 3 item 4): at the end of every repetition the minimum eigenvalue of
the scaled ``P`` and of its correlation matrix and the largest asymmetry ``|P - P^T|``.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import time
import tracemalloc
from typing import Any

import numpy as np

from imu_calib_ros.core.estimator import CalibrationEstimator, EstimatorConfig
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.config import load_yaml, resolve_config_file
from imu_calib_ros.core.plans import build_profile, plan_from_dict
from imu_calib_ros.core.simulator import SimConfig, simulate
from imu_calib_ros.core.types import ImuBatch

TARGET_SAMPLES_S = 36_000.0  # issue 3 item 7: 1 h of 200 Hz in <= 20 s


def rss_mb() -> float:
    """Current resident set size [MB] (Linux /proc; peak RSS elsewhere)."""
    try:
        with open('/proc/self/statm') as fh:
            return int(fh.read().split()[1]) * os.sysconf('SC_PAGE_SIZE') / 1e6
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6


def covariance_health(P: np.ndarray) -> tuple[float, float, float, float, float]:
    """(min eigenvalue of P, of its correlation matrix, max |P - P^T|, max |P|, condition
    number of P) for the scaled P."""
    d = np.sqrt(np.diag(P))
    corr = P / np.outer(d, d)
    ev = np.linalg.eigvalsh(0.5 * (P + P.T))
    return (float(ev.min()), float(np.linalg.eigvalsh(0.5 * (corr + corr.T)).min()),
            float(np.abs(P - P.T).max()), float(np.abs(P).max()), float(ev.max() / ev.min()))


def loop_plan() -> Any:
    """``demo_short`` plus two moves back to its start pose (joints equal modulo 360 deg), so
    that repetitions join into one continuous motion (a jump would make the filter diverge)."""
    data = dict(load_yaml(resolve_config_file('demo_short', 'plans')))
    data['steps'] = list(data['steps']) + [
        {'move': {'joint': 'outer', 'by_deg': 90.0, 'duration_s': 4.0}},
        {'move': {'joint': 'inner', 'by_deg': 180.0, 'duration_s': 4.0}},
        {'dwell': {'duration_s': 2.0}}]
    data['name'] = 'demo_short_loop'
    return plan_from_dict(data, 'bench_speed:demo_short_loop')


def replay(sim: Any, fx: Any, grade: Any, reps: int, batch: int, joints: bool,
           on_rep: Any = None) -> tuple[CalibrationEstimator, int]:
    """Push ``reps`` copies of the simulated data (stamps shifted); returns (estimator, n)."""
    est = CalibrationEstimator(fx, grade, EstimatorConfig(estimate_time_offset=True))
    imu, jb = sim.imu, sim.joints
    n = len(imu)
    period = int(imu.stamps_ns[1] - imu.stamps_ns[0])
    total = 0
    for r in range(reps):  # the same motion again: the filter sees one long run
        off = r * n * period
        if joints or r == 0:  # joints at least once: the alignment needs them
            j0 = 1 if r else 0  # the first joint sample repeats the last one's stamp
            est.push_joint_batch(dataclasses.replace(
                jb, stamps_ns=jb.stamps_ns[j0:] + off, positions_rad=jb.positions_rad[j0:],
                velocities_rad_s=None if jb.velocities_rad_s is None
                else jb.velocities_rad_s[j0:]))
        for k in range(0, n, batch):
            sl = slice(k, min(k + batch, n))
            est.push_imu_batch(ImuBatch(imu.stamps_ns[sl] + off, imu.gyro_rad_s[sl],
                                        imu.accel_m_s2[sl]))
            total += sl.stop - sl.start
        if on_rep is not None:
            on_rep(r, est)
    est.flush()
    return est, total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--minutes', type=float, default=60.0, help='length of data to replay')
    ap.add_argument('--rate', type=float, default=200.0, help='IMU rate [Hz]')
    ap.add_argument('--batch', type=int, default=4000, help='IMU samples per push')
    ap.add_argument('--no-joints', action='store_true',
                    help='push the joint states only once (IMU path alone)')
    ap.add_argument('--tracemalloc', action='store_true',
                    help='also trace Python allocations (separate untimed run)')
    a = ap.parse_args()
    fx = load_fixture('three_axis')
    grade = load_grade('nav_grade')
    prof = build_profile(loop_plan(), fx)
    sim = simulate(fx, prof, grade, SimConfig(imu_rate_hz=a.rate, seed=0))
    reps = max(1, int(np.ceil(a.minutes * 60 / prof.duration_s)))
    health: list[tuple[float, float, float, float, float]] = []
    rss: list[float] = []

    def on_rep(r: int, est: CalibrationEstimator) -> None:
        rss.append(rss_mb())
        if est._filter is not None:  # noqa: SLF001 - benchmark of the filter internals
            health.append(covariance_health(est._filter.P))  # noqa: SLF001

    health_cpu = 0.0

    def timed_on_rep(r: int, est: CalibrationEstimator) -> None:
        nonlocal health_cpu
        t = time.process_time()
        on_rep(r, est)
        health_cpu += time.process_time() - t  # not part of the replay: subtracted

    wall0 = time.perf_counter()
    cpu0 = time.process_time()
    est, total = replay(sim, fx, grade, reps, a.batch, not a.no_joints, timed_on_rep)
    cpu = time.process_time() - cpu0 - health_cpu
    wall = time.perf_counter() - wall0
    on_rep(reps, est)
    h = est.health()
    data_s = total / a.rate
    hour_s = cpu * 3600.0 / data_s * (a.rate / 200.0)
    mn_eig = min(x[0] for x in health)
    mn_corr = min(x[1] for x in health)
    asym = max(x[2] for x in health)
    rel_asym = max(x[2] / x[3] for x in health)
    cond = max(x[4] for x in health)
    print(f'states            {est.layout.n} ({", ".join(est.layout.groups)})')
    when = 'once' if a.no_joints else 'every repetition'
    print(f'data              {data_s / 60:.1f} min at {a.rate:g} Hz = {total} IMU samples '
          f'({reps} x {prof.duration_s:.0f} s), joints {when}, batches of {a.batch}')
    print(f'cpu time          {cpu:.2f} s (wall {wall:.2f} s on a shared machine)')
    print(f'1 h at 200 Hz     {hour_s:.1f} s cpu  (target <= 20 s)')
    print(f'samples/s         {total / cpu:,.0f} cpu, {total / wall:,.0f} wall  '
          f'(target >= {TARGET_SAMPLES_S:,.0f})')
    print(f'real-time factor  {data_s / cpu:.0f}x  (target >= 180x)')
    print(f'memory            RSS {rss[0]:.0f} MB after repetition 1, {rss[-1]:.0f} MB at the '
          f'end (growth {rss[-1] - rss[0]:+.1f} MB over {reps - 1} repetitions); peak RSS '
          f'{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6:.0f} MB (incl. the '
          'simulated data)')
    print(f'covariance        over {len(health)} checks: min eigenvalue of scaled P {mn_eig:.3g},'
          f' of its correlation matrix {mn_corr:.3g} (> 0: positive definite), condition '
          f'number <= {cond:.2g}; max |P - P^T| {asym:.2g} (relative {rel_asym:.1g}; P is '
          'symmetrised after every update)')
    print(f'filter            gate accepted {h.get("gate_accepted", h.get("accepted"))}, '
          f'rejected {h.get("gate_rejected")}; mean NIS {h.get("mean_nis")}')
    if a.tracemalloc:
        tracemalloc.start()
        replay(sim, fx, grade, min(reps, 2), a.batch, not a.no_joints)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        print(f'tracemalloc       peak traced {peak / 1e6:.1f} MB over {min(reps, 2)} '
              'repetitions (untimed)')
    ok = hour_s <= 20.0 and mn_eig > 0.0 and mn_corr > 0.0
    print(f'SUMMARY {"PASS" if ok else "FAIL"}: {total / cpu:,.0f} IMU samples/s cpu '
          f'({data_s / cpu:.0f}x real time, 1 h of 200 Hz in {hour_s:.1f} s), RSS growth '
          f'{rss[-1] - rss[0]:+.1f} MB, P positive definite (min corr. eigenvalue '
          f'{mn_corr:.2g}), max asymmetry {asym:.1g}')


if __name__ == '__main__':
    main()
