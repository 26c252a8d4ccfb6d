"""``imu-calib modulate BAG --fixture F --output OUT_BAG --mode one|two|four|continuous``.

``--fixture`` is any fixture replay takes: a shipped name, a CONTRACT 2 YAML, or a ``.urdf``
with ``--base-link`` and ``--imu-link`` (issue 15; the same :func:`~..core.fixture.load_fixture`).

Writes the body-frame (platform-base) IMU stream of a rotation-modulated recording
(core/methods/modulation.py) to a new bag, with the joint states copied.
"""
from __future__ import annotations

import argparse

from . import add_topic_arguments, add_urdf_arguments, urdf_options


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``modulate`` sub-command."""
    p = sub.add_parser('modulate', help='rotation modulation: body-frame IMU stream to a bag')
    p.add_argument('bag', metavar='BAG', help='input bag (directory or .mcap)')
    p.add_argument('--fixture', required=True, metavar='F',
                   help='fixture name, YAML path (CONTRACT 2) or .urdf (with --base-link, '
                   '--imu-link)')
    p.add_argument('--output', required=True, metavar='OUT_BAG', help='output bag path')
    p.add_argument('--mode', choices=('one', 'two', 'four', 'continuous'),
                   default='continuous',
                   help='continuous (default): every IMU sample, de-rotated, with the bias '
                        'of the revolution around it removed; one, two, four: the paper\'s '
                        'control-point variants, 1, 2 or 4 outputs per revolution')
    p.add_argument('--joint', default=None, help='modulation joint (default: the one that '
                   'turns most)')
    p.add_argument('--causal', action='store_true',
                   help='continuous mode: bias from the preceding revolution only')
    add_urdf_arguments(p)
    add_topic_arguments(p, 'read from (and write to)')
    p.add_argument('--force', '--overwrite', dest='overwrite', action='store_true',
                   help='replace an existing output (as simulate --force)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Read, demodulate, write."""
    from ..core.fixture import load_fixture
    from ..core.methods.modulation import DemodulationOptions, demodulate
    from msg_adapters.bag import read_bag, write_bag
    fixture = load_fixture(args.fixture, urdf_options(args))
    imu, joints = read_bag(args.bag, args.imu_topic, args.joint_topic)
    # --causal with a point mode: demodulate's InputError (one line, CONTRACT 5)
    out = demodulate(imu, joints, fixture,
                     DemodulationOptions(args.mode, joint=args.joint, causal=args.causal))
    write_bag(args.output, out, joints, imu_topic=args.imu_topic,
              joint_topic=args.joint_topic, overwrite=args.overwrite)
    print(f'wrote {len(out)} body-frame samples ({args.mode}) to {args.output}')
    return 0


if __name__ == '__main__':  # python -m imu_calib_ros.cli.modulate ... = imu-calib modulate ...
    import sys

    from . import main
    sys.exit(main(['modulate', *sys.argv[1:]]))
