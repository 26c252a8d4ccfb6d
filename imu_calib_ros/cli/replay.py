"""``imu-calib replay``: calibrate from a recorded bag and write the calibration file.

    imu-calib replay BAG --fixture F --output CALIB.yaml [--imu-topic T] [--joint-topic T]
                     [--imu GRADE] [--config EST.yaml] [--iterations N] [--method ekf]
                     [--reorder-window S] [--force]

CONTRACT 5: exit 0 on success; on unusable input one clear line, non-zero exit, and no
(partial) output file. The EKF run is self-checked (issue 17, docs/ESTIMATOR.md
"Self-check"): when its own evidence says the result is not trustworthy, one line naming the
evidence, exit status 3 and no file; ``--force`` writes it anyway, marked as failing under
``provenance.self_check`` (where a passed verdict and its figures go too).
``--method srt|oscillation`` runs ``imu_calib_ros.core.methods.<name>.calibrate`` on the
whole bag (no self-check). The bag reader puts each
topic in header-stamp order (``--reorder-window``, docs/BAD_INPUT.md); what it reordered is
printed on stderr and kept in the file under ``provenance.bag_reader``.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from msg_adapters import DEFAULT_REORDER_WINDOW_S

from ..core.errors import InputError, SelfCheckError
from . import add_topic_arguments, add_urdf_arguments, check_output_file, urdf_options

if TYPE_CHECKING:
    from ..core.calibration import CalibrationResult
    from ..core.reorder import ReorderStats

METHODS = ('ekf', 'srt', 'oscillation')


#: most passes over a bag when the first leaves its linear region (--max-passes)
AUTO_MAX_PASSES = 3


def register(subparsers: Any) -> None:
    """Add the ``replay`` sub-command."""
    p = subparsers.add_parser('replay', help='calibrate from a recorded bag (CONTRACT 5)',
                              description=__doc__.split('\n\n')[0] if __doc__ else None)
    p.add_argument('bag', metavar='BAG', help='bag directory or .mcap file')
    p.add_argument('--fixture', required=True, metavar='F',
                   help='fixture name, YAML path (CONTRACT 2) or .urdf (with --base-link, '
                        '--imu-link)')
    add_urdf_arguments(p)
    p.add_argument('--output', '-o', required=True, metavar='CALIB.yaml',
                   help='calibration file to write (CONTRACT 4)')
    add_topic_arguments(p)
    p.add_argument('--imu', default=None, metavar='GRADE',
                   help='optional IMU grade hint (name or path): its sigmas become prior '
                        'floors; the noise, the start point and the priors come from the data '
                        '(default: none, for a unit whose errors are not known; --method '
                        'srt|oscillation take nav_grade\'s for what they do not solve for)')
    p.add_argument('--config', default=None, metavar='EST.yaml',
                   help='estimator config (default: config/estimator.yaml defaults)')
    p.add_argument('--iterations', type=int, default=1, metavar='N',
                   help='passes over the bag, >= 1 (default 1); each extra pass '
                        'relinearises about the previous estimate (Savage sect. 8)')
    p.add_argument('--max-passes', type=int, default=AUTO_MAX_PASSES, metavar='M',
                   help='after the --iterations passes, more (up to M in all) while the '
                        'last pass\'s estimate moved beyond the region where its '
                        f'linearisation holds (a weak plan; default {AUTO_MAX_PASSES}; 1: never)')
    p.add_argument('--method', default='ekf', choices=METHODS,
                   help='ekf: augmented-state EKF (default); srt: Savage\'s SRT processor; '
                        'oscillation: Kozlov & Kapralov\'s harmonic oscillations')
    p.add_argument('--reorder-window', type=float, default=DEFAULT_REORDER_WINDOW_S,
                   metavar='S', help='longest wait of a bag message to put its topic in '
                   'header-stamp order, in seconds of log time (rosbag2 logs the receipt '
                   f'time; default {DEFAULT_REORDER_WINDOW_S:g}; 0: no wait)')
    p.add_argument('--force', action='store_true',
                   help='write the calibration even when the run fails its self-check, '
                   'marked as failing under provenance.self_check (default: refuse, exit 3)')
    p.add_argument('--quiet', action='store_true', help='no progress bar or summary')
    p.set_defaults(func=run)


def _summary(calib: Any) -> str:
    """The terminal summary: labelled 3x3 blocks with units per element (issue 12; the same
    layout code as the report, :mod:`imu_calib_ros.core.param_table`)."""
    from ..core.param_table import format_text
    return format_text(calib)


def _srt_note(info: dict[str, Any]) -> None:
    """One stderr line when the SRT could not determine everything (merged sequences)."""
    seqs = [q['label'] for q in info.get('sequences', [])]
    merged = [q for q in seqs if not q.startswith('srt:')]
    not_est = info.get('not_estimated', [])
    if not (merged or not_est):
        return
    print(f'imu-calib replay: note: SRT found {len(seqs)} rotation sequences, '
          f'{len(seqs) - len(merged)} of them from Savage\'s Table 1 (the others are '
          'several run together: separating them needs dwells of >= 5 s; savage_srt has '
          '10 s); not estimated, kept at the grade\'s prior and listed as fixed: '
          f'{", ".join(not_est) or "none"}', file=sys.stderr)


def _walk_note(calib: Any) -> str | None:
    """:func:`~..core.estimator.noise.assumed_walk_note` of the file, as the command's note."""
    from ..core.estimator.noise import assumed_walk_note
    note = assumed_walk_note(calib.extra)
    return None if note is None else f'imu-calib replay: note: {note}'


