"""Live performance of the calibration node and the compensator (issue 4 item 8).

A publisher process sends raw IMU at ``--imu-hz`` (stamped with the wall clock, values of an
IMU at rest) and joint states at 100 Hz; this process receives ``imu/data_corrected`` and
measures drops, latency (receive time minus stamp: publisher -> node -> us, median and 99th
percentile) and the node's CPU share (/proc). Targets: no drops, median < 2 ms, p99 < 10 ms.
Then the compensator at 5 kHz.

Run: ``.venv/bin/python bench/bench_live.py [--seconds 10]``.
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

import numpy as np


def publisher(imu_hz: float, seconds: float) -> None:
    import rclpy
    from sensor_msgs.msg import Imu, JointState
    from imu_calib_ros.nodes.common import reliable_qos
    rclpy.init()
    node = rclpy.create_node('bench_publisher')
    pub = node.create_publisher(Imu, 'imu/data_raw', reliable_qos(1000))
    jpub = node.create_publisher(JointState, 'joint_states', reliable_qos(100))
    while pub.get_subscription_count() < 1:
        rclpy.spin_once(node, timeout_sec=0.1)
    time.sleep(2.0)
    period = 1.0 / imu_hz
    t0 = time.monotonic()
    k = 0
    msg = Imu()
    msg.header.frame_id = 'imu_link'
    msg.linear_acceleration.z = 9.81
    msg.orientation_covariance[0] = -1.0
    js = JointState(name=['outer', 'middle', 'inner'], position=[0.0, 0.0, 0.0])
    while time.monotonic() - t0 < seconds:
        k += 1
        while time.monotonic() < t0 + k * period:
            pass  # busy wait: sleep() granularity is too coarse for 5 kHz
        now = time.time_ns()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 10**9)
        pub.publish(msg)
        if k % max(int(imu_hz / 100), 1) == 0:
            js.header.stamp = msg.header.stamp
            jpub.publish(js)
    print(k, flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


def cpu_seconds(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def run(node_cmd: list[str], imu_hz: float, seconds: float) -> dict[str, float]:
    import rclpy
    from sensor_msgs.msg import Imu
    from imu_calib_ros.nodes.common import sensor_qos
    node_proc = subprocess.Popen(node_cmd, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    pub_proc = subprocess.Popen([sys.executable, __file__, '--publisher', str(imu_hz),
                                 str(seconds)], stdout=subprocess.PIPE)
    rclpy.init()
    node = rclpy.create_node('bench_listener')
    lat: list[int] = []
    node.create_subscription(
        Imu, 'imu/data_corrected',
        lambda m: lat.append(time.time_ns() - m.header.stamp.sec * 10**9
                             - m.header.stamp.nanosec), sensor_qos(5000))
    cpu0 = w0 = None
    try:
        while pub_proc.poll() is None:
            rclpy.spin_once(node, timeout_sec=0.01)
            if cpu0 is None and lat:
                cpu0, w0 = cpu_seconds(node_proc.pid), time.monotonic()
        cpu1, w1 = cpu_seconds(node_proc.pid), time.monotonic()
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.01)
        sent = int(pub_proc.stdout.read().decode().split()[-1])
    finally:
        node_proc.send_signal(signal.SIGINT)
        try:
            node_proc.wait(10)
        except subprocess.TimeoutExpired:
            node_proc.kill()
        node.destroy_node()
        rclpy.try_shutdown()
    a = np.array(lat) * 1e-6
    return {'sent': sent, 'received': len(a), 'dropped': sent - len(a),
            'median_ms': float(np.median(a)) if a.size else float('nan'),
            'p99_ms': float(np.percentile(a, 99)) if a.size else float('nan'),
            'cpu_share': (cpu1 - cpu0) / (w1 - w0) if cpu0 is not None else float('nan')}


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == '--publisher':
        publisher(float(sys.argv[2]), float(sys.argv[3]))
        return 0
    ap = argparse.ArgumentParser()
    ap.add_argument('--seconds', type=float, default=10.0)
    args = ap.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(101, 200)))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    py = [sys.executable, '-m']
    r = run(py + ['imu_calib_ros.nodes.calibration', '--ros-args', '-p', 'imu_rate_hz:=1000.0',
                  '-p', 'frame_id:=imu_link'], 1000.0, args.seconds)
    print(f'calibration @1 kHz IMU + 100 Hz joints: {r}')
    ok = r['dropped'] == 0 and r['median_ms'] < 2.0 and r['p99_ms'] < 10.0
    from imu_calib_ros.core.calibration import CalibrationResult
    from imu_calib_ros.core.sensor_model import SensorErrors
    path = Path(tempfile.mkdtemp()) / 'zero.yaml'
    CalibrationResult(SensorErrors.zeros(), SensorErrors.zeros(), 'imu_link').save(path)
    c = run(py + ['imu_calib_ros.nodes.compensator', '--ros-args', '-p',
                  f'calibration_file:={path}', '-p', 'imu_rate_hz:=5000.0'], 5000.0,
            args.seconds)
    print(f'compensator @5 kHz: {c}')
    ok = ok and c['dropped'] == 0
    print('targets met' if ok else 'targets NOT met')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
