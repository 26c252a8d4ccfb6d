"""Replay speed of the calibration EKF (issue 3, items 4 and 7): samples/s, memory, P health.

    python bench/bench_speed.py [--minutes 60] [--rate 200] [--batch 4000] [--no-joints]
                                [--tracemalloc]
    python bench/bench_speed.py --bag [--minutes 60] [--rate 200|2000] [--passes read,1,cli,2]
    python bench/bench_speed.py --reader [--minutes 5]
    python bench/bench_speed.py --startup [--runs 7]

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

``--bag`` (end to end, issue 3 item 7 as a user meets it): the same repeated data written
once to an mcap bag (cached in ``/tmp``, keyed by minutes and rate) and replayed from the bag
the way ``imu-calib replay`` does it: first one pass of ``replay.replay`` over
``iter_bag(bag)``, then the CLI itself (``imu-calib replay BAG ... --quiet``) with its defaults
(one pass; ``--passes 1,cli,2`` adds a two-pass run), all with every group estimated (incl.
the time offset). Prints CPU and wall time, samples/s, RSS sampled during the replay (after
10 % of the bag and at the end: it must not grow with the bag's length), the peak RSS of the
process, and a SUMMARY line per run against issue 14's targets (one hour of 200 Hz in <= 5 s,
of 2 kHz in <= 30 s). ``--passes read`` times the bag reader alone
(``iter_bag(bag).batches()``, what replay reads): the reader's share of the end-to-end
figure. Once the bag is cached, nothing is simulated.

``--reader`` (issue 17): the bag reader alone on a 2 kHz bag (IMU 2 kHz, joint states 100
Hz, cached in ``/tmp``), written twice: log time = header stamp (``write_bag``), and as
rosbag2 records, log time = stamp + 1.5..2.5 ms (12.6 % of the IMU messages behind a newer
stamp). Prints the CPU time of ``read_bag``, ``iter_bag(bag).batches()`` (what replay reads)
and ``iter_bag`` sample by sample on each, in messages per second, with the reorder counts.

``--startup`` (issue 14 item 4): ``imu-calib --help`` and ``imu-calib replay --help`` as a user
runs them, each a new ``python -m imu_calib_ros`` process, ``--runs`` times: the median CPU
time of the child (user + system, ``resource.RUSAGE_CHILDREN``) and a SUMMARY line against the
target (< 0.5 s).
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import resource
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np

from imu_calib_ros.core.estimator import CalibrationEstimator, EstimatorConfig
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.config import load_yaml, resolve_config_file
from imu_calib_ros.core.plans import build_profile, plan_from_dict
from imu_calib_ros.core.simulator import SimConfig, simulate
from imu_calib_ros.core.types import ImuBatch, JointBatch

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


def write_hour_bag(sim: Any, reps: int, path: Path) -> None:
    """Write ``reps`` stamp-shifted copies of the simulated data to one mcap bag, repetition
    by repetition (bounded memory; the same stream ``replay`` pushes in the default mode)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from msg_adapters import bag as bagmod, cdr
    from msg_adapters.convert import IMU_MSGTYPE, JOINT_STATE_MSGTYPE
    store = bagmod._typestore()  # noqa: SLF001 - the typestore the bag module uses
    imu, jb = sim.imu, sim.joints
    n = len(imu)
    period = int(imu.stamps_ns[1] - imu.stamps_ns[0])
    tmp = path.with_name(path.name + f'.partial-{os.getpid()}')
    with tempfile.TemporaryDirectory(dir=path.parent) as d:
        bagdir = Path(d) / path.stem
        w = Writer(bagdir, version=9, storage_plugin=StoragePlugin.MCAP)
        w.open()
        c_imu = w.add_connection('/imu/data_raw', IMU_MSGTYPE, typestore=store)
        c_j = w.add_connection('/joint_states', JOINT_STATE_MSGTYPE, typestore=store)
        for r in range(reps):
            off = r * n * period
            j0 = 1 if r else 0
            ib = ImuBatch(imu.stamps_ns + off, imu.gyro_rad_s, imu.accel_m_s2, 'imu_link')
            jr = JointBatch(jb.stamps_ns[j0:] + off, jb.names, jb.positions_rad[j0:],
                            None if jb.velocities_rad_s is None else jb.velocities_rad_s[j0:])
            rows = cdr.pack_imu(ib.stamps_ns, ib.gyro_rad_s, ib.accel_m_s2, 'imu_link',
                                np.zeros(9), np.zeros(9))
            jraw = [cdr.joint_state_cdr(x.stamp_ns, '', x.names, x.positions_rad,
                                        () if x.velocities_rad_s is None else x.velocities_rad_s)
                    for x in jr]
            st = np.concatenate([jr.stamps_ns, ib.stamps_ns])  # joints first on equal stamps
            for k in np.argsort(st, kind='stable').tolist():
                if k < len(jr):
                    w.write(c_j, int(st[k]), jraw[k])
                else:
                    w.write(c_imu, int(st[k]), rows[k - len(jr)].tobytes())
        w.close()
        os.rename(next(bagdir.glob('*.mcap')), tmp)
    os.rename(tmp, path)


