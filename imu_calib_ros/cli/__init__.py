"""The ``imu-calib`` command: one sub-command per module in this package.

Each sub-command module defines ``register(subparsers) -> None`` (adds its parser and sets
``func=run``) and ``run(args) -> int``. Errors derived from :class:`ImuCalibError` (and
argparse usage errors) end the program with one line on stderr and exit status 2.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from ..core.errors import ImuCalibError

SUBCOMMANDS = ('simulate', 'replay', 'report', 'modulate')


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog='imu-calib', description='Turntable IMU calibration (imu_calib_ros).')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name in SUBCOMMANDS:
        importlib.import_module(f'{__name__}.{name}').register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ImuCalibError as exc:
        print(f'imu-calib {args.command}: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'imu-calib {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
