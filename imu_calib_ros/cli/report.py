"""``imu-calib report CALIB.yaml [--bag BAG] [--truth T.yaml] [--compare O.yaml ...]``."""
from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``report`` sub-command."""
    from . import add_topic_arguments
    p = sub.add_parser(
        'report', help='self-contained HTML report of calibration results',
        description='Write one self-contained HTML page (plots embedded) with the values and '
                    'one-sigma uncertainties of a calibration file, optionally against a '
                    'truth file, other calibrations, and the velocity error of navigating a '
                    'bag with the calibration applied.')
    p.add_argument('calib', metavar='CALIB.yaml', help='calibration file (CONTRACT 4)')
    p.add_argument('--bag', default=None, metavar='BAG',
                   help='bag to navigate with the calibration applied (needs --fixture)')
    p.add_argument('--fixture', default=None, metavar='F',
                   help='fixture name or YAML path (CONTRACT 2), for --bag')
    p.add_argument('--truth', default=None, metavar='T.yaml',
                   help='truth file (imu-calib simulate) for error columns')
    p.add_argument('--compare', nargs='*', default=[], metavar='O.yaml',
                   help='other calibration files to show next to CALIB.yaml')
    p.add_argument('--output', '-o', default='report.html', metavar='REPORT.html',
                   help='HTML file to write (default report.html in the current directory)')
    p.add_argument('--envelope-draws', type=int, default=10, metavar='N',
                   help='with --bag: navigate N more times with calibrations drawn from '
                        'CALIB.yaml\'s covariance for its expected velocity error envelope (each '
                        'one more navigation of the bag: 0.05 s for 18,500 samples; default 10, '
                        '0: no envelope)')
    p.add_argument('--pdf', default=None, metavar='REPORT.pdf',
                   help='also write the header, verdict, parameters and plots as a PDF '
                        '(matplotlib PdfPages)')
    add_topic_arguments(p)
    p.set_defaults(func=run)


def levelled_attitude(R_enu_imu_nominal: Any, f_imu_m_s2: Any) -> Any:
    """Nominal attitude tilted so that the measured mean specific force points up (ENU).

    Coarse alignment as the estimator's: at rest the specific force is ``+g`` up, so the
    smallest rotation taking ``R f / |f|`` onto ``(0, 0, 1)`` removes the mounting tilt
    (~1 mrad, which at 1 g alone gives ~1 cm/s^2 of navigated acceleration); the heading
    stays the fixture's (accelerometers do not see it).
    """
    import numpy as np

    from ..core.rotation import rotvec_to_matrix
    up = R_enu_imu_nominal @ np.asarray(f_imu_m_s2, float)
    up = up / np.linalg.norm(up)
    axis = np.cross(up, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(axis), float(up[2])
    rv = axis / s * np.arctan2(s, c) if s > 0 else np.zeros(3)
    return rotvec_to_matrix(rv) @ R_enu_imu_nominal


def _nav_motion(imu, joints, fx, w0):  # noqa: ANN001, ANN202
    """What every navigation of the bag shares, whatever the calibration: the times from the
    first stationary window ``w0`` on, their intervals, and the fixture's motion there."""
    import numpy as np

    from ..core.methods.windows import joints_at
    i0 = w0.i0
    t = (imu.stamps_ns[i0:] - imu.stamps_ns[0]) * 1e-9
    dt = np.diff(t, prepend=t[0] - float(np.median(np.diff(t))))
    q = joints_at(imu.stamps_ns[i0:], joints, fx.joint_names)
    qd = np.gradient(q, t, axis=0)
    return t, dt, fx.kinematics(q, qd, np.gradient(qd, t, axis=0))


