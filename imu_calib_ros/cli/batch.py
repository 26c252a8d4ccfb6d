"""``imu-calib batch``: one calibration per bag, on a Dask cluster, and a fleet summary.

    imu-calib batch BAG... --fixture F --output-dir D [--scheduler ADDRESS] [--workers N]
                    [--k-sigma K] [--imu-topic T] [--joint-topic T] [--force] [--quiet]

Each bag is ``imu-calib replay BAG --fixture F --output D/UNIT.yaml`` (UNIT: the bag's name)
run as one Dask task (``distributed``): on a local cluster of ``--workers`` processes (default:
this machine's cores) or on a running scheduler (``--scheduler tcp://host:8786``), so a
factory line spreads over its machines (each needs this package and the bags at the same
paths). One bag's failure (bad input, a failed self-check, a crashed worker) never stops the
others: it is listed with its one-line reason. Writes ``D/fleet_units.csv`` (one row per unit:
status, reason, every parameter and its sigma), ``D/fleet_parameters.csv`` (each parameter's
median, robust sigma, range, the units beyond ``--k-sigma`` of the fleet) and
``D/fleet.html``. Exit status 0 when every bag calibrated, 1 when some failed.
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
import time
from pathlib import Path
from typing import Any

from ..core.errors import InputError
from . import absolute_topic, add_urdf_arguments


def register(subparsers: Any) -> None:
    """Add the ``batch`` sub-command."""
    p = subparsers.add_parser('batch', help='calibrate many bags on Dask and summarise the '
                              'fleet', description=__doc__.split('\n\n')[0] if __doc__ else None)
    p.add_argument('bags', nargs='+', metavar='BAG', help='bag directories or .mcap files')
    p.add_argument('--fixture', required=True, metavar='F',
                   help='fixture name, YAML path (CONTRACT 2) or .urdf')
    add_urdf_arguments(p)
    p.add_argument('--output-dir', required=True, metavar='D',
                   help='directory for UNIT.yaml per bag and the fleet summary (created)')
    p.add_argument('--scheduler', default=None, metavar='ADDRESS',
                   help='a running Dask scheduler (tcp://host:8786); default: a local '
                        'cluster on this machine')
    p.add_argument('--workers', type=int, default=None, metavar='N',
                   help='local cluster processes (default: the number of cores)')
    p.add_argument('--k-sigma', type=float, default=3.0, metavar='K',
                   help='flag units beyond K fleet sigmas in a parameter (default 3)')
    p.add_argument('--imu-topic', default='/imu/data_raw', metavar='T', type=absolute_topic,
                   help='sensor_msgs/Imu topic (default /imu/data_raw)')
    p.add_argument('--joint-topic', default='/joint_states', metavar='T', type=absolute_topic,
                   help='sensor_msgs/JointState topic (default /joint_states)')
    p.add_argument('--force', action='store_true',
                   help='replay --force: write calibrations that fail their self-check')
    p.add_argument('--quiet', action='store_true', help='no progress bar or summary')
    p.set_defaults(func=run)


def calibrate_one(bag: str, out: str, replay_args: list[str]) -> dict[str, Any]:
    """One Dask task: ``imu-calib replay`` on one bag. Never raises for a bad bag: returns
    ``{'status', 'reason', 'seconds'}`` with the command's one-line error as the reason."""
    from . import main
    t0 = time.monotonic()
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            status = main(['replay', bag, '--output', out, '--quiet', *replay_args])
    except Exception as exc:  # a bug or a crash inside: still one line, never the batch
        status, msg = 2, f'{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ""}'
        err.write(msg + '\n')
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    reason = ''
    if status != 0:
        errs = [ln for ln in lines if ': error: ' in ln]
        reason = (errs[-1] if errs else lines[-1] if lines else f'exit status {status}')
        reason = reason.split(': error: ', 1)[-1]
    return {'status': 'ok' if status == 0 else 'failed', 'reason': reason,
            'seconds': time.monotonic() - t0, 'exit_status': status}


