"""Replay speed of the calibration EKF (issue 3, item 7): samples/s and peak memory.

    python bench/bench_speed.py [--minutes 60] [--rate 200]

Simulates ``minutes`` of the random plan repeated (nav grade, all groups on), then times
``push_imu_batch`` in 4000-sample batches (the replay path) on one core.
"""
from __future__ import annotations

import argparse
import resource
import time
import tracemalloc

import numpy as np

from imu_calib_ros.core.estimator import CalibrationEstimator, EstimatorConfig
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.plans import build_profile, load_plan
from imu_calib_ros.core.simulator import SimConfig, simulate
from imu_calib_ros.core.types import ImuBatch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument('--minutes', type=float, default=60.0)
    ap.add_argument('--rate', type=float, default=200.0)
    a = ap.parse_args()
    fx = load_fixture('three_axis')
    grade = load_grade('nav_grade')
    prof = build_profile(load_plan('demo_short'), fx)
    sim = simulate(fx, prof, grade, SimConfig(imu_rate_hz=a.rate, seed=0))
    reps = max(1, int(np.ceil(a.minutes * 60 / prof.duration_s)))
    cfg = EstimatorConfig(estimate_time_offset=True)
    est = CalibrationEstimator(fx, grade, cfg)
    est.push_joint_batch(sim.joints)
    n = len(sim.imu)
    period = sim.imu.stamps_ns[1] - sim.imu.stamps_ns[0]
    tracemalloc.start()
    t0 = time.process_time()
    total = 0
    for r in range(reps):  # the same motion again, stamps shifted (the filter sees a long run)
        off = r * (n * period)
        for k in range(0, n, 4000):
            sl = slice(k, min(k + 4000, n))
            est.push_imu_batch(ImuBatch(sim.imu.stamps_ns[sl] + off, sim.imu.gyro_rad_s[sl],
                                        sim.imu.accel_m_s2[sl]))
            total += sl.stop - sl.start
        if r == 0:
            est._jt = est._jt[-2:]  # noqa: SLF001 - joints only needed for the alignment
            est._jq = est._jq[-2:]  # noqa: SLF001
    est.flush()
    cpu = time.process_time() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    h = est.health()
    data_s = total / a.rate
    print(f'states            {est.layout.n}')
    print(f'data              {data_s / 60:.1f} min at {a.rate:g} Hz = {total} samples')
    print(f'cpu time          {cpu:.2f} s  (1 h would take {cpu * 3600 / data_s:.1f} s; '
          'target <= 20 s)')
    print(f'samples/s         {total / cpu:,.0f}  (target >= 36,000)')
    print(f'real-time factor  {data_s / cpu:.0f}x  (target >= 180x)')
    print(f'peak traced mem   {peak / 1e6:.1f} MB;  max RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3:.0f} MB')
    print(f'covariance        min eigenvalue (scaled) {h["covariance_min_eigenvalue_scaled"]:.3g},'
          f' asymmetry {h["covariance_asymmetry"]:.1g}; mean NIS {h["mean_nis"]}')


if __name__ == '__main__':
    main()
