"""Accuracy and honesty of the calibration EKF (issue 3, item 6): simulate, replay, compare.

    python bench/bench_accuracy.py [--cases nav,mems,mems-stable,random,mc] [--seed 1]
                                   [--iterations 1] [--nav-rate 200] [--mems-rate 100]
                                   [--mc-seeds 20] ...

Cases (each prints a per-parameter table and a one-line ``SUMMARY`` per case):

``nav``
    navigation grade (config/imus/nav_grade.yaml), ``--nav-rate`` Hz, plan ``--nav-plan``
    (default srt_kozlov_bias: SRT, Kozlov, 6 x 120 s static) on
    config/fixtures/three_axis.yaml, config/estimator.yaml,
    against the issue-3 targets: gyro scale <= 1 ppm, gyro misalignment <= 1 urad, accel
    misalignment <= 2 urad, accel bias <= 2 ug, accel scale <= 5 ppm, asymmetries <= 5 ppm,
    size effect <= 0.1 mm (error AND sigma), gyro bias sigma <= 0.005 deg/h.
``mems``
    MEMS grade (config/imus/mems_mti1.yaml), ``--mems-rate`` Hz, savage_srt, encoder aiding
    (config/estimator_mems.yaml): gyro bias <= 2 deg/h, accel bias <= 0.3 mg, scale <= 300 ppm,
    misalignment <= 300 urad. The gyro-bias target is below what the grade's 10 deg/h in-run
    bias instability allows (the bench prints that floor);
``mems-stable``
    the ``mems`` case on the same unit without its gyro bias instability: shows that the
    estimator itself reaches the <= 2 deg/h target (the angle-random-walk limit).
``random``
    ``plans.random_plan(seed)`` (random moves of random joints, random dwells), as long as the
    designed plan ``--random-vs`` (default demo_short), both at ``--random-rate`` Hz, nav
    grade: per-group sigma ratio random/designed and the honesty of both runs.
``mc``
    ``--mc-seeds`` Monte-Carlo runs (true errors, noise and mounting drawn per seed) of
    ``--mc-plan`` (default demo_short) at ``--mc-rate`` Hz: the average NEES of the calibration
    states (all states but psi, dv) against its two-sided 95 % chi-square band
    (M * mean NEES ~ chi2(M n)), and the fraction of |error/sigma| > 3.

Replay is the CLI's: ``core.estimator.replay.replay`` over the samples merged in stamp order,
``--iterations`` passes (Savage sect. 8). Truth of the bias states is the constant plus the
simulated Gauss-Markov drift at the end of the run (the filter tracks the total bias). This is
not a timed test; the nav case takes a few minutes on this machine.
"""
from __future__ import annotations

import argparse
import time
import dataclasses
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np
from scipy.stats import chi2

from imu_calib_ros.core.estimator import CalibrationEstimator, load_estimator_config
from imu_calib_ros.core.estimator import error_model as em
from imu_calib_ros.core.estimator.estimator import prior_sigmas
from imu_calib_ros.core.estimator.truth import calibration_truth as truth_vector
from imu_calib_ros.core.estimator.replay import replay
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.plans import build_profile, load_plan, random_plan
from imu_calib_ros.core.simulator import SimConfig, SimResult, simulate

# group -> (target in the group's engineering unit, what must meet it: 'both' = error and sigma)
NAV_TARGETS: dict[str, tuple[float, str]] = {
    'gyro_scale': (1.0, 'both'), 'gyro_misalignment': (1.0, 'both'),
    'accel_misalignment': (2.0, 'both'), 'accel_bias': (2.0, 'both'),
    'accel_scale': (5.0, 'both'), 'gyro_asymmetry': (5.0, 'both'),
    'accel_asymmetry': (5.0, 'both'), 'size_effect': (0.1, 'both'),
    'gyro_bias': (0.005, 'sigma'),
}
MEMS_TARGETS: dict[str, tuple[float, str]] = {
    'gyro_bias': (2.0 * 1.0, 'both'),  # deg/h
    'accel_bias': (300.0, 'both'),  # 0.3 mg in ug
    'gyro_scale': (300.0, 'both'), 'accel_scale': (300.0, 'both'),  # ppm
    'gyro_misalignment': (300.0, 'both'), 'accel_misalignment': (300.0, 'both'),  # urad
}


