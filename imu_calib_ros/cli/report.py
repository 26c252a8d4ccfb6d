"""``imu-calib report CALIB.yaml [--bag BAG] [--truth T.yaml] [--compare O.yaml ...]``."""
from __future__ import annotations

import argparse
import os
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``report`` sub-command."""
    p = sub.add_parser('report', help='self-contained HTML report of calibration results')
    p.add_argument('calib', help='calibration file (CONTRACT 4)')
    p.add_argument('--bag', default=None,
                   help='bag to navigate with the calibration applied (needs --fixture)')
    p.add_argument('--fixture', default=None, help='fixture YAML (for --bag)')
    p.add_argument('--truth', default=None, help='truth file (simulator) for error columns')
    p.add_argument('--compare', nargs='*', default=[], help='other calibration files')
    p.add_argument('--output', default='report.html')
    p.add_argument('--imu-topic', default='/imu/data_raw')
    p.add_argument('--joint-topic', default='/joint_states')
    p.set_defaults(func=run)


def _nav_velocity(args: argparse.Namespace, calib):  # noqa: ANN001, ANN202
    import numpy as np

    from ..core.errors import InputError
    from ..core.fixture import load_fixture
    from ..core.methods.windows import joints_at
    from ..core.sensor_model import compensate
    from ..core.strapdown import Strapdown
    from ..msg_adapters.bag import read_bag
    if args.fixture is None:
        raise InputError('--bag needs --fixture (the navigation starts from its kinematics)')
    fx = load_fixture(args.fixture)
    imu, joints = read_bag(args.bag, args.imu_topic, args.joint_topic)
    w, f = compensate(calib.errors, imu.gyro_rad_s, imu.accel_m_s2, stamps_ns=imu.stamps_ns)
    q0 = joints_at(imu.stamps_ns[:1], joints, fx.joint_names)[0]
    t = (imu.stamps_ns - imu.stamps_ns[0]) * 1e-9
    dt = np.diff(t, prepend=t[0] - float(np.median(np.diff(t))))
    nav = Strapdown(fx.site, fx.R_enu_imu(q0)).propagate(dt, w, f)
    step = max(1, len(t) // 3000)
    # the IMU point stays within millimetres of the axes: navigated velocity = its error
    return t[::step], nav.v_enu_m_s[::step]


def run(args: argparse.Namespace) -> int:
    """Build and write the page atomically."""
    from ..core.calibration import CalibrationResult
    from ..report import build_report
    calib = CalibrationResult.load(args.calib)
    truth = CalibrationResult.load(args.truth) if args.truth else None
    compare = [(Path(p).stem, CalibrationResult.load(p)) for p in args.compare]
    nav = _nav_velocity(args, calib) if args.bag else None
    page = build_report(calib, truth, compare, title=f'IMU calibration: {args.calib}',
                        nav_velocity=nav)
    out = Path(args.output)
    tmp = out.with_name(f'.{out.name}.tmp')
    tmp.write_text(page, encoding='utf-8')
    os.replace(tmp, out)
    print(f'wrote {out}')
    return 0