def _nav_velocity(calib, imu, fx, w0, motion):  # noqa: ANN001, ANN202
    """Navigated velocity error over the bag with the calibration applied.

    Starts at rest at the first stationary window ``w0``, with the EKF's mounting rotation if
    the file has one (the heading part: ~1 mrad of heading error turns into a tilt at the
    earth rate, ~0.15 m/s after 800 s on a nav-grade unit), levelled on its accelerometers;
    the IMU point's own velocity (``omega_eb x rho``, the estimator's lever arm if the file
    has one, else the fixture's nominal offset) is subtracted; the size effect is compensated
    (``compensate`` with omega_dot from the stamps). What is left is what the calibration
    leaves (plus the heading error, which the accelerometers cannot level). ``motion`` is
    :func:`_nav_motion`'s (computed once for all the calibrations navigated).
    """
    import numpy as np

    from ..core.sensor_model import compensate
    from ..core.strapdown import Strapdown
    t, dt, kin = motion
    w, f = compensate(calib.errors, imu.gyro_rad_s, imu.accel_m_s2, stamps_ns=imu.stamps_ns)
    est = (calib.extra or {}).get('estimator', {})
    R_w0 = fx.R_enu_imu(w0.q_rad)
    if 'mounting_rotvec_rad' in est:  # the EKF's mounting: R_enu_imu = R_fixture exp(m)
        from ..core.rotation import rotvec_to_matrix
        R_w0 = R_w0 @ rotvec_to_matrix(np.asarray(est['mounting_rotvec_rad'], float))
    R0 = levelled_attitude(R_w0, np.mean(f[w0.i0:w0.i1], axis=0))
    i0 = w0.i0
    nav = Strapdown(fx.site, R0).propagate(dt, w[i0:], f[i0:])
    # the IMU point's own velocity on the fixture: omega_eb x (R rho), rho in the IMU frame
    if 'lever_arm_imu_m' in est:
        rho = np.asarray(est['lever_arm_imu_m'], float)
        v_point = np.cross(kin.omega_eb_enu_rad_s, kin.R_enu_imu @ rho)
    else:
        v_point = kin.v_enu_m_s
    step = max(1, len(t) // 3000)
    return t[::step], (nav.v_enu_m_s - v_point)[::step]


def _bag_facts(args: argparse.Namespace, calib, compare):  # noqa: ANN001, ANN202
    """The bag as the report shows it: hash, joint timeline, stationary windows, Allan
    deviation, navigated velocity without calibration, with this one and with the others."""
    import dataclasses

    import numpy as np

    from ..core.calibration import CalibrationResult
    from ..core.errors import InputError
    from ..core.fixture import load_fixture
    from ..core.methods.windows import joint_positions, stationary_windows
    from ..core.sensor_model import SensorErrors
    from msg_adapters.bag import read_bag
    from ..report.bag_facts import BagFacts, content_hash, windows_noise
    if args.fixture is None:
        raise InputError('--bag needs --fixture (the navigation starts from its kinematics)')
    fx = load_fixture(args.fixture)
    imu, joints = read_bag(args.bag, args.imu_topic, args.joint_topic)
    t0 = int(imu.stamps_ns[0])
    t_imu = (imu.stamps_ns - t0).astype(np.float64) * 1e-9
    dt = float(np.median(np.diff(t_imu)))
    wins = stationary_windows(imu, joints, fx, min_duration_s=2.0)
    q = np.degrees(joint_positions(joints, fx.joint_names))
    tj = (joints.stamps_ns - t0).astype(np.float64) * 1e-9
    step = max(1, len(tj) // 4000)
    allan = windows_noise(imu.gyro_rad_s, imu.accel_m_s2, dt, [(w.i0, w.i1) for w in wins])
    if not wins:
        raise InputError(f'{args.bag}: no stationary window to start the navigation from')
    motion = _nav_motion(imu, joints, fx, wins[0])
    nav = {}
    zero = CalibrationResult.exact(SensorErrors.zeros(), calib.frame_id)
    for name, c in (('no calibration', zero), ('this calibration', calib), *compare):
        nav[name] = _nav_velocity(c, imu, fx, wins[0], motion)
    envelope = None
    draws = int(getattr(args, 'envelope_draws', 0) or 0)
    if draws > 0:
        # Monte Carlo over the file's covariance (its correlations when it has them; else
        # independent per entry, an upper bound); fixed entries with their assumed sigma
        rng = np.random.default_rng(0)
        x0, sd = calib.errors.as_vector(), calib.sigma.as_vector()
        cov = ((calib.extra or {}).get('estimator') or {}).get('parameter_covariance')
        if cov is not None:  # the filter's correlations (an EKF file since session 6)
            w, V = np.linalg.eigh(np.asarray(cov, float))
            L = V * np.sqrt(np.clip(w, 0.0, None))  # 4-digit rounding: clip tiny negatives
        else:  # no correlations in the file: independent draws, an upper bound
            L = np.diag(sd)
        runs = []
        for _ in range(draws):
            c = dataclasses.replace(calib, errors=SensorErrors.from_vector(
                x0 + L @ rng.standard_normal(len(x0))))
            runs.append(_nav_velocity(c, imu, fx, wins[0], motion)[1]
                        - nav['this calibration'][1])
        envelope = (nav['this calibration'][0], np.sqrt(np.mean(np.square(runs), axis=0)),
                    draws)
    return fx, BagFacts(str(args.bag), content_hash(args.bag), float(t_imu[-1]), len(imu),
                        1.0 / dt, fx.joint_names, tj[::step], q[::step],
                        [(w.t0_s, w.t1_s) for w in wins], allan, nav, envelope)


def run(args: argparse.Namespace) -> int:
    """Build and write the page atomically (and the PDF with ``--pdf``)."""
    from ..core.calibration import CalibrationResult
    from ..core.errors import InputError
    from ..report import build_report
    from . import check_output_file
    out = Path(args.output)
    check_output_file(out, 'report.html')
    if args.pdf:
        check_output_file(Path(args.pdf), 'report.pdf')
    calib = CalibrationResult.load(args.calib)
    truth = CalibrationResult.load(args.truth) if args.truth else None
    compare = [(Path(p).stem, CalibrationResult.load(p)) for p in args.compare]
    fixture = bag = None
    if args.bag:
        fixture, bag = _bag_facts(args, calib, compare)
    elif args.fixture:
        from ..core.fixture import load_fixture
        fixture = load_fixture(args.fixture)
    figures: list[Any] = []
    page = build_report(calib, truth, compare, title=f'IMU calibration of {calib.frame_id}: '
                        f'{Path(args.calib).name}', calib_path=str(args.calib),
                        fixture=fixture, bag=bag, figures=figures)
    tmp = out.with_name(f'.{out.name}.tmp')
    try:
        tmp.write_text(page, encoding='utf-8')
        os.replace(tmp, out)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise InputError(f'--output {out}: cannot write ({exc.strerror})') from None
    print(f'wrote {out}')
    if args.pdf:
        from ..report.pdf import write_pdf
        write_pdf(Path(args.pdf), page)
        print(f'wrote {args.pdf}')
    return 0


if __name__ == '__main__':  # python -m imu_calib_ros.cli.report ... = imu-calib report ...
    import sys

    from . import main
    sys.exit(main(['report', *sys.argv[1:]]))