def mems_gyro_bias_target_deg_h(grade: Any) -> float:
    """Issue 3's MEMS gyro-bias target as the owner restated it: at the floor the unit's own
    in-run instability allows (:func:`imu_calib_ros.core.estimator.noise.gyro_bias_floor_rad_s`,
    1.5x for a filter that estimates 50 states besides, as bench_robustness.py allows), and
    ``MEMS_TARGETS['gyro_bias']`` (2 deg/h) on a unit whose noise allows it."""
    from imu_calib_ros.core.estimator.noise import gyro_bias_floor_rad_s
    return max(MEMS_TARGETS['gyro_bias'][0], 1.5 * gyro_bias_floor_rad_s(grade) / em.DEG_H)


AUX_UNITS = {'lever_arm': (em.MM, 'mm'), 'mounting': (em.URAD, 'urad')}


@dataclass
class RunResult:
    """One simulated + replayed run."""

    est: CalibrationEstimator
    sim: SimResult
    labels: list[str]
    groups: list[str]
    truth: np.ndarray  # SI, calibration states
    value: np.ndarray
    sigma: np.ndarray
    cov: np.ndarray
    sim_s: float
    replay_s: float

    @property
    def err(self) -> np.ndarray:
        return self.value - self.truth

    @property
    def z(self) -> np.ndarray:
        return self.err / self.sigma

    @property
    def nees(self) -> float:
        e = self.err
        return float(e @ np.linalg.solve(self.cov, e))




def merged_samples(sim: SimResult) -> Iterator[Any]:
    """IMU and joint samples in stamp order (joints first on ties), like a bag."""
    ti, tj = sim.imu.stamps_ns, sim.joints.stamps_ns
    stamps = np.concatenate([tj, ti])
    kind = np.concatenate([np.zeros(len(tj), np.int8), np.ones(len(ti), np.int8)])
    idx = np.concatenate([np.arange(len(tj)), np.arange(len(ti))])
    order = np.lexsort((kind, stamps))
    for k in order:
        yield sim.imu.sample(int(idx[k])) if kind[k] else sim.joints.sample(int(idx[k]))


def run_case(grade_name: str, plan: Any, rate_hz: float, est_config: str, seed: int,
             iterations: int) -> RunResult:
    """Simulate ``plan`` on three_axis with ``grade_name`` and replay it."""
    fx = load_fixture('three_axis')
    grade = load_grade(grade_name) if isinstance(grade_name, str) else grade_name
    plan_obj = load_plan(plan) if isinstance(plan, str) else plan
    t0 = time.perf_counter()
    sim = simulate(fx, build_profile(plan_obj, fx), grade,
                   SimConfig(imu_rate_hz=rate_hz, seed=seed))
    t1 = time.perf_counter()
    cfg = load_estimator_config(est_config)
    est = replay(lambda: merged_samples(sim), fx, grade, cfg, iterations)
    t2 = time.perf_counter()
    st = est.estimate_state()
    labels = list(st.labels)
    groups = [lab.split('[')[0] for lab in labels]
    return RunResult(est, sim, labels, groups, truth_vector(est, sim), st.values,
                     np.sqrt(np.diag(st.covariance)), st.covariance, t1 - t0, t2 - t1)


def unit_of(group: str) -> tuple[float, str]:
    if group in AUX_UNITS:
        return AUX_UNITS[group]
    _, _, si, unit, _ = em.GROUP_INFO[group]
    return si, unit


