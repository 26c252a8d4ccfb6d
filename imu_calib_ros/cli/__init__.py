"""The ``imu-calib`` command: one sub-command per module in this package.

Each sub-command module defines ``register(subparsers) -> None`` (adds its parser and sets
``func=run``) and ``run(args) -> int``. Errors derived from :class:`ImuCalibError` (and
argparse usage errors) end the program with one line on stderr and exit status 2.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys
from pathlib import Path

from ..core.errors import ImuCalibError, InputError

SUBCOMMANDS = ('simulate', 'replay', 'report', 'modulate')


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog='imu-calib', description='Turntable IMU calibration (imu_calib_ros).')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name in SUBCOMMANDS:
        importlib.import_module(f'{__name__}.{name}').register(sub)
    return parser


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
        return 2
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
