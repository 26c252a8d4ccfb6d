"""The ``imu-calib`` command: one sub-command per module in this package.

Each sub-command module defines ``register(subparsers) -> None`` (adds its parser and sets
``func=run``) and ``run(args) -> int``. Errors derived from :class:`ImuCalibError` (and
argparse usage errors) end the program with one line on stderr and exit status 2.
``python -m imu_calib_ros.cli`` is ``imu-calib``; ``python -m imu_calib_ros.cli.replay ...`` is
``imu-calib replay ...`` (each sub-command module). Start-up stays light (``--help`` imports
no numpy/scipy): sub-command modules import the core inside ``run``.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys
from pathlib import Path
from typing import Any

from ..core.errors import ImuCalibError, InputError

SUBCOMMANDS = ('simulate', 'replay', 'report', 'modulate', 'noise', 'export', 'import', 'batch')

#: Where "CONTRACT n" in the help texts points (the external contract, in the repository).
CONTRACT_NOTE = ('"CONTRACT n" is section n of the external contract: docs/CONTRACT.md in the '
                 'source tree (installed as share/imu_calib_ros/docs/CONTRACT.md).')


class _VersionAction(argparse.Action):
    """``--version``: the package version, read only when asked (one source: package.xml)."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS,
                 default: str = argparse.SUPPRESS, help: str | None = None) -> None:
        super().__init__(option_strings, dest, nargs=0, default=default, help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        from .. import __version__
        print(f'{parser.prog} {__version__}')
        parser.exit()


def absolute_topic(name: str) -> str:
    """A topic name from the command line as a bag stores it: absolute.

    ROS 2 bags record fully qualified names (``/imu/data_raw``); a name given without the
    leading slash (``imu/data_raw``) is the same topic in the root namespace.
    """
    return name if not name or name.startswith('/') else f'/{name}'


def add_topic_arguments(parser: argparse.ArgumentParser, what: str = 'read from') -> None:
    """``--imu-topic`` and ``--joint-topic`` with their help (``what``: read from / write to)."""
    parser.add_argument('--imu-topic', default='/imu/data_raw', metavar='T', type=absolute_topic,
                        help=f'sensor_msgs/Imu topic to {what} the bag (default /imu/data_raw; '
                             'a name without the leading slash means the same topic)')
    parser.add_argument('--joint-topic', default='/joint_states', metavar='T',
                        type=absolute_topic,
                        help=f'sensor_msgs/JointState topic to {what} the bag (default '
                             '/joint_states; a name without the leading slash means the same '
                             'topic)')


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog='imu-calib', description='Turntable IMU calibration (imu_calib_ros).',
        epilog=CONTRACT_NOTE)
    parser.add_argument('--version', action=_VersionAction,
                        help='print the version and exit (CONTRACT 5)')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name in SUBCOMMANDS:
        importlib.import_module(f'{__name__}.{name}').register(sub)
    for p in sub.choices.values():
        p.epilog = p.epilog or CONTRACT_NOTE
    return parser


def add_urdf_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of a URDF fixture (issue 15: ``--fixture robot.urdf --base-link B
    --imu-link L``)."""
    g = parser.add_argument_group('URDF fixture (a robot arm or any chain as the turntable)')
    g.add_argument('--base-link', default='', metavar='B',
                   help='with a .urdf fixture: the link fixed to the earth (chain start)')
    g.add_argument('--imu-link', default='', metavar='L',
                   help='with a .urdf fixture: the link the IMU frame is (chain end)')
    g.add_argument('--site-latitude-deg', type=float, default=None, metavar='DEG',
                   help='site latitude (overrides the URDF\'s <imu_calib_site>)')
    g.add_argument('--site-height-m', type=float, default=None, metavar='M',
                   help='site ellipsoidal height (overrides the URDF\'s <imu_calib_site>)')


def urdf_options(args: Any) -> Any:
    """The :class:`~..core.urdf_fixture.UrdfOptions` of the parsed arguments."""
    from ..core.urdf_fixture import UrdfOptions
    return UrdfOptions(getattr(args, 'base_link', ''), getattr(args, 'imu_link', ''),
                       getattr(args, 'site_latitude_deg', None),
                       getattr(args, 'site_height_m', None))


def tune_allocator() -> None:
    """Keep a long replay's numpy temporaries on the heap (glibc only; elsewhere nothing).

    glibc serves allocations above its mmap threshold (128 KiB, raised only when such a
    block is freed) with fresh pages from the kernel and returns them on free. A replay
    allocates and frees arrays of one to a few MiB per batch, so every batch page-faults its
    temporaries in again: measured on an hour of 2 kHz data, 2.2 million minor faults and
    4.5 s of system time; with a fixed 32 MiB threshold (and a trim threshold above it)
    95 thousand and 1.2 s. Peak memory is unchanged (the same arrays, reused).
    """
    import ctypes
    import ctypes.util
    name = ctypes.util.find_library('c')
    try:
        libc = ctypes.CDLL(name) if name else None
        if libc is not None and hasattr(libc, 'mallopt'):
            libc.mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD
            libc.mallopt(-1, 256 << 20)  # M_TRIM_THRESHOLD
    except OSError:  # pragma: no cover - not glibc: nothing to tune
        pass


def check_output_file(out: Path, example: str) -> None:
    """``--output`` must name a file in an existing directory (one line otherwise)."""
    if out.is_dir():
        raise InputError(f'--output {out} is a directory; give a file name like {example}')
    if not out.parent.is_dir():
        raise InputError(f'--output: directory {out.parent} does not exist')


class _Held(logging.Handler):
    """Holds the core's log records while a sub-command runs."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point.

    The core's warnings (e.g. rejected input samples) are printed as
    ``imu-calib CMD: warning: ...`` after a successful run; after a failure only the one
    error line is printed (CONTRACT 5), which already says what went wrong.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    log = logging.getLogger('imu_calib_ros')
    held = _Held()
    log.addHandler(held)
    propagate, log.propagate = log.propagate, False
    status = 2
    try:
        status = int(args.func(args) or 0)
        return status
    except ImuCalibError as exc:
        print(f'imu-calib {args.command}: error: {exc}', file=sys.stderr)
        status = int(getattr(exc, 'exit_status', 2))
        return status
    except KeyboardInterrupt:
        print(f'imu-calib {args.command}: interrupted', file=sys.stderr)
        status = 130
        return 130
    finally:
        log.removeHandler(held)
        log.propagate = propagate
        if status == 0:
            for r in held.records:
                print(f'imu-calib {args.command}: {r.levelname.lower()}: {r.getMessage()}',
                      file=sys.stderr)


if __name__ == '__main__':
    sys.exit(main())