def _reorder_note(stats: dict[str, ReorderStats], window_s: float, quiet: bool) -> None:
    """One stderr line per topic the reader had to put in stamp order (always when some
    messages stayed out of order or the stamps jumped back)."""
    for topic, st in stats.items():
        if st.late or st.backward_jumps or (st.reordered and not quiet):
            hint = (f' (the estimator rejects them; a --reorder-window over {window_s:g} s '
                    'may take them in)' if st.late else '')
            print(f'imu-calib replay: note: {topic}: {st.describe()}{hint}', file=sys.stderr)


def _with_provenance(calib: Any, args: Any, stats: dict[str, ReorderStats]) -> Any:
    """The calibration with the bag reader's reorder counts under ``provenance``."""
    import dataclasses
    extra = dict(calib.extra)
    prov = dict(extra.get('provenance', {}) or {})
    prov['bag_reader'] = {'bag': str(args.bag), 'reorder_window_s': float(args.reorder_window),
                          'reorder': {t: s.as_dict() for t, s in stats.items()}}
    extra['provenance'] = prov
    return dataclasses.replace(calib, extra=extra)


def _joints_the_fixture_lacks(args: Any, fixture: Any) -> str:
    """'the bag's joint(s) X move(s) but the fixture has no such joint' when the bag moves
    joints the fixture does not list (CONTRACT 1 ignores unknown joints, so a fixture of the
    wrong table shows only as rotations the fit cannot explain), else ''."""
    import numpy as np

    from msg_adapters.bag import read_bag
    try:
        _, joints = read_bag(args.bag, args.imu_topic, args.joint_topic, args.reorder_window)
    except Exception:  # noqa: BLE001 - a hint only; the original error stands
        return ''
    if not len(joints):
        return ''
    known = set(fixture.joint_names)
    q = np.unwrap(np.asarray(joints.positions_rad, float), axis=0)
    travel = np.nanmax(q, axis=0) - np.nanmin(q, axis=0)
    extra = [n for n, d in zip(joints.names, travel, strict=True)
             if n not in known and d > 0.01]
    if not extra:
        return ''
    names = ', '.join(repr(n) for n in extra)
    return (f"the bag's joint{'s' if len(extra) > 1 else ''} {names} move"
            f"{'' if len(extra) > 1 else 's'} but the fixture has no such joint "
            f"(fixture joints: {', '.join(fixture.joint_names)})")


def _weak_plan_hint(run_: Any, fixture: Any) -> str:
    """A clause naming what the recorded plan lacks when it is weak (fewer than the
    self-check's ``min_plan_poses`` distinct stationary poses over the run, or turns about
    fewer than three IMU axes in what the coarse start saw), for a refusal whose cause is
    then the plan rather than the unit, and what to record instead on this fixture; ``''``
    otherwise."""
    from ..core.estimator.selfcheck import SelfCheckConfig
    lacks = []
    poses = run_.ledger.distinct_poses()
    if poses < SelfCheckConfig().min_plan_poses:
        lacks.append(f'{poses} stationary poses')
    start = run_.estimator.start
    if start is not None and any('fewer than three' in n for n in start.notes):
        lacks.append('turns about fewer than three IMU axes')
    if not lacks:
        return ''
    return (f' (the plan has {" and ".join(lacks)}: too little to determine an uncalibrated '
            f'unit\'s errors; {_what_to_record(fixture)})')