def print_table(r: RunResult, targets: dict[str, tuple[float, str]]) -> dict[str, Any]:
    """Per-parameter table; returns target bookkeeping for the summary."""
    print(f'{"parameter":24s} {"unit":>7s} {"truth":>11s} {"estimate":>11s} {"error":>10s} '
          f'{"sigma":>10s} {"err/sig":>8s} {"target":>8s}  status')
    met: dict[str, bool] = {}
    worst: dict[str, tuple[float, float]] = {}
    for i, (lab, g) in enumerate(zip(r.labels, r.groups)):
        si, unit = unit_of(g)
        tr, va, er, sd = (r.truth[i] / si, r.value[i] / si, r.err[i] / si, r.sigma[i] / si)
        status = ''
        tgt = ''
        if g in targets:
            lim, what = targets[g]
            tgt = f'{lim:g}'
            ok_s = sd <= lim
            ok_e = abs(er) <= lim
            ok = ok_s and (ok_e or what == 'sigma')
            status = 'ok' if ok else ('FAIL sigma' if not ok_s else 'FAIL error')
            if what == 'sigma':
                status += ' (sigma target)'
            met[g] = met.get(g, True) and ok
            we, ws = worst.get(g, (0.0, 0.0))
            worst[g] = (max(we, abs(er)), max(ws, sd))
        if abs(r.z[i]) > 3.0:
            status += ' |err|>3sig'
        print(f'{lab:24s} {unit:>7s} {tr:11.4g} {va:11.4g} {er:10.3g} {sd:10.3g} '
              f'{r.z[i]:8.2f} {tgt:>8s}  {status}')
    print('per target group (max |error|, max sigma):')
    for g, (lim, what) in targets.items():
        if g not in worst:
            print(f'  {g:22s} not estimated')
            continue
        we, ws = worst[g]
        print(f'  {g:22s} |err| {we:9.3g}  sigma {ws:9.3g}  target {lim:g} ({what})  '
              f'{"met" if met[g] else "NOT MET"}')
    return {'met': met, 'worst': worst}


def honesty_line(r: RunResult) -> str:
    n = len(r.err)
    lo, hi = chi2.ppf([0.025, 0.975], n)
    return (f'max|err/sig| {np.abs(r.z).max():.2f} ({r.labels[int(np.argmax(np.abs(r.z)))]}), '
            f'{int((np.abs(r.z) > 3).sum())}/{n} beyond 3 sigma, NEES {r.nees:.1f} '
            f'(n={n}, 95% band {lo:.1f}..{hi:.1f})')


def health_line(r: RunResult) -> str:
    h = r.est.health()
    return (f'mean NIS {h.get("mean_nis")}, rejected {h.get("rejected")}, min eig '
            f'{h.get("covariance_min_eigenvalue_scaled", float("nan")):.3g}')


