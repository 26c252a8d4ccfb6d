"""``imu-calib export``: a calibration file (CONTRACT 4) in another tool's format.

    imu-calib export CALIB.yaml --format kalibr|openvins|imu_calib|imu_tk [--output F]
                     [--noise NOISE.yaml] [--openvins-model kalibr|rpng] [--rostopic T]
                     [--update-rate HZ]

Kalibr's IMU intrinsics (``model: scale-misalignment``), OpenVINS ``kalibr_imu_chain.yaml``
(``Tw``, ``R_IMUtoGYRO``, ``Ta``, ``R_IMUtoACC``, ``Tg``), dpkoch/imu_calib (``SM``, ``bias``),
imu_tk's matrices (``F_acc.calib``, ``F_gyro.calib``). The models and their correction
formulas: :mod:`imu_calib_ros.core.exchange`. What the target cannot hold is named in one
warning line and in the file's comment. Without ``--output`` the file goes to stdout.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

#: the same as core.exchange's (the parser stays light: no numpy at --help)
FORMATS = ('kalibr', 'openvins', 'imu_calib', 'imu_tk')
OPENVINS_MODELS = ('kalibr', 'rpng')


def register(subparsers: Any) -> None:
    """Add the ``export`` sub-command."""
    p = subparsers.add_parser('export', help="a calibration in Kalibr's, OpenVINS', "
                              "imu_calib's or imu_tk's format",
                              description=__doc__.split('\n\n')[0] if __doc__ else None)
    p.add_argument('calib', metavar='CALIB.yaml', help='calibration file (CONTRACT 4)')
    p.add_argument('--format', required=True, choices=FORMATS,
                   help='target tool (models in imu_calib_ros/core/exchange.py)')
    p.add_argument('--output', '-o', default=None, metavar='F',
                   help='file to write (imu_tk: the prefix of F_acc.calib, F_gyro.calib); '
                        'default: stdout')
    p.add_argument('--noise', default=None, metavar='NOISE.yaml',
                   help='IMU grade (imu-calib noise) for the Kalibr/OpenVINS noise keys')
    p.add_argument('--openvins-model', default='kalibr', choices=OPENVINS_MODELS,
                   help='OpenVINS intrinsics model (default kalibr: lower triangular)')
    p.add_argument('--rostopic', default='/imu0', metavar='T', help='IMU topic in the file')
    p.add_argument('--update-rate', type=float, default=None, metavar='HZ',
                   help='IMU rate for the Kalibr/OpenVINS file')
    p.set_defaults(func=run)


def run(args: Any) -> int:
    """Run the sub-command."""
    from ..core.calibration import CalibrationResult
    from ..core.exchange import export
    from ..core.imu_grade import load_grade
    from . import check_output_file
    calib = CalibrationResult.load(args.calib)
    noise = load_grade(args.noise) if args.noise else None
    files, warn = export(calib, args.format, noise, args.rostopic, args.update_rate,
                         args.openvins_model)
    if warn:
        print(f'imu-calib export: warning: {warn}', file=sys.stderr)
    if args.output is None:
        for suffix, text in files.items():
            if suffix:
                print(f'# --- {suffix}')
            sys.stdout.write(text)
        return 0
    for suffix, text in files.items():
        out = Path(str(args.output) + suffix)
        check_output_file(out, 'kalibr.yaml')
        out.write_text(text, encoding='utf-8')
    return 0


if __name__ == '__main__':
    from . import main
    sys.exit(main(['export', *sys.argv[1:]]))
