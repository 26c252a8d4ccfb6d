"""Issue 17 item 1, live: the calibration node puts raw IMU back in stamp order within its
reorder window and counts what still comes too late.

Real rclpy over DDS: the node runs as a child process started with --ros-args; this process
publishes raw IMU with pairs of stamps swapped (as a transport with receipt jitter larger
than the sample period delivers them) and listens to the corrected stream and /diagnostics.
"""
from __future__ import annotations

import os
import random
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 200)))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402
from ros_helpers import spin_until, start_node, stop_node  # noqa: E402
from rclpy.node import Node  # noqa: E402

from imu_calib_ros.nodes.common import reliable_qos  # noqa: E402

T0 = 2_000_000_000_000
PERIOD_NS = 2_000_000
N = 600


@pytest.fixture(scope='module')
def ros() -> Iterator[Node]:
    rclpy.init(args=[])
    node = rclpy.create_node(f'test_reorder_{os.getpid()}')
    yield node
    node.destroy_node()
    rclpy.try_shutdown()


def arrival_order() -> np.ndarray:
    """Stamps in the order they are sent: every fourth pair swapped (150 late by a period)."""
    k = np.arange(N)
    order = k.copy()
    pairs = k[(k % 4 == 0) & (k + 1 < N)]
    order[pairs], order[pairs + 1] = pairs + 1, pairs
    return T0 + PERIOD_NS * (order + 1)


def imu_msg(stamp_ns: int) -> Any:
    from sensor_msgs.msg import Imu
    m = Imu()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(stamp_ns), 10**9)
    m.header.frame_id = 'imu_link'
    m.linear_acceleration.z = 9.81
    return m


@pytest.mark.parametrize('window_s', [0.2, 0.0])
def test_out_of_order_stamps_within_the_window_are_all_accepted(ros: Node, tmp_path: Path,
                                                                window_s: float) -> None:
    """With the window (0.2 s here, a loaded machine's scheduling on top of the 2 ms
    swap) every sample is corrected and published, in stamp order, none rejected, the swaps
    counted as reordered; without it (0: the node before issue 17) the 150 late ones are
    rejected as out of order."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Imu
    proc = start_node('calibration', {'fixture': 'three_axis', 'frame_id': 'imu_link',
                                      'imu_rate_hz': 500.0,
                                      'estimator_mode': 'thread', 'diagnostics_rate_hz': 5.0,
                                      'reorder_window_s': window_s}, tmp_path)
    corrected: list[int] = []
    diags: list[Any] = []
    subs = [ros.create_subscription(
        Imu, 'imu/data_corrected',
        lambda m: corrected.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec),
        reliable_qos(5000)),
        ros.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 100)]
    pub = ros.create_publisher(Imu, 'imu/data_raw', reliable_qos(5000))
    stamps = arrival_order()
    swapped = int((stamps[1:] < np.maximum.accumulate(stamps)[:-1]).sum())
    assert swapped == 150

    def values() -> dict[str, str]:
        found = [s for d in diags for s in d.status if s.name.endswith('IMU calibration')]
        return {kv.key: kv.value for kv in found[-1].values} if found else {}

    def settled() -> bool:
        v = values()
        return int(v.get('published', 0)) + int(v.get('rejected.node.out_of_order', 0)) >= N
    try:
        assert spin_until(ros, lambda: pub.get_subscription_count() > 0
                          and subs[0].get_publisher_count() > 0
                          and subs[1].get_publisher_count() > 0, 90.0), stop_node(proc)
        time.sleep(1.0)
        for ns in stamps.tolist():
            pub.publish(imu_msg(ns))
            rclpy.spin_once(ros, timeout_sec=0.0)
            time.sleep(PERIOD_NS * 1e-9)
        assert spin_until(ros, settled, 30.0), values()
        spin_until(ros, lambda: len(corrected) >= int(values()['published']), 10.0)
        v = values()
    finally:
        log = stop_node(proc)
        for s in subs:
            ros.destroy_subscription(s)
        ros.destroy_publisher(pub)
    assert 'Traceback' not in log, log
    assert int(v['imu']) == N, v
    got = np.array(corrected, np.int64)
    assert np.all(np.diff(got) > 0)  # the corrected stream is in stamp order
    if window_s > 0:
        assert v['published'] == str(N) and v.get('rejected.node.out_of_order', '0') == '0', v
        assert v['reorder.reordered'] == str(swapped) and v.get('reorder.late', '0') == '0', v
        np.testing.assert_array_equal(got, np.sort(stamps))
    else:
        assert v['published'] == str(N - swapped), v
        assert v['rejected.node.out_of_order'] == str(swapped), v
        assert v['reorder.late'] == str(swapped), v
