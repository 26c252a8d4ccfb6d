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


def comparison_table(estimate: Any, truth: Any) -> tuple[str, int, int]:
    """Estimate vs truth in engineering units, one row per parameter entry, laid out by
    :mod:`imu_calib_ros.core.param_table` (the blocks, units and fixed marks of the
    ``replay`` summary and the report); returns (text, #within 3 sigma, #compared)."""
    from .core.param_table import blocks, fmt, folded_line
    tb = {b.key: b for b in blocks(estimate, truth.tracked_truth())}  # the filter tracks
    lines = [f'{"parameter":<18}{"unit":>8}{"truth":>12}{"estimate":>12}{"sigma":>10}'
             f'{"err/sigma":>11}']
    within = total = 0
    bl = blocks(estimate)
    for b in bl:
        if b.folded:
            continue
        for idx in b.entries():
            v, s, tv = (float(x[idx]) for x in (b.value, b.sigma, tb[b.key].value))
            if b.fixed[idx]:
                z_txt = 'fixed'
            else:
                z = (v - tv) / s if s > 0 else float('nan')
                if np.isfinite(z):
                    total += 1
                    within += int(abs(z) <= 3)
                z_txt = f'{z:+.2f}'
            lines.append(f'{b.label + "[" + b.name_of(idx) + "]":<18}{str(b.units[idx]):>8}'
                         f'{fmt(tv):>12}{fmt(v):>12}{fmt(s, 2):>10}{z_txt:>11}')
    folded = [b for b in bl if b.folded]
    if folded:
        lines.append(folded_line(folded))
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
