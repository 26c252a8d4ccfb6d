"""``make demo``: a simulated turntable and the live calibration node, over real DDS topics.

Starts ``turntable_sim`` (running the compressed plan ``demo_short`` at ``--speed`` times real
time, publishing ``/clock``) and ``calibration`` (``use_sim_time``) as two separate processes,
waits for the plan to finish, calls ``/calibration/save_calibration`` from a small client
node, and prints the saved estimate against the simulator's truth in engineering units, with
the one-sigma values and the error in sigmas. Exit status 0 when the calibration was saved
and reloads; 1 otherwise. Child processes are always stopped.

Run: ``python -m imu_calib_ros.demo [--speed 4] [--plan demo_short] [--grade nav_grade]``.
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from .core.sensor_model import KEY_OF_FIELD as CONTRACT_KEY
from .core.units import DEG_H_RAD_S as DEG_H, G0_M_S2 as G0, URAD

#: (label, SensorErrors field, flat indices, unit name, SI value per unit)
ROWS: list[tuple[str, str, list[int], str, float]] = [
    ('gyro bias', 'gyro_bias_rad_s', [0, 1, 2], 'deg/h', DEG_H),
    ('gyro scale', 'gyro_scale_misalignment', [0, 4, 8], 'ppm', 1e-6),
    ('gyro misalign yz,xz,xy', 'gyro_scale_misalignment', [5, 2, 1], 'urad', URAD),
    ('gyro asymmetry', 'gyro_scale_asymmetry', [0, 1, 2], 'ppm', 1e-6),
    ('gyro g-sens row x', 'gyro_g_sensitivity_rad_s_per_m_s2', [0, 1, 2], 'deg/h/g', DEG_H / G0),
    ('gyro g-sens row y', 'gyro_g_sensitivity_rad_s_per_m_s2', [3, 4, 5], 'deg/h/g', DEG_H / G0),
    ('gyro g-sens row z', 'gyro_g_sensitivity_rad_s_per_m_s2', [6, 7, 8], 'deg/h/g', DEG_H / G0),
    ('accel bias', 'accel_bias_m_s2', [0, 1, 2], 'ug', 1e-6 * G0),
    ('accel scale', 'accel_scale_misalignment', [0, 4, 8], 'ppm', 1e-6),
    ('accel misalign yz,xz,xy', 'accel_scale_misalignment', [5, 2, 1], 'urad', URAD),
    ('accel misalign zy,zx,yx', 'accel_scale_misalignment', [7, 6, 3], 'urad', URAD),
    ('accel asymmetry', 'accel_scale_asymmetry', [0, 1, 2], 'ppm', 1e-6),
    ('accel quadratic', 'accel_quadratic_per_m_s2', [0, 1, 2], 'ug/g^2', 1e-6 / G0),
    ('size effect xy,xz,yx', 'size_effect_m', [1, 2, 3], 'mm', 1e-3),
    ('size effect yz,zx,zy', 'size_effect_m', [5, 6, 7], 'mm', 1e-3),
]




def comparison_table(estimate: Any, truth: Any) -> tuple[str, int, int]:
    """Estimate vs truth in engineering units; returns (text, #within 3 sigma, #compared)."""
    lines = [f'{"parameter":<26}{"unit":<9}{"truth":>33}{"estimate":>33}{"sigma":>27}'
             f'{"err/sigma":>22}']
    within = total = 0
    fixed = set(getattr(estimate, 'fixed', ()))
    tracked = truth.tracked_truth()  # the filter tracks the total bias
    for label, attr, idx, unit, scale in ROWS:
        est = np.asarray(getattr(estimate.errors, attr), float).ravel()[idx] / scale
        sig = np.asarray(getattr(estimate.sigma, attr), float).ravel()[idx] / scale
        tru = np.asarray(getattr(tracked, attr), float).ravel()[idx] / scale
        is_fixed = CONTRACT_KEY[attr] in fixed
        ratio = np.where(sig > 0, (est - tru) / np.where(sig > 0, sig, 1), np.nan)
        if not is_fixed:
            ok = np.abs(ratio) <= 3
            within += int(np.sum(ok))
            total += int(np.sum(np.isfinite(ratio)))
        def fmt(v: Any, w: int = 11, spec: str = '.3g') -> str:  # noqa: E306 - tiny local
            return ''.join(f' {x:>{w - 1}{spec}}' for x in v)   # one space: never run together
        lines.append(f'{label:<26}{unit:<9}{fmt(tru)}{fmt(est)}{fmt(sig, 9)}'
                     f'{fmt(ratio, 7, ".2f") if not is_fixed else "   (fixed)":>22}')
    if truth.extra.get('bias_at_end'):
        lines.append('(bias truth: the turn-on value plus the simulated in-run drift at the end '
                     'of the plan, which is what the filter tracks)')
    return '\n'.join(lines), within, total


def _node_cmd(module: str, params: dict[str, Any]) -> list[str]:
    cmd = [sys.executable, '-m', f'imu_calib_ros.nodes.{module}', '--ros-args']
    for k, v in params.items():
        v = str(v).lower() if isinstance(v, bool) else v
        cmd += ['-p', f'{k}:={v}']
    return cmd


def _stop(proc: subprocess.Popen[bytes], timeout_s: float = 10.0) -> None:
    """SIGINT (clean ROS shutdown), then SIGKILL if it does not end."""
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


def call_trigger(node: Any, service: str, timeout_s: float) -> Any:
    """Call a std_srvs/Trigger service from ``node``; None on timeout."""
    import rclpy
    from std_srvs.srv import Trigger
    client = node.create_client(Trigger, service)
    if not client.wait_for_service(timeout_sec=timeout_s):
        return None
    future = client.call_async(Trigger.Request())
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout_s)
    return future.result()


