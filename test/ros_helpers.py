"""Helpers shared by the tests that run nodes over real DDS (no mocks of ROS).

Importing this module does not import rclpy, so a test module can set ROS_DOMAIN_ID first.
"""
from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable


def start_node(module: str, params: dict[str, Any], cwd: Path) -> subprocess.Popen[bytes]:
    """``python -m imu_calib_ros.nodes.<module> --ros-args -p k:=v ...`` (stdout+stderr piped)."""
    cmd = [sys.executable, '-m', f'imu_calib_ros.nodes.{module}', '--ros-args']
    for k, v in params.items():
        cmd += ['-p', f'{k}:={str(v).lower() if isinstance(v, bool) else v}']
    return subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def stop_node(proc: subprocess.Popen[bytes], sig: int = signal.SIGINT,
              wait_s: float = 30.0) -> str:
    """Send ``sig`` (if still running), wait up to ``wait_s``, then kill; return the output."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGUSR1)  # the node's stacks into its output (run_node)
            time.sleep(1.0)
            proc.kill()
            proc.wait(5)
    return proc.stdout.read().decode(errors='replace') if proc.stdout else ''


def spin_until(node: Any, cond: Callable[[], bool], timeout_s: float) -> bool:
    """Spin ``node`` until ``cond()`` holds or ``timeout_s`` passes; the final ``cond()``."""
    import rclpy
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        rclpy.spin_once(node, timeout_sec=0.05)
    return cond()
