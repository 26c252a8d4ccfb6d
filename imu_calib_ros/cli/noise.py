"""``imu-calib noise``: the unit's noise from a static bag or a calibration bag's still windows.

    imu-calib noise BAG [--imu-topic T] [--joint-topic T] [--output NOISE.yaml]
                    [--report noise.html] [--kalibr imu.yaml] [--static] [--quiet]

Overlapping Allan deviation of each gyro and accelerometer axis (streamed: memory stays
flat, however long the record), the IEEE Std 952 terms each with a 95 % interval where the
record shows them (docs in :mod:`imu_calib_ros.core.noise_fit`), one warning line per term
the record is too short for and per visible failure of the static assumption (a vibration
bump, a drift). A bag with the joint topic is a calibration bag: only its stationary windows
(every joint still, found as the coarse start finds them) are used, each on its own;
``--static`` takes the whole record instead. Writes the IMU grade file (CONTRACT 5;
``replay --imu NOISE.yaml`` accepts it), Kalibr's ``imu.yaml`` and an HTML report.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Callable

from ..core.errors import InputError
from . import absolute_topic, check_output_file

#: a joint still within this for this long is a stationary window (the coarse start's)
STATIC_TOL_RAD = 1e-4
MIN_STATIC_S = 2.0


def register(subparsers: Any) -> None:
    """Add the ``noise`` sub-command."""
    p = subparsers.add_parser('noise', help='noise characterisation: Allan deviation, IEEE '
                              '952 terms, grade and Kalibr imu.yaml (CONTRACT 5)',
                              description=__doc__.split('\n\n')[0] if __doc__ else None)
    p.add_argument('bag', metavar='BAG', help='bag directory or .mcap file')
    p.add_argument('--imu-topic', default='/imu/data_raw', metavar='T', type=absolute_topic,
                   help='sensor_msgs/Imu topic (default /imu/data_raw)')
    p.add_argument('--joint-topic', default='/joint_states', metavar='T', type=absolute_topic,
                   help='sensor_msgs/JointState topic: when the bag has it, only the '
                        'stationary windows are used (default /joint_states)')
    p.add_argument('--output', '-o', default=None, metavar='NOISE.yaml',
                   help='IMU grade file to write (replay --imu accepts it)')
    p.add_argument('--report', default=None, metavar='noise.html', help='HTML report')
    p.add_argument('--kalibr', default=None, metavar='imu.yaml',
                   help="Kalibr's imu.yaml (noise densities and random walks, Kalibr units)")
    p.add_argument('--static', action='store_true',
                   help='the whole record is static (ignore the joint topic)')
    p.add_argument('--min-static-s', type=float, default=MIN_STATIC_S, metavar='S',
                   help=f'shortest stationary window of a calibration bag (default '
                        f'{MIN_STATIC_S:g} s)')
    p.add_argument('--quiet', action='store_true', help='no progress bar or summary')
    p.set_defaults(func=run)


def accumulate_static(bag: str, imu_topic: str, progress: Callable[[int], None] | None
                      ) -> Any:
    """Stream the IMU topic into an :class:`~..core.allan.AllanAccumulator`; a gap (an
    interval over 1.5 nominal periods, CONTRACT 1) starts a new segment."""
    import numpy as np

    from ..core.allan import AllanAccumulator
    from ..core.types import GAP_PERIODS, ImuBatch
    from msg_adapters.bag import iter_bag_batches
    acc = None
    last = None
    period_ns = 0.0
    for b in iter_bag_batches(bag, imu_topic, None):
        if not len(b):
            continue
        assert isinstance(b, ImuBatch)  # no joint topic asked
        t = b.stamps_ns.astype(np.int64)
        y = np.hstack([b.gyro_rad_s, b.accel_m_s2])
        if acc is None:
            if len(t) < 2:
                raise InputError(f'{imu_topic}: too few samples for a noise characterisation')
            period_ns = float(np.median(np.diff(t)))
            acc = AllanAccumulator(period_ns * 1e-9, 6)
        dt = np.diff(np.concatenate([[t[0] if last is None else last], t]))
        cuts = np.flatnonzero((dt > GAP_PERIODS * period_ns) | (dt <= 0))
        start = 0
        for c in cuts:
            acc.add(y[start:c])
            acc.new_segment()
            start = int(c)
        acc.add(y[start:])
        last = int(t[-1])
        if progress is not None:
            progress(len(t))
    if acc is None:
        raise InputError(f'{imu_topic}: no IMU samples in {bag}')
    return acc


def accumulate_windows(bag: str, imu_topic: str, joint_topic: str, min_static_s: float
                       ) -> tuple[Any, int]:
    """The stationary windows of a calibration bag (every joint within
    :data:`STATIC_TOL_RAD`, or within six of the encoders' own noise sigmas where that is
    larger, as the estimator judges rest (``alignment.still_tolerance_rad``), for
    ``min_static_s``: ``coarse.static_windows``), one segment each."""
    import numpy as np

    from ..core.allan import windows_accumulator
    from ..core.estimator.alignment import still_tolerance_rad
    from ..core.estimator.coarse import static_windows
    from msg_adapters.bag import read_bag
    imu, joints = read_bag(bag, imu_topic, joint_topic)
    if len(imu) < 2 or len(joints) < 2:
        raise InputError(f'{bag}: too few IMU or joint samples for stationary windows')
    q = np.unwrap(joints.positions_rad, axis=0)
    t = imu.stamps_ns.astype(np.int64)
    tol = still_tolerance_rad(joints.stamps_ns, q, min_static_s, STATIC_TOL_RAD)
    tol = STATIC_TOL_RAD if tol is None else tol
    wins = static_windows(joints.stamps_ns, q, t, imu.gyro_rad_s, imu.accel_m_s2,
                          min_static_s, tol)
    if not wins:
        raise InputError(f'{bag}: no stationary window of {min_static_s:g} s (every joint '
                         f'still within {tol:g} rad); --static for a static record')
    ranges = [(int(np.searchsorted(t, w.t0_ns)), int(np.searchsorted(t, w.t1_ns)))
              for w in wins]
    return windows_accumulator(imu.gyro_rad_s, imu.accel_m_s2,
                               float(np.median(np.diff(t))) * 1e-9, ranges), len(wins)


def _write_yaml(path: Path, data: Any, comments: list[str]) -> None:
    import os
    import tempfile

    import yaml
    text = ''.join(f'# {c}\n' for c in comments) + yaml.safe_dump(
        data, sort_keys=False, default_flow_style=None, width=99)
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', dir=path.parent)
    with os.fdopen(fd, 'w', encoding='utf-8') as fh:
        fh.write(text)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


def run(args: Any) -> int:
    """Run the sub-command."""
    from ..core.noise_characterisation import characterise
    from msg_adapters.bag import list_topics
    outs = [Path(p) for p in (args.output, args.report, args.kalibr) if p]
    for out, ex in zip(outs, ('noise.yaml', 'noise.html', 'imu.yaml')):
        check_output_file(out, ex)
    if not Path(args.bag).exists():
        raise InputError(f'bag {args.bag} does not exist')
    topics = list_topics(args.bag)
    if args.imu_topic not in topics:
        raise InputError(f'{args.bag} has no topic {args.imu_topic} (it has: '
                         f'{", ".join(sorted(topics)) or "none"}); --imu-topic names it')
    if args.joint_topic in topics and not args.static:
        acc, n = accumulate_windows(args.bag, args.imu_topic, args.joint_topic,
                                    args.min_static_s)
        source = f'{n} stationary windows'
    else:
        bar = None
        if not args.quiet:
            from tqdm import tqdm
            bar = tqdm(total=topics[args.imu_topic].count, unit=' samples', unit_scale=True,
                       file=sys.stderr, desc='noise')
        try:
            acc = accumulate_static(args.bag, args.imu_topic,
                                    bar.update if bar is not None else None)
        finally:
            if bar is not None:
                bar.close()
        source = 'static record'
    result = characterise(acc.curve(), source)
    for line in result.warnings():
        print(f'imu-calib noise: warning: {line}', file=sys.stderr)
    if args.output:
        _write_yaml(Path(args.output), result.grade_dict(Path(args.output).stem),
                    ['IMU grade measured by imu-calib noise (SI units; replay --imu accepts '
                     'it). Per-axis terms with 95 % intervals under noise_characterisation.'])
    if args.kalibr:
        data, notes = result.kalibr_dict(args.imu_topic)
        _write_yaml(Path(args.kalibr), data, notes)
    if args.report:
        from ..report.noise_report import noise_report_html
        Path(args.report).write_text(noise_report_html(result, args.bag), encoding='utf-8')
    if not args.quiet:
        print(summary(result))
        for p in outs:
            print(f'wrote {p}')
    return 0


def summary(result: Any) -> str:
    """A terminal table: each term per axis with its 95 % interval or upper bound."""
    from ..core.noise_characterisation import SENSORS
    from ..core.noise_fit import TERMS
    lines = [f'noise from a {result.source}: {result.curve.duration_s:.0f} s at '
             f'{result.rate_hz:.6g} Hz']
    for sensor, col, _, units in SENSORS:
        for t in TERMS:
            cells = []
            for a in range(3):
                tf = result.fits[col + a].terms[t]
                cells.append(f'{tf.value:.3g} [{tf.low:.3g}, {tf.high:.3g}]' if tf.shown
                             else f'< {tf.high:.3g}')
            lines.append(f'  {sensor:5s} {t} [{units[t]}]: ' + ' | '.join(cells))
    return '\n'.join(lines)


if __name__ == '__main__':  # python -m imu_calib_ros.cli.noise ... = imu-calib noise ...
    from . import main
    sys.exit(main(['noise', *sys.argv[1:]]))