def gyro_bias_limits(plan: str, grade: Any, fixture: Any, heading_sigma_rad: float,
                     dt_s: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Lower bounds (deg/h) on the gyro-bias sigma from the angle random walk alone.

    Fisher information of the three IMU gyro biases and the initial heading error when the
    tilt is known perfectly (no accelerometer noise, no other unknowns): the ENU tilt rates
    are ``psi_E' = -(R b)_E - Omega_N psi_U``, ``psi_N' = -(R b)_N`` with white noise of the
    ARW density N, ``psi_U(t) = psi_U0 - int (R b)_U`` (error dynamics of strapdown.py; the
    known tilt terms of ``-Omega x psi`` dropped). Returns (heading free = gyrocompassing,
    heading observed too), both with the grade prior on b. A filter that also has to find
    the tilt from noisy velocities and the accelerometer errors cannot do better.
    """
    prof = build_profile(load_plan(plan), fixture)
    t = np.arange(0.0, prof.duration_s, dt_s)
    q, _, _ = prof.evaluate(t)
    R = fixture.R_enu_imu(q)
    om_n = fixture.site.omega_ie_enu[1]
    n_arw = grade.gyro_noise_rad_s_rt_hz
    cum_u = np.cumsum(R[:, 2, :], axis=0) * dt_s
    zero = np.zeros((len(t), 1))
    j_e = np.concatenate([-R[:, 0, :] + om_n * cum_u, np.full((len(t), 1), -om_n)], axis=1)
    j_n = np.concatenate([-R[:, 1, :], zero], axis=1)
    j_u = np.concatenate([-R[:, 2, :], zero], axis=1)
    sb = float(np.hypot(grade.sigma.gyro_bias_rad_s, grade.gyro_bias_instability_rad_s))
    info0 = np.diag([sb ** -2] * 3 + [heading_sigma_rad ** -2])
    info = info0 + (j_e.T @ j_e + j_n.T @ j_n) * dt_s / n_arw ** 2
    info_h = info + (j_u.T @ j_u) * dt_s / n_arw ** 2
    lim = [np.sqrt(np.diag(np.linalg.inv(i)))[:3] / em.DEG_H for i in (info, info_h)]
    return lim[0], lim[1]


def gm_bias_limits(grade: Any, duration_s: float) -> tuple[float, float]:
    """Gyro-bias limits (deg/h) set by the Gauss-Markov bias instability of the grade.

    Tracked total bias, angle known perfectly: the steady state of a random-walk bias
    (PSD ``q = 2 sigma^2 / tau``) seen through white rate noise N has variance
    ``N sqrt(q)`` (scalar Kalman-Bucy Riccati equation). Constant (turn-on) part alone: the
    mean over T of a Gauss-Markov process has variance ``2 sigma^2 tau / T`` (T >> tau),
    plus the ARW's ``N^2 / T``.
    """
    from imu_calib_ros.core.estimator.noise import gyro_bias_floor_rad_s
    n = grade.gyro_noise_rad_s_rt_hz
    s, tau = grade.gyro_bias_instability_rad_s, grade.gyro_bias_correlation_s
    tracked = gyro_bias_floor_rad_s(grade)
    const = np.sqrt(2.0 * s ** 2 * tau / duration_s + n ** 2 / duration_s)
    return float(tracked / em.DEG_H), float(const / em.DEG_H)


def case_targets(name: str, grade: str, plan: str, rate: float, est_cfg: str,
                 targets: dict[str, tuple[float, str]], a: argparse.Namespace) -> None:
    print(f'\n=== {name}: {getattr(grade, "name", grade)}, {plan}, {rate:g} Hz, {est_cfg}, '
          f'seed {a.seed}, '
          f'{a.iterations} passes ===')
    r = run_case(grade, plan, rate, est_cfg, a.seed, a.iterations)
    dur = len(r.sim.imu) / rate
    print(f'data {dur:.0f} s ({len(r.sim.imu)} samples); simulate {r.sim_s:.1f} s, replay '
          f'{r.replay_s:.1f} s ({a.iterations * len(r.sim.imu) / r.replay_s:,.0f} samples/s)')
    info = print_table(r, targets)
    print(health_line(r))
    grade_obj, fx = r.est.grade, r.est.fixture
    free, head = gyro_bias_limits(plan, grade_obj, fx, r.est.config.initial_heading_sigma_rad)
    print(f'gyro-bias noise limits (ARW only, tilt known perfectly): heading free '
          f'{np.array2string(free, precision=4)} deg/h, heading observed '
          f'{np.array2string(head, precision=4)} deg/h; N/sqrt(T) = '
          f'{grade_obj.gyro_noise_rad_s_rt_hz / np.sqrt(dur) / em.DEG_H:.4f} deg/h')
    tracked, const = gm_bias_limits(grade_obj, dur)
    const_txt = (f', constant part over {dur:.0f} s {const:.3g} deg/h'
                 if dur > 3.0 * grade_obj.gyro_bias_correlation_s else '')
    print(f'gyro-bias limit from the bias instability: tracked total bias {tracked:.3g} '
          f'deg/h{const_txt}')
    n_met = sum(info['met'].values())
    failed = [g for g, ok in info['met'].items() if not ok]
    print(f'SUMMARY {name}: targets met {n_met}/{len(targets)}'
          f'{" (not met: " + ", ".join(failed) + ")" if failed else ""}; {honesty_line(r)}')


def group_sigma(r: RunResult, group: str) -> np.ndarray:
    return np.array([s for s, g in zip(r.sigma, r.groups) if g == group])


def case_random(a: argparse.Namespace) -> None:
    fx = load_fixture('three_axis')
    designed = load_plan(a.random_vs)
    t_des = build_profile(designed, fx).duration_s
    # the random plan with the duration closest to the designed one (count of moves chosen)
    best = None
    kw = {'max_deg': a.random_max_deg, 'duration_s': tuple(a.random_move_s),
          'dwell_s': tuple(a.random_dwell_s)}
    for count in range(2, 400):
        p = random_plan(a.seed, count, **kw)
        d = build_profile(p, fx).duration_s
        if best is None or abs(d - t_des) < abs(best[1] - t_des):
            best = (p, d, count)
        if d > t_des:
            break
    assert best is not None
    rp, t_rand, count = best
    print(f'\n=== random: random_plan(seed={a.seed}, count={count}, {kw}) {t_rand:.0f} s vs '
          f'{a.random_vs} {t_des:.0f} s; nav_grade, {a.random_rate:g} Hz, {a.iterations} '
          'passes ===')
    rr = run_case('nav_grade', rp, a.random_rate, 'estimator', a.seed, a.iterations)
    rd = run_case('nav_grade', designed, a.random_rate, 'estimator', a.seed, a.iterations)
    prior = prior_sigmas(rr.est.grade, rr.est.config)
    print(f'{"group":22s} {"unit":>7s} {"prior":>9s} {"sig rand":>10s} {"sig design":>10s} '
          f'{"ratio":>7s}  (median over the group; ratio = random / designed)')
    ratios = []
    for g in dict.fromkeys(rr.groups):
        si, unit = unit_of(g)
        sr, sd = np.median(group_sigma(rr, g)), np.median(group_sigma(rd, g))
        pr = float(np.median(prior[g])) / si
        excited = sd < 0.5 * pr * si
        ratio = sr / sd
        if excited:
            ratios.append(ratio)
        print(f'{g:22s} {unit:>7s} {pr:9.3g} {sr / si:10.3g} {sd / si:10.3g} {ratio:7.2f}'
              f'{"" if excited else "  (designed plan does not excite it)"}')
    print(f'random  : {honesty_line(rr)}')
    print(f'designed: {honesty_line(rd)}')
    # works on any such plan: a different random plan (and truth, noise) per seed
    nees, zs = [], []
    for k in range(a.random_seeds):
        seed = a.seed + 1000 + k
        r = run_case('nav_grade', random_plan(seed, count, **kw), a.random_rate, 'estimator',
                     seed, a.iterations)
        nees.append(r.nees)
        zs.append(r.z)
    z = np.array(zs)
    M, n = z.shape
    lo, hi = chi2.ppf([0.025, 0.975], M * n) / M
    mean = float(np.mean(nees))
    print(f'{M} other random plans (seeds {a.seed + 1000}..{a.seed + 999 + M}): mean NEES '
          f'{mean:.1f} (n = {n}, 95 % band {lo:.1f}..{hi:.1f}: '
          f'{"INSIDE" if lo <= mean <= hi else "OUTSIDE"}), '
          f'{int((np.abs(z) > 3).sum())}/{z.size} |err/sig| > 3 (expected {0.0027 * z.size:.1f})')
    print(f'SUMMARY random: sigma ratio random/designed over excited groups: median '
          f'{np.median(ratios):.2f}, max {np.max(ratios):.2f}; random run '
          f'max|err/sig| {np.abs(rr.z).max():.2f}, NEES {rr.nees:.1f}/{len(rr.err)}; '
          f'{M} random plans mean NEES {mean:.1f} in {lo:.1f}..{hi:.1f}: '
          f'{"honest" if lo <= mean <= hi else "NOT honest"}')


def case_mc(a: argparse.Namespace) -> None:
    grade = a.mc_grade
    est_cfg = 'estimator_mems' if grade == 'mems_mti1' else 'estimator'
    print(f'\n=== mc: {a.mc_seeds} seeds, {grade}, {a.mc_plan}, {a.mc_rate:g} Hz, {est_cfg}, '
          f'{a.iterations} passes ===')
    nees, zs, labels = [], [], None
    for k in range(a.mc_seeds):
        seed = a.mc_first_seed + k
        r = run_case(grade, a.mc_plan, a.mc_rate, est_cfg, seed, a.iterations)
        nees.append(r.nees)
        zs.append(r.z)
        labels = r.labels
        print(f'seed {seed:3d}: NEES {r.nees:7.1f}  max|z| {np.abs(r.z).max():5.2f} '
              f'({r.labels[int(np.argmax(np.abs(r.z)))]})  replay {r.replay_s:.1f} s', flush=True)
    assert labels is not None
    z = np.array(zs)
    M, n = z.shape
    lo, hi = chi2.ppf([0.025, 0.975], M * n) / M
    mean = float(np.mean(nees))
    print('per state over seeds: mean z, rms z (1 for an honest filter):')
    rms = np.sqrt(np.mean(z ** 2, axis=0))
    for i in np.argsort(-rms):
        print(f'  {labels[i]:24s} mean {z[:, i].mean():6.2f}  rms {rms[i]:5.2f}')
    by_group: dict[str, list[float]] = {}
    for i, lab in enumerate(labels):
        by_group.setdefault(lab.split('[')[0], []).extend(z[:, i] ** 2)
    print('per group rms z: ' + ', '.join(f'{g} {np.sqrt(np.mean(v)):.2f}'
                                         for g, v in by_group.items()))
    inside = lo <= mean <= hi
    print(f'SUMMARY mc: mean NEES {mean:.1f} over {M} seeds, n = {n} states, 95 % band '
          f'{lo:.1f}..{hi:.1f}: {"INSIDE" if inside else "OUTSIDE"}; '
          f'{int((np.abs(z) > 3).sum())}/{z.size} |err/sig| > 3 (expected {0.0027 * z.size:.1f})')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--cases', default='nav,mems,mems-stable,random,mc',
                    help='comma-separated subset of nav,mems,mems-stable,random,mc')
    ap.add_argument('--seed', type=int, default=1, help='simulation seed (nav, mems, random)')
    ap.add_argument('--iterations', type=int, default=1, help='replay passes (CLI default 1)')
    ap.add_argument('--nav-rate', type=float, default=200.0)
    ap.add_argument('--nav-plan', default='srt_kozlov_bias')
    ap.add_argument('--nav-grade', default='nav_grade', help='grade name or path (nav case)')
    ap.add_argument('--nav-config', default='estimator', help='estimator config (nav case)')
    ap.add_argument('--mems-config', default='estimator_mems', help='estimator config (mems)')
    ap.add_argument('--mems-grade', default='mems_mti1', help='grade name or path (mems case)')
    ap.add_argument('--mems-rate', type=float, default=100.0)
    ap.add_argument('--mems-plan', default='savage_srt')
    ap.add_argument('--random-rate', type=float, default=100.0)
    ap.add_argument('--random-vs', default='demo_short', help='designed plan to compare with')
    ap.add_argument('--random-max-deg', type=float, default=360.0,
                    help='random moves uniform in +-this angle')
    ap.add_argument('--random-move-s', type=float, nargs=2, default=[4.0, 8.0],
                    help='random move durations (uniform), like the designed plan\'s rotations')
    ap.add_argument('--random-dwell-s', type=float, nargs=2, default=[2.0, 6.0],
                    help='random dwells (uniform), like the designed plan\'s dwells')
    ap.add_argument('--random-seeds', type=int, default=10,
                    help='further random plans (one per seed) for the honesty check')
    ap.add_argument('--mc-seeds', type=int, default=20)
    ap.add_argument('--mc-first-seed', type=int, default=100)
    ap.add_argument('--mc-plan', default='demo_short')
    ap.add_argument('--mc-rate', type=float, default=100.0)
    ap.add_argument('--mc-grade', default='nav_grade', help='nav_grade or mems_mti1')
    a = ap.parse_args()
    cases = [c.strip() for c in a.cases.split(',') if c.strip()]
    np.set_printoptions(precision=4, suppress=True)
    for c in cases:
        t0 = time.perf_counter()
        if c == 'nav':
            case_targets('nav', a.nav_grade, a.nav_plan, a.nav_rate, a.nav_config,
                         NAV_TARGETS, a)
        elif c == 'mems':
            case_targets('mems', a.mems_grade, a.mems_plan, a.mems_rate, a.mems_config,
                         MEMS_TARGETS, a)
        elif c == 'mems-stable':
            # evidence for the one target the MEMS case cannot meet: the same unit without
            # its datasheet in-run gyro bias instability (10 deg/h) meets <= 2 deg/h
            g = load_grade(a.mems_grade)
            g = dataclasses.replace(g, name=g.name + '_without_gyro_bias_instability',
                                    gyro_bias_instability_rad_s=0.0)
            case_targets('mems-stable', g, a.mems_plan, a.mems_rate, a.mems_config,
                         MEMS_TARGETS, a)
        elif c == 'random':
            case_random(a)
        elif c == 'mc':
            case_mc(a)
        else:
            raise SystemExit(f'--cases: unknown case {c!r} (nav, mems, mems-stable, random, '
                             'mc)')
        print(f'[{c}: {time.perf_counter() - t0:.0f} s]', flush=True)


if __name__ == '__main__':
    main()