def _unit_names(bags: list[str]) -> list[str]:
    names: list[str] = []
    for b in bags:
        base = Path(b).name
        base = base[:-5] if base.endswith('.mcap') else base
        name, k = base or 'bag', 2
        while name in names:
            name, k = f'{base}_{k}', k + 1
        names.append(name)
    return names


def run(args: Any) -> int:
    """Run the sub-command."""
    import logging

    from ..core.calibration import CalibrationResult
    from ..core.fleet import UnitOutcome, spreads, spreads_csv, units_csv
    out_dir = Path(args.output_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f'--output-dir {out_dir} is a file')
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.workers is not None and args.workers < 1:
        raise InputError(f'--workers must be >= 1, got {args.workers}')
    replay_args = ['--fixture', str(args.fixture), '--imu-topic', args.imu_topic,
                   '--joint-topic', args.joint_topic]
    for opt, val in (('--base-link', args.base_link), ('--imu-link', args.imu_link),
                     ('--site-latitude-deg', args.site_latitude_deg),
                     ('--site-height-m', args.site_height_m)):
        if val not in (None, ''):
            replay_args += [opt, str(val)]
    if args.force:
        replay_args.append('--force')
    bags = [str(Path(b).resolve()) for b in args.bags]
    units = _unit_names(args.bags)
    from distributed import Client, LocalCluster, as_completed
    cluster = None
    if args.scheduler:
        client = Client(args.scheduler)
    else:
        n = args.workers or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=min(n, len(bags)), threads_per_worker=1,
                               processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
        client = Client(cluster)
    outcomes: dict[str, UnitOutcome] = {}
    try:
        futs = {client.submit(calibrate_one, bag, str((out_dir / f'{u}.yaml').resolve()),
                              replay_args, key=f'imu-calib-{u}-{i}', pure=False): (u, bag)
                for i, (u, bag) in enumerate(zip(units, bags))}
        bar = None
        if not args.quiet:
            from tqdm import tqdm
            bar = tqdm(total=len(futs), unit=' bags', file=sys.stderr, desc='batch')
        for fut in as_completed(futs):
            u, bag = futs[fut]
            try:
                r = fut.result()
            except Exception as exc:  # the worker died (KilledWorker) or the task was lost
                first = str(exc).splitlines()[0] if str(exc) else ''
                r = {'status': 'failed', 'seconds': 0.0,
                     'reason': f'{type(exc).__name__}: {first}'}
            calib = None
            path = out_dir / f'{u}.yaml'
            if r['status'] == 'ok':
                calib = CalibrationResult.load(path)
            outcomes[u] = UnitOutcome(u, bag, r['status'], r['reason'],
                                      str(path) if calib is not None else '', r['seconds'], calib)
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    ordered = [outcomes[u] for u in units]
    sp = spreads(ordered, args.k_sigma)
    (out_dir / 'fleet_units.csv').write_text(units_csv(ordered), encoding='utf-8')
    (out_dir / 'fleet_parameters.csv').write_text(spreads_csv(sp, args.k_sigma),
                                                  encoding='utf-8')
    from ..report.fleet_report import fleet_html
    (out_dir / 'fleet.html').write_text(fleet_html(ordered, sp, args.k_sigma),
                                        encoding='utf-8')
    failed = [o for o in ordered if o.status != 'ok']
    for o in failed:
        print(f'imu-calib batch: failed: {o.unit}: {o.reason}', file=sys.stderr)
    if not args.quiet:
        flagged = sorted({u for p in sp for u, _ in p.outliers})
        print(f'{len(ordered) - len(failed)} of {len(ordered)} bags calibrated; units beyond '
              f'{args.k_sigma:g} sigma of the fleet: {", ".join(flagged) or "none"}; '
              f'wrote {out_dir}/fleet_units.csv, fleet_parameters.csv, fleet.html')
    return 1 if failed else 0


if __name__ == '__main__':
    from . import main
    sys.exit(main(['batch', *sys.argv[1:]]))
