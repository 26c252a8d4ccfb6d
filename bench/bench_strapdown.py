"""Throughput of Strapdown.propagate [IMU samples/s] for batches of 20, 200 and 2000 samples.

The estimator (issue 3) must reach >= 36,000 samples/s overall, so the navigator alone has
to be well above that at the batch sizes it uses.
Run: ``.venv/bin/python bench/bench_strapdown.py``.
"""
from __future__ import annotations

import time

import numpy as np

from imu_calib_ros.core.earth import Site
from imu_calib_ros.core.strapdown import Strapdown

RATE_HZ = 200.0
TOTAL_SAMPLES = 40_000
TARGET_SAMPLES_S = 36_000.0


def run(batch: int, total: int = TOTAL_SAMPLES, repeats: int = 3) -> float:
    """Best-of-``repeats`` throughput [samples/s] pushing ``total`` samples in ``batch`` chunks."""
    rng = np.random.default_rng(0)
    site = Site(55.7, 200.0)
    gyro = rng.normal(0.0, 0.5, (total, 3))
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.1, (total, 3))
    dt = np.full(total, 1.0 / RATE_HZ)
    best = 0.0
    for _ in range(repeats):
        nav = Strapdown(site, np.eye(3))
        t0 = time.perf_counter()
        for i in range(0, total, batch):
            nav.propagate(dt[i:i + batch], gyro[i:i + batch], accel[i:i + batch])
        best = max(best, total / (time.perf_counter() - t0))
    return best


def main() -> None:
    figures = {}
    for batch in (1, 20, 200, 2000):
        figures[batch] = run(batch, total=TOTAL_SAMPLES if batch > 1 else 4000)
        print(f'batch {batch:5d}: {figures[batch]:12,.0f} samples/s')
    ok = all(figures[b] >= TARGET_SAMPLES_S for b in (200, 2000))
    print(f'strapdown: {figures[20]:,.0f} / {figures[200]:,.0f} / {figures[2000]:,.0f} samples/s '
          f'at batch 20/200/2000 (target >= {TARGET_SAMPLES_S:,.0f} for the whole estimator): '
          f'{"OK" if ok else "TOO SLOW"}')


if __name__ == '__main__':
    main()
