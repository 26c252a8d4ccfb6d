"""``imu-calib simulate``: simulate a turntable run and write it as a ROS 2 bag plus truth.

    imu-calib simulate --fixture F --plan P --imu GRADE|FILE --output BAG
                       [--rate HZ] [--joint-rate HZ] [--seed N] [--storage mcap|sqlite3]
                       [--no-noise] [--no-errors] [--imu-topic T] [--joint-topic T]
                       [--frame-id F] [--truth PATH] [--force]
                       [--joint-offset-sigma-rad RAD] [--link-sigma-m M]

F, P and GRADE are shipped names (``config/fixtures``, ``config/plans``, ``config/imus``) or
paths. ``BAG`` is a bag directory, or a single file if it ends in ``.mcap``. The true
parameters go to ``truth.yaml`` beside the bag (in the bag's parent directory; ``--truth``
chooses another path) in the CONTRACT 4 layout with the extra keys ``mounting``, ``noise``
and ``provenance`` (and ``chain_errors``: the arm's drawn joint zero offsets and joint-origin
errors, with ``--joint-offset-sigma-rad``/``--link-sigma-m``). Existing outputs are refused
unless ``--force``; nothing partial is left behind on failure (temporary names, then rename).
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

from ..core.errors import ConfigError, InputError
from . import add_topic_arguments, add_urdf_arguments, urdf_options

IMU_RATE_MAX_HZ = 100_000.0


def register(subparsers: Any) -> None:
    """Add the ``simulate`` sub-command."""
    p = subparsers.add_parser(
        'simulate', help='simulate a calibration run into a ROS 2 bag and truth.yaml',
        description=__doc__.split('\n\n')[0] if __doc__ else None)
    p.add_argument('--fixture', required=True, metavar='F',
                   help='fixture: shipped name or YAML path (CONTRACT 2), or a .urdf with '
                   '--base-link and --imu-link')
    add_urdf_arguments(p)
    add_chain_error_arguments(p)
    p.add_argument('--plan', required=True, metavar='P',
                   help='motion plan: shipped name or YAML path')
    p.add_argument('--imu', required=True, metavar='GRADE|FILE',
                   help='IMU grade: shipped name (e.g. nav_grade, mems_mti1) or YAML path')
    p.add_argument('--output', '-o', required=True, metavar='BAG',
                   help='bag directory to create, or a file ending in .mcap')
    p.add_argument('--rate', type=float, default=200.0, metavar='HZ',
                   help='IMU sample rate [Hz] (default 200)')
    p.add_argument('--joint-rate', type=float, default=100.0, metavar='HZ',
                   help='joint-state rate [Hz] (default 100)')
    p.add_argument('--seed', type=int, default=0, metavar='N',
                   help='random seed for true errors, mounting and noise (default 0)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='bag storage for a bag directory (default mcap)')
    p.add_argument('--no-noise', action='store_true',
                   help='no random noise (white noise, bias drift, encoder noise)')
    p.add_argument('--no-errors', action='store_true',
                   help='an error-free IMU (all constant sensor errors zero)')
    add_topic_arguments(p, 'write to')
    p.add_argument('--frame-id', default='imu_link', metavar='F',
                   help='IMU header.frame_id and calibration frame_id (default imu_link)')
    p.add_argument('--truth', default=None, metavar='PATH',
                   help='truth file (default: truth.yaml in the directory of BAG)')
    p.add_argument('--force', action='store_true',
                   help='replace existing output bag and truth file')
    p.set_defaults(func=run)


def add_chain_error_arguments(parser: argparse.ArgumentParser) -> None:
    """``--joint-offset-sigma-rad``, ``--link-sigma-m``: simulate an uncalibrated arm
    (:attr:`~..core.simulator.SimConfig.joint_offset_sigma_rad`; the ``turntable_sim`` node's
    parameters of the same names)."""
    g = parser.add_argument_group('errors of the simulated chain (the data come from it, the '
                                  'estimator gets the nominal one)')
    g.add_argument('--joint-offset-sigma-rad', type=float, default=0.0, metavar='RAD',
                   help='each revolute joint\'s zero off by N(0, RAD) (e.g. 1e-3; default 0)')
    g.add_argument('--link-sigma-m', type=float, default=0.0, metavar='M',
                   help='each joint origin (link lengths, offsets) off by N(0, M) per '
                   'coordinate; not on a turntable (axes through one point) (e.g. 2e-3; '
                   'default 0)')


def _sigma(value: float, name: str) -> float:
    if not math.isfinite(value) or value < 0.0:
        raise ConfigError(f'must be a finite number >= 0, got {value!r}', f'argument {name}')
    return float(value)


def truth_path_for(output: Path, truth: str | None) -> Path:
    """Where the truth file goes: ``--truth``, else ``truth.yaml`` beside the bag."""
    return Path(truth) if truth else output.parent / 'truth.yaml'


def _positive_rate(value: float, name: str) -> float:
    if not math.isfinite(value) or value <= 0.0:
        raise ConfigError(f'must be a positive number of Hz, got {value!r}', f'argument {name}')
    if value > IMU_RATE_MAX_HZ:
        raise ConfigError(f'{value!r} Hz is above the supported {IMU_RATE_MAX_HZ:g} Hz',
                          f'argument {name}')
    return float(value)


def _check_outputs(output: Path, truth: Path, storage: str, force: bool) -> None:
    if output.suffix == '.mcap' and storage != 'mcap':
        raise ConfigError(f'a .mcap file needs --storage mcap, not {storage}',
                          'argument --output')
    for path, opt in ((output, '--output'), (truth, '--truth')):
        if not path.parent.is_dir():
            raise ConfigError(f'directory {str(path.parent)!r} does not exist',
                              f'argument {opt}')
        if (path.exists() or path.is_symlink()) and not force:
            raise ConfigError(f'{str(path)!r} exists already (use --force to replace it)',
                              f'argument {opt}')
    if output.resolve() == truth.resolve():
        raise ConfigError('the truth file and the bag must differ', 'argument --truth')
    if truth.is_dir():
        raise ConfigError(f'{str(truth)!r} is a directory', 'argument --truth')


class _Progress:
    """A tqdm bar on stderr, shown only on a terminal and only once a stage lasts > 1 s."""

    def __init__(self, total: float, desc: str, unit: str) -> None:
        from tqdm import tqdm
        self._bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, delay=1.0,
                         disable=not sys.stderr.isatty(), leave=False, dynamic_ncols=True)
        self._done = 0.0

    def add(self, n: float) -> None:
        """Advance by ``n`` units."""
        self._bar.update(n)

    def fraction(self, f: float) -> None:
        """Set the fraction done (0..1) of a bar whose total is 100 %."""
        step = 100.0 * f - self._done
        if step > 0:
            self._bar.update(step)
            self._done += step

    def close(self) -> None:
        self._bar.close()


def run(args: argparse.Namespace) -> int:
    """Simulate and write the bag and the truth file (see module docstring)."""
    rate = _positive_rate(args.rate, '--rate')
    joint_rate = _positive_rate(args.joint_rate, '--joint-rate')
    if args.seed < 0:
        raise ConfigError(f'must be a non-negative integer, got {args.seed}', 'argument --seed')
    if not args.frame_id:
        raise ConfigError('must not be empty', 'argument --frame-id')
    offset_sigma = _sigma(args.joint_offset_sigma_rad, '--joint-offset-sigma-rad')
    link_sigma = _sigma(args.link_sigma_m, '--link-sigma-m')
    for topic, opt in ((args.imu_topic, '--imu-topic'), (args.joint_topic, '--joint-topic')):
        if not topic.startswith('/') or not topic[1:2].isalpha() or ' ' in topic:
            raise ConfigError(f'not a valid topic name: {topic!r}', f'argument {opt}')
    if args.imu_topic == args.joint_topic:
        raise ConfigError('the IMU and joint topics must differ', 'argument --joint-topic')
    output = Path(args.output)
    truth_path = truth_path_for(output, args.truth)
    _check_outputs(output, truth_path, args.storage, args.force)

    from ..core import simulator
    from ..core.fixture import load_fixture
    from ..core.imu_grade import load_grade
    from ..core.plans import build_profile, load_plan
    from ..core.sensor_model import SensorErrors
    from msg_adapters.bag import remove_bag, write_bag

    fixture = load_fixture(args.fixture, urdf_options(args))
    plan = load_plan(args.plan)
    grade = load_grade(args.imu)
    profile = build_profile(plan, fixture)

    cfg = simulator.SimConfig(imu_rate_hz=rate, joint_rate_hz=joint_rate, seed=args.seed,
                              noise=not args.no_noise, frame_id=args.frame_id,
                              joint_offset_sigma_rad=offset_sigma, link_sigma_m=link_sigma)
    t0 = time.monotonic()
    bar = _Progress(100.0, f'simulating {profile.duration_s:.0f} s', '%')
    try:
        result = simulator.simulate(fixture, profile, grade, cfg,
                                    errors=SensorErrors.zeros() if args.no_errors else None,
                                    progress=bar.fraction)
    except ValueError as exc:  # e.g. a plan shorter than one IMU interval
        raise InputError(f'cannot simulate plan {plan.name!r} on this fixture: {exc}') from None
    finally:
        bar.close()
    t_sim = time.monotonic() - t0

    imu = dataclasses.replace(result.imu, frame_id=args.frame_id)
    truth = result.truth
    provenance = {
        'tool': 'imu-calib simulate',
        'fixture': str(args.fixture), 'plan': str(args.plan), 'imu': str(args.imu),
        'plan_name': plan.name, 'grade_name': grade.name,
        'imu_rate_hz': rate, 'joint_rate_hz': joint_rate, 'seed': int(args.seed),
        'noise': not args.no_noise, 'errors': not args.no_errors,
        'duration_s': float(profile.duration_s),
        'bag': output.name, 'storage': 'mcap' if output.suffix == '.mcap' else args.storage,
        'imu_topic': args.imu_topic, 'joint_topic': args.joint_topic,
        'imu_samples': len(imu), 'joint_samples': len(result.joints),
    }
    if offset_sigma or link_sigma:
        provenance.update(joint_offset_sigma_rad=offset_sigma, link_sigma_m=link_sigma)
    extra = dict(truth.extra)
    extra.setdefault('noise', grade.noise_dict() if not args.no_noise else {})
    extra['provenance'] = {**dict(extra.get('provenance', {})), **provenance}
    truth = dataclasses.replace(truth, frame_id=args.frame_id, extra=extra)

    # truth first under a temporary name, then the bag (atomic), then rename the truth:
    # any failure leaves neither file behind.
    tmp_truth = truth_path.with_name(f'.{truth_path.stem}.partial-{os.getpid()}.yaml')
    try:
        truth.save(tmp_truth)
        bar = _Progress(len(imu) + len(result.joints), 'writing bag', 'msg')
        try:
            write_bag(output, imu, result.joints, imu_topic=args.imu_topic,
                      joint_topic=args.joint_topic, storage=args.storage,
                      frame_id=args.frame_id, overwrite=args.force, progress=bar.add)
        finally:
            bar.close()
        try:
            os.replace(tmp_truth, truth_path)
        except OSError as exc:
            remove_bag(output)
            raise ConfigError(f'cannot write truth file ({exc.strerror})',
                              str(truth_path)) from None
    finally:
        try:
            tmp_truth.unlink()
        except FileNotFoundError:
            pass
    print(f'wrote {output} ({len(imu)} IMU + {len(result.joints)} joint msgs, '
          f'{profile.duration_s:.1f} s, simulated in {t_sim:.1f} s) and {truth_path}')
    return 0


__all__ = ['register', 'run', 'truth_path_for']


if __name__ == '__main__':  # python -m imu_calib_ros.cli.simulate ... = imu-calib simulate ...
    import sys

    from . import main
    sys.exit(main(['simulate', *sys.argv[1:]]))
