"""Speed and memory of the streaming Allan deviation (issue 13): 4 h at 2 kHz, target < 60 s.

    python bench/bench_noise.py [--hours 4] [--rate 2000] [--chunk 65536]

Generates the record in-process, chunk by chunk (28.8 million samples x 6 channels at the
defaults; never all in memory): white noise N, rate random walk K and quantisation Q with a
carry across chunks, and feeds :class:`~imu_calib_ros.core.allan.AllanAccumulator` as
``imu-calib noise`` does. Prints the CPU time of the accumulation alone (generation is timed
apart), the RSS after 10 % of the record and at the end (flat: the accumulator holds a few
phase points per level), the fit's N, K, Q against the truth with their 95 % intervals, and a
SUMMARY line against the target (CPU time: the machine is shared). The bag reader's own speed
at 2 kHz is bench_speed.py --reader's.
"""
from __future__ import annotations

import argparse
import math
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from imu_calib_ros.core.allan import AllanAccumulator  # noqa: E402
from imu_calib_ros.core.noise_characterisation import characterise  # noqa: E402

TRUTH = {'gyro': dict(N=1.2e-4, K=2e-6, Q=2e-6), 'accel': dict(N=1.2e-3, K=2e-5, Q=2e-5)}


def rss_mb() -> float:
    with open('/proc/self/statm') as fh:
        return int(fh.read().split()[1]) * resource.getpagesize() / 2 ** 20


class Generator:
    """White + random walk + quantisation, in chunks, with state carried across them."""

    def __init__(self, tau0: float, seed: int) -> None:
        self.tau0 = tau0
        self.rng = np.random.default_rng(seed)
        self.walk = np.zeros(6)
        self.e_last = np.zeros(6)
        t = [TRUTH['gyro']] * 3 + [TRUTH['accel']] * 3
        self.N = np.array([x['N'] for x in t])
        self.K = np.array([x['K'] for x in t])
        self.Q = np.array([x['Q'] for x in t])

    def chunk(self, n: int) -> np.ndarray:
        r = self.rng
        y = r.standard_normal((n, 6)) * (self.N / math.sqrt(self.tau0))
        w = np.cumsum(r.standard_normal((n, 6)) * (self.K * math.sqrt(self.tau0)), axis=0)
        w += self.walk
        self.walk = w[-1].copy()
        e = r.uniform(-1.0, 1.0, (n, 6)) * (math.sqrt(3.0) * self.Q)
        q = np.diff(np.vstack([self.e_last, e]), axis=0) / self.tau0
        self.e_last = e[-1].copy()
        return y + w + q


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--hours', type=float, default=4.0)
    ap.add_argument('--rate', type=float, default=2000.0)
    ap.add_argument('--chunk', type=int, default=65536)
    ap.add_argument('--seed', type=int, default=1)
    a = ap.parse_args()
    tau0 = 1.0 / a.rate
    total = int(round(a.hours * 3600 * a.rate))
    gen = Generator(tau0, a.seed)
    acc = AllanAccumulator(tau0, 6)
    t_gen = t_acc = 0.0
    rss_10 = None
    done = 0
    while done < total:
        n = min(a.chunk, total - done)
        c0 = time.process_time()
        y = gen.chunk(n)
        c1 = time.process_time()
        acc.add(y)
        t_acc += time.process_time() - c1
        t_gen += c1 - c0
        done += n
        if rss_10 is None and done >= total // 10:
            rss_10 = rss_mb()
    c1 = time.process_time()
    result = characterise(acc.curve(), 'static record (bench)')
    t_fit = time.process_time() - c1
    rss_end = rss_mb()
    print(f'{total} samples x 6 channels ({a.hours:g} h at {a.rate:g} Hz), chunks of {a.chunk}')
    print(f'generation {t_gen:.1f} s CPU (not counted); Allan accumulation {t_acc:.1f} s CPU '
          f'({total / t_acc / 1e6:.2f} M samples/s); fit {t_fit:.2f} s')
    print(f'RSS after 10 %: {rss_10:.0f} MB, at the end: {rss_end:.0f} MB; peak '
          f'{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB')
    for sensor, col in (('gyro', 0), ('accel', 3)):
        for term, true in TRUTH[sensor].items():
            cells = []
            for ax in range(3):
                tf = result.fits[col + ax].terms[term]
                ok = tf.shown and tf.low <= true <= tf.high
                cells.append(f'{tf.value / true:.3f} [{tf.low / true:.3f}, {tf.high / true:.3f}]'
                             f'{"" if ok else " OUT"}' if tf.shown else 'not shown')
            print(f'  {sensor:5s} {term}/truth: ' + ' | '.join(cells))
    for w in result.warnings():
        print(f'  warning: {w}')
    t = t_acc + t_fit
    print(f'SUMMARY noise 4h@2kHz: {t:.1f} s CPU (accumulate + fit) vs target 60 s: '
          f'{"PASS" if t < 60 else "FAIL"}; RSS growth {rss_end - rss_10:+.0f} MB')
    return 0


if __name__ == '__main__':
    sys.exit(main())
