"""``imu-calib import``: another tool's calibration as a CONTRACT 4 file.

    imu-calib import FILE --format kalibr|openvins|imu_calib|imu_tk --output CALIB.yaml
                     [--frame-id F]

The inverse of ``imu-calib export`` (imu_tk: FILE is the prefix of FILE_acc.calib and
FILE_gyro.calib), so a Kalibr or imu_tk result can drive our compensator and be compared in
our report. Our body frame is the one where the gyro misalignment is symmetric (CONTRACT 3):
the rotation from the tool's frame is kept under ``provenance.imported_from.R_b_tool``.
Sigmas are written as 0 (the files hold none); what the format cannot hold is listed as fixed.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from ..core.errors import InputError

#: the same as core.exchange's (the parser stays light: no numpy at --help)
FORMATS = ('kalibr', 'openvins', 'imu_calib', 'imu_tk')


def register(subparsers: Any) -> None:
    """Add the ``import`` sub-command."""
    p = subparsers.add_parser('import', help="a Kalibr, OpenVINS, imu_calib or imu_tk "
                              'calibration as a CONTRACT 4 file',
                              description=__doc__.split('\n\n')[0] if __doc__ else None)
    p.add_argument('file', metavar='FILE', help='the tool\'s file (imu_tk: the prefix)')
    p.add_argument('--format', required=True, choices=FORMATS, help='the tool that wrote FILE')
    p.add_argument('--output', '-o', required=True, metavar='CALIB.yaml',
                   help='calibration file to write (CONTRACT 4)')
    p.add_argument('--frame-id', default='imu_link', metavar='F', help='IMU frame id')
    p.set_defaults(func=run)


def run(args: Any) -> int:
    """Run the sub-command."""
    from ..core.exchange import import_text
    from . import check_output_file
    out = Path(args.output)
    check_output_file(out, 'calib.yaml')
    suffixes = ('_acc.calib', '_gyro.calib') if args.format == 'imu_tk' else ('',)
    texts = {}
    for s in suffixes:
        p = Path(str(args.file) + s)
        if not p.is_file():
            raise InputError(f'{p} does not exist')
        texts[s] = p.read_text(encoding='utf-8')
    calib, _ = import_text(texts, args.format, str(args.file), args.frame_id)
    calib.save(out)
    return 0


if __name__ == '__main__':
    from . import main
    sys.exit(main(['import', *sys.argv[1:]]))
