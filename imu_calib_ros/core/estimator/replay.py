"""Offline replay: a loop over a bag pushing samples into the streaming estimator.

Iteration (Savage, "Improved strapdown IMU calibration procedures", sect. 8; PSINS's passes):
each pass re-plays the whole bag with the compensation of the previous pass as the starting
point; the prior covariance is the grade's again, so the data are counted once. Memory is
bounded: the bag is streamed. A source with a ``batches()`` method (``iter_bag``'s iterator)
is read as :class:`ImuBatch` / :class:`JointBatch` chunks (``iter_bag_batches``: numpy
decoding, no per-sample Python objects, joints pushed with ``push_joint_batch``); a plain
iterable of samples is gathered into batches here. Joint states are always pushed before the
IMU samples that follow them in stamp order (the estimator's results do not depend on how
far ahead the joint states are, nor on the IMU batch sizes: tested).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterator

import numpy as np

from ..errors import InputError
from ..joint_merge import MERGE_WAIT_NS
from ..types import ImuBatch, ImuSample, JointBatch, JointSample
from .config import EstimatorConfig
from .estimator import CalibrationEstimator, Estimate
from .noise import MEMS_BIAS_WALK, MEMS_FLOOR_SOURCE, bias_walk_sources
from .quantiles import chi2_ppf
from .run_ledger import RunLedger
from .selfcheck import SelfCheckConfig, Verdict

if TYPE_CHECKING:
    from ..fixture import Fixture
    from ..imu_grade import ImuGrade


def _batches_of_samples(samples: Any, batch: int) -> Iterator[ImuBatch | JointBatch]:
    """Group a stream of ImuSample / JointSample (or batches) into batches, keeping every
    joint state ahead of the IMU samples that follow it (runs of one joint-name list)."""
    imu: list[ImuSample] = []
    joints: list[JointSample] = []

    def joint_batch() -> JointBatch:
        return JointBatch(np.array([j.stamp_ns for j in joints], np.int64), joints[0].names,
                          np.array([np.asarray(j.positions_rad, float) for j in joints]))

    for s in samples:
        if isinstance(s, ImuSample):
            if imu and s.frame_id != imu[0].frame_id:
                if joints:
                    yield joint_batch()
                    joints = []
                yield ImuBatch.from_samples(imu)
                imu = []
            imu.append(s)
            if len(imu) >= batch:
                if joints:
                    yield joint_batch()
                    joints = []
                yield ImuBatch.from_samples(imu)
                imu = []
        elif isinstance(s, JointSample):
            if joints and (s.names != joints[0].names or len(s.positions_rad)
                           != len(joints[0].positions_rad)):
                yield joint_batch()
                joints = []
            joints.append(s)
        else:  # already a batch: keep the order
            if joints:
                yield joint_batch()
                joints = []
            if imu:
                yield ImuBatch.from_samples(imu)
                imu = []
            yield s
    if joints:
        yield joint_batch()
    if imu:
        yield ImuBatch.from_samples(imu)


#: how far a pass's estimate may move from where the pass started and still count as
#: linearised about it (the coarse start's own "determined" limits, :meth:`.coarse.CoarseStart.
#: determined`: gyro scale and misalignment and the mounting turn into attitude errors that
#: multiply gravity; the accelerometer's are linear in velocity)
LINEAR_MOVE: dict[str, float] = {'gyro_scale': 2e-3, 'gyro_misalignment': 2e-3,
                                 'mounting': 2e-3, 'accel_scale': 5e-3,
                                 'accel_misalignment': 5e-3}


def moved_beyond_linear(est: CalibrationEstimator) -> str:
    """The state whose estimate moved furthest beyond :data:`LINEAR_MOVE` from where the pass
    started, as ``'label moved X (limit L)'``; ``''`` if none did. Such a pass linearised its
    first updates about a point it then left: on a weak plan (three poses, rotations about two
    axes, the mounting unmeasured) the feedback filter gained information along directions the
    data do not determine (a misalignment 46 sigma off, no update gated), which a pass started
    from its estimate does not (Savage sect. 8)."""
    lay = est.layout
    st = est.estimate_state()
    move = np.abs(np.asarray(st.values, float) - est.start_values())
    worst, text = 1.0, ''
    for g, lim in LINEAR_MOVE.items():
        if g not in lay.slices:
            continue
        sl = slice(lay.slices[g].start - 6, lay.slices[g].stop - 6)
        j = int(np.argmax(move[sl]))
        if move[sl][j] / lim > worst:
            worst = float(move[sl][j] / lim)
            text = f'{st.labels[sl.start + j]} moved {move[sl][j]:.3g} (limit {lim:g})'
    return text


#: a pass whose stationary windows showed a bias walk more than this (PSD ratio: 2x in sigma)
#: above the one it started with linearised and weighted
#: everything before the growth with a walk the data then contradicted: another pass assumes
#: the grown walk from its start (issue 11 item 5; measured on a MEMS unit with 10x less white
#: noise than its 8 deg/h instability implies: windows chi2/dof 3.3, g-sensitivity 10 sigma
#: off after one pass)
WALK_GROWTH = 4.0


def walk_grown(est: CalibrationEstimator) -> tuple[str, Any]:
    """``(why, start)``: when the walk the pass's stationary windows showed grew beyond
    :data:`WALK_GROWTH` (:meth:`.noise.ProcessNoise.grown`), why (``'gyro bias walk grew
    55x (...)'``) and the coarse start with the grown walk as the walk it measured (the next
    pass assumes it from its start); else ``('', None)``."""
    q_g, q_a, r_g, r_a = est.bias_walk_growth()
    st = est.start
    if st is None or max(r_g, r_a) <= WALK_GROWTH:
        return '', None
    parts: list[str] = []
    grown: dict[str, Any] = {}  # only the group that grew: the other keeps the pass's start
    for what, q, r, unit, name in (
            ('gyro', q_g, r_g, 'rad/s/sqrt(s)', 'gyro_bias_random_walk_rad_s2_rt_hz'),
            ('accelerometer', q_a, r_a, 'm/s^2/sqrt(s)', 'accel_bias_random_walk_m_s3_rt_hz')):
        if r > WALK_GROWTH:
            parts.append(f'{what} bias walk grew {r:.3g}x to {math.sqrt(q):.3g} {unit}')
            grown[name] = max(getattr(st, name), math.sqrt(q))
    return ('; '.join(parts) + ': the next pass assumes it from its start',
            dataclasses.replace(st, **grown))


#: the least gyro walk the profile tries, as walk density / white-noise density [1/s] (real
#: MEMS parts span 0.006-0.06, noise.MEMS_BIAS_WALK); it steps by factors of 2 from the floor
WALK_PROFILE_RANGE = (0.002, 0.2)
#: the walk chosen is the likelihood's one-sided 95 % upper bound: above the most likely walk,
#: where the NLL has risen by chi2(0.90, 1) / 2 = 1.35
WALK_PROFILE_RISE = chi2_ppf(0.90, 1) / 2.0
#: a pass with fewer updates than the most of any pass (by this fraction) re-aligned or
#: restarted at its walk: its NLL sums fewer terms and is not comparable; it counts as unlikely
WALK_PROFILE_UPDATES_LOST = 1e-3


def profile_gyro_walk(nll_at: Callable[[float], tuple[float, int] | None], floor: float,
                      least: float = WALK_PROFILE_RANGE[0]
                      ) -> tuple[float, tuple[tuple[float, float], ...]]:
    """Issue 11 item 5 for a MEMS unit without a grade: its gyro bias walk chosen by the data.

    A plan's stationary windows cannot show a 100 s instability, and real parts' walks span
    a factor 10 around the floor :data:`.noise.MEMS_BIAS_WALK` assumes: a unit worse than the
    floor got gyro-bias sigmas too small (the arm's MEMS unit, 0.056 of its noise density
    against the floor's 0.022; :func:`_profiled` raises the walk to the bound, never lowers
    it). The whole run's
    innovations decide: ``nll_at(r)`` replays from the coarse start with the walk at ``r`` x
    the white-noise density and returns its innovations' negative log-likelihood and update
    count (:meth:`~.estimator.CalibrationEstimator.innovation_nll`; None if it diverged). They
    are compared at factors of 2 from ``floor`` (no lower than ``least``, e.g. the walk the
    stationary windows showed, below which the passes are the same) until the least NLL is
    bracketed and the NLL has risen by :data:`WALK_PROFILE_RISE` above it (within
    :data:`WALK_PROFILE_RANGE`). The walk chosen is where it crosses that rise above the most
    likely one (log-linear between the two passes around it), the one-sided 95 % upper bound:
    the likelihood is flat towards small walks, and its maximum alone fell 2-4x below the
    truth on some of the grid's MEMS runs (gyro-bias z up to 3.1); the bound found the arm
    unit's 0.056 at 0.052. A diverged pass, or one with fewer updates than the others
    (:data:`WALK_PROFILE_UPDATES_LOST`), counts as infinitely unlikely; of equal NLLs the
    largest walk is the most likely (the passes below it were the same pass).

    Returns ``(walk ratio, profile)``: ``profile`` is ``((ratio, NLL - least NLL), ...)`` in
    ratio order; ``(floor, ())`` when no pass could be compared.
    """
    lo = max(least, WALK_PROFILE_RANGE[0])
    hi = WALK_PROFILE_RANGE[1]
    evals: dict[float, tuple[float, int]] = {}

    def evaluate(r: float) -> None:
        evals[r] = nll_at(r) or (math.inf, 0)

    for r in (floor / 2.0, floor, 2.0 * floor):
        if r >= lo or r == floor:
            evaluate(r)
    while True:
        fs = sorted(evals)
        most = max(n for _, n in evals.values())
        nll = np.array([v if n >= most * (1.0 - WALK_PROFILE_UPDATES_LOST) else math.inf
                        for v, n in (evals[r] for r in fs)])
        if not np.isfinite(nll).any():
            return floor, ()
        i = int(np.flatnonzero(nll <= nll.min() + 1e-9)[-1])  # ties: the largest walk
        if i == 0 and fs[0] / 2.0 >= lo:
            evaluate(fs[0] / 2.0)
        elif i == len(fs) - 1 or nll[-1] <= nll[i] + WALK_PROFILE_RISE:
            if fs[-1] * 2.0 > hi:
                break
            evaluate(fs[-1] * 2.0)
        else:
            break
    level = nll[i] + WALK_PROFILE_RISE
    above = [j for j in range(i + 1, len(fs)) if nll[j] > level]
    if not above:
        chosen = fs[-1]
    elif not np.isfinite(nll[above[0]]):
        chosen = fs[above[0] - 1]  # the largest walk that ran: no crossing to interpolate to
    else:
        j = above[0]
        t = (level - nll[j - 1]) / (nll[j] - nll[j - 1])
        chosen = fs[j - 1] * (fs[j] / fs[j - 1]) ** t
    return chosen, tuple((r, float(v - nll[i])) for r, v in zip(fs, nll))


@dataclass(frozen=True)
class ReplayRun:
    """A replay's estimator (after the last pass), the evidence of that pass and its
    self-check verdict (:mod:`.selfcheck`), and why each pass after the requested ones ran."""

    estimator: CalibrationEstimator
    ledger: RunLedger
    verdict: Verdict
    extra_passes: tuple[str, ...] = ()


def replay_pass(samples: Any, fixture: Fixture, grade: ImuGrade | None, config: EstimatorConfig,
                initial: Estimate | None = None, batch: int = 4000,
                progress: Callable[[int], None] | None = None,
                start: Any = None) -> CalibrationEstimator:
    """Run one pass over ``samples``: an iterable of ImuSample / JointSample in stamp order,
    or of ImuBatch / JointBatch (joint batches no later than the IMU samples after them), or
    an object with ``batches()`` giving the latter (``msg_adapters.bag.iter_bag``).

    Raises
    ------
    InputError
        No IMU samples, no joint states of the fixture's joints, no stationary window for the
        alignment, or no motion.
    """
    return _replay_pass(samples, fixture, grade, config, initial, batch, progress, start)[0]


def _replay_pass(samples: Any, fixture: Fixture, grade: ImuGrade | None, config: EstimatorConfig,
                 initial: Estimate | None, batch: int, progress: Callable[[int], None] | None,
                 start: Any) -> tuple[CalibrationEstimator, RunLedger]:
    """:func:`replay_pass` with the run's evidence (:class:`RunLedger`) fed alongside."""
    est = CalibrationEstimator(fixture, grade, config, initial=initial, start=start)
    ledger = RunLedger(est)
    batches = samples.batches() if callable(getattr(samples, 'batches', None)) \
        else _batches_of_samples(samples, batch)
    try:
        for b in batches:
            if isinstance(b, ImuBatch):
                ledger.imu(b)
                est.push_imu_batch(b)
                if progress is not None:
                    progress(len(b))
            else:
                ledger.joints(b)
                est.push_joint_batch(b)
        est.flush()
        _check_usable(est, ledger, fixture, config)
    except InputError as exc:  # stamps taken on receipt may be why: say so on the same line
        hint = est.stamp_hint()
        if hint and not est.stamps_error:
            raise InputError(f'{exc}{hint}') from None
        raise
    return est, ledger