#: shipped plans that determine a raw unit, in the order the hint suggests them
RAW_UNIT_PLANS = ('six_position_turns', 'savage_srt')


def fixture_turn_axes(fixture: Any, configurations: int = 8) -> int:
    """How many independent IMU axes the fixture's joints can turn the IMU about, over
    ``configurations`` random poses: the rank of the IMU-frame angular rates of unit joint
    rates (finite differences of ``R_enu_imu``). A one-axis rate table gives 1 whatever the
    plan; a two-axis table 3 (its outer axis moves in the IMU frame with the inner one)."""
    import numpy as np
    from ..core.rotation import unskew
    rng = np.random.default_rng(0)
    lo = np.array([-np.pi if j.lower is None else j.lower for j in fixture.joints])
    hi = np.array([np.pi if j.upper is None else j.upper for j in fixture.joints])
    rates = []
    h = 1e-6
    for _ in range(configurations):
        q = rng.uniform(lo, hi)
        R = fixture.R_enu_imu(q)
        for j, joint in enumerate(fixture.joints):
            if joint.kind == 'prismatic':
                continue
            dq = np.zeros(len(q))
            dq[j] = h
            dR = (fixture.R_enu_imu(q + dq) - fixture.R_enu_imu(q - dq)) / (2 * h)
            rates.append(unskew(R.T @ dR))
    if not rates:
        return 0
    s = np.linalg.svd(np.array(rates), compute_uv=False)
    return int(np.sum(s > 1e-3 * s[0]))


def _what_to_record(fixture: Any) -> str:
    """What to record instead: the shipped plans of :data:`RAW_UNIT_PLANS` that run on
    ``fixture``, or why none can (a fixture that cannot turn the IMU about three axes)."""
    from ..core.plans import build_profile, load_plan
    n = fixture_turn_axes(fixture)
    if n < 3:
        return (f'this fixture turns the IMU about {"one axis" if n == 1 else f"{n} axes"} '
                'only, so no plan on it can: calibrate on a two- or three-axis fixture')
    if not fixture.concurrent:  # a robot arm: its axes do not meet in one point
        return ('record the excitation plan generated for this chain '
                '(core.chain_plans.excitation_plan, docs/NODES.md)')
    ok = []
    for name in RAW_UNIT_PLANS:
        try:
            build_profile(load_plan(name), fixture)
        except Exception:  # noqa: BLE001 - any reason the plan does not run here
            continue
        ok.append(name)
    if ok:
        return f'record a plan such as {" or ".join(ok)}'
    return ('record a plan that turns the IMU about each of its axes with that axis near up '
            'and near down (docs/PLANS.md)')