def main(argv: list[str] | None = None) -> int:
    """Run the demo; exit status 0 on success."""
    ap = argparse.ArgumentParser(prog='python -m imu_calib_ros.demo', description=__doc__)
    ap.add_argument('--plan', default='demo_short')
    ap.add_argument('--fixture', default='three_axis')
    ap.add_argument('--grade', default='nav_grade')
    ap.add_argument('--speed', type=float, default=4.0,
                    help='simulated seconds per wall second (default 4)')
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--out', default='', help='directory for truth and calibration files')
    ap.add_argument('--timeout', type=float, default=280.0, help='wall-clock limit [s]')
    args = ap.parse_args(argv)
    t_start = time.monotonic()
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 100)))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.update({k: env[k] for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')})
    out = Path(args.out or tempfile.mkdtemp(prefix='imu_calib_demo_'))
    out.mkdir(parents=True, exist_ok=True)
    truth_file, calib_file = out / 'truth.yaml', out / 'calibration.yaml'
    print(f'demo: plan {args.plan}, fixture {args.fixture}, grade {args.grade}, speed '
          f'{args.speed}x, ROS_DOMAIN_ID {env["ROS_DOMAIN_ID"]}, files in {out}', flush=True)
    calib = subprocess.Popen(_node_cmd('calibration', {
        'use_sim_time': True, 'fixture': args.fixture, 'imu_grade': args.grade,
        'output_file': str(calib_file), 'imu_rate_hz': 200.0}), env=env)
    sim = subprocess.Popen(_node_cmd('turntable_sim', {
        'fixture': args.fixture, 'imu_grade': args.grade, 'plan': args.plan,
        'speed': args.speed, 'seed': args.seed, 'truth_file': str(truth_file),
        'wait_for_subscribers': 1, 'wait_timeout_s': 60.0, 'exit_when_done': True,
        'exit_after_s': 2.0, 'imu_rate_hz': 200.0}), env=env)
    import rclpy
    rclpy.init(args=[])
    node = rclpy.create_node('imu_calib_demo')
    status = 1
    try:
        limit = t_start + args.timeout
        while sim.poll() is None and time.monotonic() < limit:
            if calib.poll() is not None:
                print(f'demo: calibration node exited early ({calib.returncode})')
                return 1
            rclpy.spin_once(node, timeout_sec=0.5)
        if sim.returncode != 0:
            print(f'demo: turntable_sim failed or timed out (status {sim.returncode})')
            return 1
        print(f'demo: plan finished after {time.monotonic() - t_start:.0f} s; saving',
              flush=True)
        reply = call_trigger(node, '/calibration/save_calibration',
                             max(limit - time.monotonic(), 30.0))
        if reply is None or not reply.success:
            print(f'demo: save_calibration failed: {getattr(reply, "message", "timeout")}')
            return 1
        from .core.calibration import CalibrationResult
        estimate = CalibrationResult.load(calib_file)
        truth = CalibrationResult.load(truth_file)
        table, within, total = comparison_table(estimate, truth)
        print(table)
        print(f'demo: {within} of {total} estimated values within 3 sigma of the truth; '
              f'calibration file {calib_file}; {time.monotonic() - t_start:.0f} s wall')
        status = 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        _stop(sim)
        _stop(calib)
    return status


if __name__ == '__main__':
    sys.exit(main())