def _check_usable(est: CalibrationEstimator, ledger: RunLedger, fixture: Fixture,
                  config: EstimatorConfig) -> None:
    """After a pass: :class:`InputError` with one line when the input could not calibrate."""
    c = est.counters
    if c['imu_samples'] == 0:
        raise InputError('no IMU samples in the input: check --imu-topic')
    if est.units_error:  # every later IMU sample was refused: the cause of what follows
        raise InputError(est.units_error)
    if est.stamps_error:
        raise InputError(est.stamps_error)
    if c['joint_samples'] == 0:
        names = ', '.join(fixture.joint_names)
        what = ('joint states lack the fixture joints ' + names if c['joint_missing_names']
                else 'no joint states in the input')
        seen = est.partial_joints_seen
        never = [n for n in fixture.joint_names if n not in seen]
        if seen and never:  # some fixture joints came (alone or with others), one never did
            what = (f'the joint states never carry the fixture joint{"s" * (len(never) > 1)} '
                    f'{", ".join(never)} (they carry {", ".join(seen)})')
        elif seen:  # one axis per message, and they never met
            what = (f'the joint states carry the fixture joints {", ".join(seen)} one per '
                    f'message, and never all within {MERGE_WAIT_NS * 1e-9:g} s of one another')
        raise InputError(f'{what}: check --joint-topic and the fixture file')
    if not est.is_running and est.counters['imu_processed'] == 0:
        gap = ledger.longest_joint_gap_s()
        if gap > config.init_window_s:  # a driver that is silent while the table stands
            raise InputError(f'the joint states stop for up to {gap:.1f} s, so no '
                             f'stationary window of {config.init_window_s:g} s has them for '
                             'the initial alignment: publish joint states at a steady rate, '
                             'also while the table stands (not only on change)')
        raise InputError(f'no stationary window of {config.init_window_s:g} s with joint '
                         'states for the initial alignment: start the recording at rest')
    if est.joint_travel_rad < 1e-2:
        raise InputError('no motion: the fixture joints did not move (less than 0.01 rad); '
                         'record a rotation plan')
    health = est.health()
    if health['status'] == 'ERROR':
        # A diverged filter never becomes a calibration file (issue 6).
        raise InputError(f'the estimator diverged ({health["divergence_reason"]}); no '
                         f'calibration written: {_weak_plan(ledger)}check the IMU grade, '
                         'units and the fixture file')