#: issue 14 item 4: CPU seconds for one hour of data, end to end from a bag, by IMU rate
HOUR_TARGET_S = {200.0: 5.0, 2000.0: 30.0}


def bench_bag(a: Any, fx: Any, grade: Any, make_sim: Any) -> None:
    """End-to-end mode (``--bag``): replay from an mcap bag, one pass and the CLI default;
    ``read``: the bag reader alone (what replay reads: ``iter_bag(bag).batches()``)."""
    from imu_calib_ros.cli import main as cli_main
    from imu_calib_ros.core.estimator.replay import replay as replay_bag
    from msg_adapters.bag import iter_bag, list_topics
    path = Path(tempfile.gettempdir()) / f'imu_calib_bench_{a.minutes:g}min_{a.rate:g}hz.mcap'
    if not path.exists():
        t = time.perf_counter()
        write_hour_bag(*make_sim(), path)
        print(f'wrote {path} ({path.stat().st_size / 1e6:.0f} MB) in '
              f'{time.perf_counter() - t:.0f} s (cached for later runs)')
    else:
        print(f'using cached {path} ({path.stat().st_size / 1e6:.0f} MB)')
    n_total = list_topics(path)['/imu/data_raw'].count
    data_s = n_total / a.rate
    target = HOUR_TARGET_S.get(a.rate)
    cfg = EstimatorConfig(estimate_time_offset=True)
    rss: list[tuple[int, float]] = []
    seen = 0

    def progress(k: int) -> None:
        nonlocal seen
        seen += k
        if not rss or seen - rss[-1][0] >= n_total // 20:
            rss.append((seen, rss_mb()))

    results = []
    for run in a.passes.split(','):
        rss.clear()
        seen = 0
        wall0, cpu0 = time.perf_counter(), time.process_time()
        est = None
        if run == 'read':
            passes = 0
            n_read = sum(len(b) for b in iter_bag(path).batches() if hasattr(b, 'gyro_rad_s'))
            assert n_read == n_total, (n_read, n_total)
            what = 'bag read alone: iter_bag(bag).batches() (what replay reads)'
        elif run == '1':
            passes = 1
            est = replay_bag(lambda: iter_bag(path), fx, grade, cfg, 1, progress=progress)
            what = 'replay.replay(iter_bag(bag)), 1 pass'
        else:
            yaml = Path(tempfile.gettempdir()) / 'imu_calib_bench_estimator.yaml'
            yaml.write_text('estimate_time_offset: true\n')
            out = Path(tempfile.gettempdir()) / 'imu_calib_bench_calib.yaml'
            extra = [] if run == 'cli' else ['--iterations', run]
            passes = 1 if run == 'cli' else int(run)
            # --force: the data are one simulated loop replayed with shifted stamps, so the
            # truth's bias walk jumps back at every join and the self-check (rightly) sees
            # stationary windows that disagree (4.8 sigma along gyro_asymmetry[2], on the
            # code before issue 11's session 4 too); this run times the command, the
            # self-check's verdict on real data is bench_selfcheck's
            rc = cli_main(['replay', str(path), '--fixture', 'three_axis', '--imu', 'nav_grade',
                           '--config', str(yaml), '--output', str(out), '--quiet', '--force',
                           *extra])
            assert rc == 0, rc
            what = ('imu-calib replay (CLI defaults: 1 pass, in process)' if run == 'cli'
                    else f'imu-calib replay --iterations {passes} (CLI, in process)')
        cpu = time.process_time() - cpu0
        wall = time.perf_counter() - wall0
        hour = cpu * 3600.0 / data_s
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6
        print(f'--- {what}')
        print(f'data              {data_s / 60:.1f} min at {a.rate:g} Hz = {n_total} IMU samples '
              f'x {passes} pass(es), from {path.name}')
        print(f'cpu time          {cpu:.2f} s (wall {wall:.2f} s on a shared machine)')
        print(f'samples/s         {n_total / cpu:,.0f} cpu, {n_total / wall:,.0f} wall '
              f'(bag samples per second of the whole run; target >= {TARGET_SAMPLES_S:,.0f})')
        if rss:
            i10 = min(range(len(rss)), key=lambda i: abs(rss[i][0] - n_total // 10))
            print(f'memory            RSS {rss[i10][1]:.0f} MB after {rss[i10][0]} samples, '
                  f'{rss[-1][1]:.0f} MB at {rss[-1][0]} (growth {rss[-1][1] - rss[i10][1]:+.1f}'
                  f' MB); peak RSS of the process {peak:.0f} MB')
        else:
            print(f'memory            peak RSS of the process {peak:.0f} MB')
        if est is not None:
            h = est.health()
            print(f'filter            gate accepted {h.get("gate_accepted")}, rejected '
                  f'{h.get("gate_rejected")}, status {h["status"]}')
        results.append((passes, hour, cpu, wall))
        if run == 'read':
            print(f'SUMMARY reader: 1 h of {a.rate:g} Hz read in {hour:.2f} s cpu, '
                  f'{n_total / cpu:,.0f} IMU samples/s cpu, wall {wall:.1f} s')
            continue
        verdict = 'INFO' if target is None else 'PASS' if hour <= target else 'FAIL'
        goal = f' (target <= {target:g} s)' if target is not None else ''
        print(f'SUMMARY {verdict}: end to end from a bag, {passes} pass(es): 1 h of '
              f'{a.rate:g} Hz in {hour:.1f} s cpu{goal}, {n_total / cpu:,.0f} bag IMU '
              f'samples/s cpu ({n_total * passes / cpu:,.0f} pushed), wall {wall:.1f} s')


#: issue 14 item 4: CPU seconds for ``imu-calib --help``
HELP_TARGET_S = 0.5


def bench_startup(runs: int) -> None:
    """``--startup``: CPU time of ``imu-calib [replay] --help`` in a new process (median)."""
    import statistics
    import subprocess
    import sys
    for args in (['--help'], ['replay', '--help']):
        cpu = []
        for _ in range(runs):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            subprocess.run([sys.executable, '-m', 'imu_calib_ros', *args], check=True,
                           stdout=subprocess.DEVNULL)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
        med = statistics.median(cpu)
        what = 'imu-calib ' + ' '.join(args)
        print(f'--- {what}: cpu {min(cpu):.3f} / {med:.3f} / {max(cpu):.3f} s (min / median / '
              f'max of {runs} processes)')
        print(f'SUMMARY {"PASS" if med < HELP_TARGET_S else "FAIL"}: {what} in {med:.3f} s cpu '
              f'(median; target < {HELP_TARGET_S:g} s)')


def reader_bags(minutes: float) -> tuple[Path, Path]:
    """The ordered and the receipt-jitter 2 kHz bags of ``--reader`` (cached in /tmp)."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer
    from msg_adapters import bag as bagmod
    d = Path(tempfile.gettempdir()) / f'imu_calib_bench_reader_{minutes:g}min'
    ordered, jittered = d / 'ordered.mcap', d / 'rosbag2_like.mcap'
    if ordered.exists() and jittered.exists():
        return ordered, jittered
    d.mkdir(exist_ok=True)
    rng = np.random.default_rng(0)
    n, nj = int(minutes * 60 * 2000), int(minutes * 60 * 100)
    t0 = 1_700_000_000_000_000_000
    imu = ImuBatch(t0 + 500_000 * np.arange(1, n + 1, dtype=np.int64),
                   rng.normal(0, 1e-3, (n, 3)), rng.normal([0, 0, 9.8], 1e-3, (n, 3)),
                   'imu_link')
    joints = JointBatch(t0 + 10_000_000 * np.arange(1, nj + 1, dtype=np.int64),
                        ('outer', 'middle', 'inner'), rng.uniform(-3, 3, (nj, 3)))
    bagmod.write_bag(ordered, imu, joints, overwrite=True)
    with Reader(ordered) as r:
        msgs = [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in r.messages()]
    log = np.array([m[2] for m in msgs], np.int64) + rng.integers(1_500_000, 2_500_001,
                                                                  len(msgs))
    with tempfile.TemporaryDirectory(dir=d) as tmp:
        w = Writer(Path(tmp) / 'b', version=9, storage_plugin=StoragePlugin.MCAP)
        w.open()
        conns = {topic: w.add_connection(topic, mt, typestore=bagmod._typestore())  # noqa
                 for topic, mt in {(m[0], m[1]) for m in msgs}}
        for k in np.argsort(log, kind='stable').tolist():
            w.write(conns[msgs[k][0]], int(log[k]), msgs[k][3])
        w.close()
        os.rename(next((Path(tmp) / 'b').glob('*.mcap')), jittered)
    return ordered, jittered


def bench_reader(minutes: float) -> None:
    """``--reader``: CPU time of the bag read paths on a 2 kHz bag, ordered and jittered."""
    from msg_adapters.bag import iter_bag, read_bag
    for path in reader_bags(minutes):
        for name, run in (('read_bag', lambda: len(read_bag(path)[0])),
                          ('iter_bag().batches()',
                           lambda: sum(len(b) for b in iter_bag(path).batches())),
                          ('iter_bag (samples)', lambda: sum(1 for _ in iter_bag(path)))):
            cpu = []
            for _ in range(3):
                c0 = time.process_time()
                n = run()
                cpu.append(time.process_time() - c0)
            print(f'{path.name:18s} {name:22s} {n} msgs  cpu {min(cpu):6.2f} s (best of 3)  '
                  f'{n / min(cpu):,.0f} msgs/s')
        src = iter_bag(path)
        for _ in src.batches():
            pass
        for topic, st in src.reorder_stats.items():
            print(f'{path.name:18s} {topic}: {st.describe()}')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--minutes', type=float, default=60.0, help='length of data to replay')
    ap.add_argument('--rate', type=float, default=200.0, help='IMU rate [Hz]')
    ap.add_argument('--batch', type=int, default=4000, help='IMU samples per push')
    ap.add_argument('--no-joints', action='store_true',
                    help='push the joint states only once (IMU path alone)')
    ap.add_argument('--tracemalloc', action='store_true',
                    help='also trace Python allocations (separate untimed run)')
    ap.add_argument('--bag', action='store_true',
                    help='end to end: write the data to an mcap bag (cached in /tmp) and time '
                         'the replay from it')
    ap.add_argument('--passes', default='1,cli',
                    help="with --bag: comma-separated runs to time: 'read' = the bag reader "
                         "alone; '1' = replay.replay, one "
                         "pass (RSS sampled); 'cli' = the CLI with its defaults (one pass); "
                         "N > 1 = the CLI with --iterations N (default '1,cli')")
    ap.add_argument('--reader', action='store_true',
                    help='time the bag reader alone on a 2 kHz bag, log time = stamp and '
                         'rosbag2-like (log time = receipt time); --minutes default 5')
    ap.add_argument('--startup', action='store_true',
                    help='time imu-calib --help (and replay --help), each a new process')
    ap.add_argument('--runs', type=int, default=7, help='with --startup: processes per command')
    a = ap.parse_args()
    if a.startup:
        bench_startup(a.runs)
        return
    if a.reader:
        bench_reader(a.minutes if a.minutes != 60.0 else 5.0)
        return
    fx = load_fixture('three_axis')
    grade = load_grade('nav_grade')
    prof = build_profile(loop_plan(), fx)
    reps = max(1, int(np.ceil(a.minutes * 60 / prof.duration_s)))
    if a.bag:  # the simulation only when the bag is not cached yet
        bench_bag(a, fx, grade, lambda: (simulate(fx, prof, grade, SimConfig(
            imu_rate_hz=a.rate, seed=0)), reps))
        return
    sim = simulate(fx, prof, grade, SimConfig(imu_rate_hz=a.rate, seed=0))
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