def run(args: Any) -> int:
    """Run the sub-command (errors propagate as ImuCalibError: one line, exit 2)."""
    from ..core.fixture import load_fixture
    from ..core.imu_grade import load_grade
    from msg_adapters.bag import iter_bag, read_bag
    out = Path(args.output)
    if args.iterations < 1:
        raise InputError(f'--iterations must be >= 1, got {args.iterations}')
    if args.max_passes < 1:
        raise InputError(f'--max-passes must be >= 1, got {args.max_passes}')
    check_output_file(out, 'calib.yaml')
    fixture = load_fixture(args.fixture, urdf_options(args))
    grade = load_grade(args.imu) if args.imu else None
    if not Path(args.bag).exists():
        raise InputError(f'bag {args.bag} does not exist')
    reorder: dict[str, ReorderStats] = {}  # what the bag reader reordered, per topic
    verdict = None  # the EKF's self-check
    if args.method != 'ekf':
        from ..core.methods import oscillation, srt
        methods: dict[str, Callable[..., CalibrationResult]] = {
            'srt': srt.calibrate, 'oscillation': oscillation.calibrate}
        method = methods[args.method]
        imu, joints = read_bag(args.bag, args.imu_topic, args.joint_topic,
                               args.reorder_window, reorder)
        # the analytic methods take the parameters they do not solve for, and the consider
        # covariance, from a grade: nav_grade unless --imu says otherwise
        grade = grade or load_grade('nav_grade')
        try:
            calib = method(imu, joints, fixture, grade)
        except (RuntimeError, ValueError, ArithmeticError) as exc:
            # a non-converging compensation, a rank-deficient least squares (LinAlgError
            # is a ValueError), a degenerate fit: CONTRACT 5 wants one line, not a traceback
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise InputError(f'--method {args.method}: {msg} (does the bag {args.bag} contain '
                             f'the plan this method needs?)') from exc
        if args.method == 'srt':
            _srt_note(calib.extra.get('srt', {}))
    else:
        from ..core.estimator import load_estimator_config
        from ..core.estimator.replay import replay_run
        from . import tune_allocator
        tune_allocator()
        config = load_estimator_config(args.config)
        bar = None
        if not args.quiet:
            from tqdm import tqdm
            bar = tqdm(unit=' samples', unit_scale=True, file=sys.stderr,
                       desc=f'replay x{args.iterations}')
        passes: list[Any] = []

        def open_bag() -> Any:
            passes[:] = [iter_bag(args.bag, args.imu_topic, args.joint_topic,
                                  args.reorder_window)]
            return passes[0]

        try:
            run_ = replay_run(open_bag, fixture, grade, config, args.iterations,
                              progress=bar.update if bar is not None else None,
                              max_passes=args.max_passes)
        except InputError as exc:  # name a joint the bag moves and the fixture lacks
            hint = _joints_the_fixture_lacks(args, fixture)
            if hint:
                raise InputError(f'{exc}; {hint}') from None
            raise
        finally:
            if bar is not None:
                bar.close()
        calib = run_.estimator.estimate()
        if run_.extra_passes:
            import dataclasses
            n = max(1, args.iterations) + len(run_.extra_passes)
            est_extra = dict(calib.extra.get('estimator', {}))
            est_extra['passes'] = {'count': n, 'extra_because': list(run_.extra_passes)}
            calib = dataclasses.replace(calib, extra={**calib.extra, 'estimator': est_extra})
            if not args.quiet:
                print(f'imu-calib replay: note: {n} passes; the plan left the first '
                      f'linearisation ({run_.extra_passes[0]}): each further pass starts '
                      'from the last estimate (Savage sect. 8)', file=sys.stderr)
        reorder = passes[-1].reorder_stats
        verdict = run_.verdict
        if not verdict.passed and not args.force:
            lacks = _joints_the_fixture_lacks(args, fixture)  # the likeliest cause, if so
            raise SelfCheckError(f'{verdict.line}{_weak_plan_hint(run_, fixture)}'
                                 f'{run_.estimator.stamp_hint()}{run_.ledger.encoder_hint()}'
                                 f'{"; " * bool(lacks)}{lacks}; '
                                 'no calibration written (--force writes it, marked as '
                                 'failing)')
        note = _walk_note(calib)  # about the file written: not before a refusal
        if note and not args.quiet:
            print(note, file=sys.stderr)
        from ..core.estimator.priors import kernel_note
        note = kernel_note(calib.extra.get('estimator', {}), config)
        if note and not args.quiet:
            print(f'imu-calib replay: note: {note}', file=sys.stderr)
    _reorder_note(reorder, args.reorder_window, args.quiet)
    calib = _with_provenance(calib, args, reorder)
    if verdict is not None:  # the same rule as the node's save (core/estimator/selfcheck.py)
        import dataclasses

        from ..core.estimator.selfcheck import saved_extra
        extra, _ = saved_extra(calib.extra, verdict.as_dict(), args.force)
        assert extra is not None  # refused above
        calib = dataclasses.replace(calib, extra=extra)
    calib.save(out)
    if verdict is not None and not verdict.passed:
        print(f'imu-calib replay: warning: {verdict.line}; written because of --force, marked '
              'under provenance.self_check', file=sys.stderr)
    if not args.quiet:
        print(_summary(calib))
        if verdict is not None:
            print(verdict.line)
        failed = '' if verdict is None or verdict.passed else ' (FAILED its self-check)'
        print(f'wrote {out}{failed}')
    return 0


if __name__ == '__main__':  # python -m imu_calib_ros.cli.replay ... = imu-calib replay ...
    import sys

    from . import main
    sys.exit(main(['replay', *sys.argv[1:]]))