def _weak_plan(ledger: RunLedger) -> str:
    """A divergence's likelier cause when the run's stationary poses never stood some IMU
    direction near vertical (the self-check's 'plan' rule, which a diverged run never
    reaches), as the start of the advice, or ''."""
    from .coarse import MIN_ACCEL_REACH
    from .selfcheck import direction_name
    reach, v = ledger.accel_reach()
    if not v or reach >= MIN_ACCEL_REACH:
        return ''
    return (f'the plan never stands {direction_name(v)} within 60 deg of vertical (at most '
            f'{reach:.2g} of gravity along it), so an uncalibrated unit\'s errors along it '
            'cannot be determined on this plan or table; else ')


def replay(open_samples: Callable[[], Any], fixture: Fixture, grade: ImuGrade | None,
           config: EstimatorConfig, iterations: int = 1,
           progress: Callable[[int], None] | None = None) -> CalibrationEstimator:
    """``iterations`` passes over the data (``open_samples()`` gives a fresh iterator).

    Pass ``k > 1`` compensates from pass ``k - 1``'s estimate (its linearisation point) and
    keeps the grade's prior (:meth:`CalibrationEstimator._prior_correction`): a Gauss-Newton
    step, not a second helping of the same data. The feedback filter relinearises as it
    goes, so one pass is the default: measured, a second pass moves the nav-grade states by
    at most 0.014 sigma and the MEMS ones (encoder aiding) by 0.12 sigma (docs/ESTIMATOR.md).
    """
    return _passes(open_samples, fixture, grade, config, iterations, progress)[0]


def replay_run(open_samples: Callable[[], Any], fixture: Fixture, grade: ImuGrade | None,
               config: EstimatorConfig, iterations: int = 1,
               progress: Callable[[int], None] | None = None,
               selfcheck: SelfCheckConfig | None = None,
               max_passes: int = 0) -> ReplayRun:
    """:func:`replay`, with the self-check verdict of the last pass (issue 17).

    ``max_passes`` > ``iterations``: after the requested passes, more (up to ``max_passes``
    in all) while the last one moved beyond :data:`LINEAR_MOVE` from where it started
    (:func:`moved_beyond_linear`) or its bias walk grew beyond :data:`WALK_GROWTH`
    (:func:`walk_grown`: the next pass assumes the grown walk from its start);
    ``extra_passes`` says why each ran."""
    est, ledger, why = _passes(open_samples, fixture, grade, config, iterations, progress,
                               max_passes)
    return ReplayRun(est, ledger, ledger.verdict(selfcheck), why)


def _profiled(open_samples: Callable[[], Any], fixture: Fixture, grade: ImuGrade | None,
              config: EstimatorConfig, progress: Callable[[int], None] | None,
              est: CalibrationEstimator, ledger: RunLedger
              ) -> tuple[CalibrationEstimator, RunLedger]:
    """The first pass ``est`` (``ledger``) of a MEMS unit whose gyro walk is the floor:
    :func:`profile_gyro_walk` from its coarse start (the first pass is its point at the
    floor), and a pass at its bound when that is above the floor (else the first pass, with
    the profile recorded). Only the NLLs of the profile's passes are kept."""
    assert est.start is not None
    start0 = est.start
    floor = MEMS_BIAS_WALK[0]

    def run_pass(r: float) -> tuple[CalibrationEstimator, RunLedger] | None:
        st = dataclasses.replace(start0, gyro_walk_to_noise_per_s=r)
        try:
            return _replay_pass(open_samples(), fixture, grade, config, None, 4000, progress, st)
        except InputError:  # diverged at this walk: the profile counts it as unlikely
            return None

    def nll_at(r: float) -> tuple[float, int] | None:
        if r == floor:
            # the first pass ran at the floor from this start: the same pass (its NLL to the
            # last digit on the grid's MEMS bags)
            return est.innovation_nll()
        res = run_pass(r)
        return None if res is None else res[0].innovation_nll()

    n_g = start0.gyro_noise_rad_s_rt_hz
    windows = start0.gyro_bias_random_walk_rad_s2_rt_hz / n_g if n_g > 0 else 0.0
    bound, profile = profile_gyro_walk(nll_at, floor, windows)
    if not profile:
        return est, ledger
    # never below the floor: the data may raise it, not lower it (the likelihood of a random
    # walk prefers a smaller one than a Gauss-Markov instability's 2 sigma^2 / tau: lowered,
    # an industrial unit's gyro bias ended 3.03 sigma off on the grid)
    raised = bound if bound > floor else 0.0
    st = dataclasses.replace(start0, gyro_walk_to_noise_per_s=raised,
                             gyro_walk_bound_per_s=bound, gyro_walk_profile=profile)
    res = (est, ledger) if not raised else run_pass(raised)
    if res is None:
        return est, ledger
    res[0].start = st  # the walk it ran with, and the profile behind it
    return res


def _passes(open_samples: Callable[[], Any], fixture: Fixture, grade: ImuGrade | None,
            config: EstimatorConfig, iterations: int,
            progress: Callable[[int], None] | None, max_passes: int = 0
            ) -> tuple[CalibrationEstimator, RunLedger, tuple[str, ...]]:
    init: Estimate | None = None
    est = None
    ledger = None
    start: Any = None  # later passes keep the first pass's coarse start (the prior mean)
    why: list[str] = []
    k = 0
    while True:
        est, ledger = _replay_pass(open_samples(), fixture, grade, config, init, 4000,
                                   progress, start)
        cfg = est.config  # the settings the pass ran with (the defaults for config None)
        if k == 0 and cfg.walk_profile and est.start is not None and bias_walk_sources(
                grade, est.start, cfg.aiding_gyro_noise_rad_s_rt_hz)[0] == MEMS_FLOOR_SOURCE:
            est, ledger = _profiled(open_samples, fixture, grade, config, progress, est, ledger)
        init = est.estimate_state()
        start = est.start
        k += 1
        if k < max(1, iterations):
            continue
        if k >= max_passes:
            break
        grew, grown_start = walk_grown(est)
        if grown_start is not None:
            # from the coarse start again, not from this pass's estimate: that one was made
            # with a walk the data contradicted (linearised there, a MEMS unit's gyro biases
            # ended 41 sigma off; from the coarse start, NEES 50 of 45 states)
            start, init = grown_start, None
        moved = moved_beyond_linear(est)
        if not (moved or grew):
            break
        why.append(f'pass {k}: ' + '; '.join(x for x in (moved, grew) if x))
    assert est is not None and ledger is not None
    return est, ledger, tuple(why)
