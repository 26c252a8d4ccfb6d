"""``bag_player``: play a ROS 2 bag's IMU and joint-state topics with ``/clock``.

Without ros2cli there is no ``ros2 bag play`` here; this node fills that gap for our two
topics, so the live ``calibration`` node can be run against a recorded bag on simulated time
(``use_sim_time:=true``), exactly as it would behind ``ros2 bag play --clock``. The bag is read
with rosbags through ``msg_adapters`` (streaming, bounded memory); messages are republished
with their recorded stamps, paced by the recorded time divided by ``rate``.

Parameters: ``bag`` (path; required), ``rate`` (speed factor, default 1.0), ``loop`` (start
again at the end: the stamps then jump backward, as with a looping ``ros2 bag play -l``),
``bag_imu_topic``/``bag_joint_topic`` (topics in the bag), ``wait_for_subscribers`` (number of
IMU subscribers to wait for before starting, up to ``wait_timeout_s``), ``clock_period_s``
(simulated time between ``/clock`` messages). Publishes ``imu/data_raw``, ``joint_states``
(relative names: remap with ``-r``) and ``/clock``. Exits 0 at the end of the bag.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState

from msg_adapters.bag import DEFAULT_IMU_TOPIC, DEFAULT_JOINT_TOPIC, iter_bag
from msg_adapters.convert import imu_msg_from_sample, joint_state_msg_from_sample, \
    time_msg_from_ns

from ..cli import absolute_topic
from ..core.errors import ImuCalibError
from ..core.types import ImuSample
from .common import (Endpoint, NodeInterface, declare_config, print_help_if_asked,
                     reliable_qos)


@dataclass(frozen=True)
class BagPlayerConfig:
    """Parameters of the ``bag_player`` node."""

    bag: str = field(default='', metadata={'doc': 'bag directory or .mcap file to play',
                                           'required': True})
    rate: float = field(default=1.0, metadata={'doc': 'speed factor (2.0 = twice real time)',
                                               'min': 0.01, 'max': 1000.0})
    loop: bool = field(default=False, metadata={'doc': 'play again from the start at the end'})
    bag_imu_topic: str = field(default=DEFAULT_IMU_TOPIC, metadata={
        'doc': 'IMU topic in the bag (a name without the leading slash means the same topic)'})
    bag_joint_topic: str = field(default=DEFAULT_JOINT_TOPIC, metadata={
        'doc': 'joint-state topic in the bag (a name without the leading slash means the '
               'same topic)'})
    wait_for_subscribers: int = field(default=0, metadata={
        'doc': 'IMU subscribers to wait for before playing', 'min': 0, 'max': 100})
    wait_timeout_s: float = field(default=10.0, metadata={
        'doc': 'longest wait for subscribers', 'min': 0.0, 'max': 3600.0})
    clock_period_s: float = field(default=0.01, metadata={
        'doc': 'simulated time between /clock messages', 'min': 0.0, 'max': 10.0})


class BagPlayer(Node):
    """Publishes a bag's IMU and joint states with their recorded stamps, and ``/clock``."""

    def __init__(self) -> None:
        super().__init__('bag_player')
        self.cfg: BagPlayerConfig = declare_config(self, BagPlayerConfig)
        qos = reliable_qos(depth=1000)
        self._imu_pub = self.create_publisher(Imu, 'imu/data_raw', qos)
        self._joint_pub = self.create_publisher(JointState, 'joint_states', qos)
        self._clock_pub = self.create_publisher(Clock, '/clock', reliable_qos(depth=10))
        self.published = 0

    def _wait_for_subscribers(self) -> None:
        deadline = time.monotonic() + self.cfg.wait_timeout_s
        while (self._imu_pub.get_subscription_count() < self.cfg.wait_for_subscribers
               and time.monotonic() < deadline):
            time.sleep(0.05)

    def _publish_clock(self, stamp_ns: int) -> None:
        msg = Clock()
        msg.clock = time_msg_from_ns(stamp_ns)
        self._clock_pub.publish(msg)

    def play_once(self) -> None:
        """Play the bag from start to end, paced by the recorded stamps / ``rate``."""
        t0_bag: int | None = None
        t0_wall = time.monotonic()
        last_clock: int | None = None
        period_ns = int(self.cfg.clock_period_s * 1e9)
        for sample in iter_bag(self.cfg.bag, absolute_topic(self.cfg.bag_imu_topic),
                               absolute_topic(self.cfg.bag_joint_topic)):
            if not rclpy.ok():
                return
            if t0_bag is None:
                t0_bag = sample.stamp_ns
            due = t0_wall + (sample.stamp_ns - t0_bag) * 1e-9 / self.cfg.rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            try:
                if last_clock is None or sample.stamp_ns - last_clock >= period_ns:
                    self._publish_clock(sample.stamp_ns)
                    last_clock = sample.stamp_ns
                if isinstance(sample, ImuSample):
                    self._imu_pub.publish(imu_msg_from_sample(sample))
                else:
                    self._joint_pub.publish(joint_state_msg_from_sample(sample))
            except Exception:  # noqa: BLE001 - a signal shut the context down mid-publish
                if not rclpy.ok():
                    return
                raise
            self.published += 1
        if last_clock is not None and t0_bag is not None and rclpy.ok():
            self._publish_clock(sample.stamp_ns)

    def play(self) -> None:
        """Wait for subscribers, then play once, or forever with ``loop``."""
        self._wait_for_subscribers()
        self.play_once()
        while self.cfg.loop and rclpy.ok():
            self.play_once()


INTERFACE = NodeInterface(
    name='bag_player', config=BagPlayerConfig,
    summary='Plays a ROS 2 bag\'s IMU and joint-state topics with their recorded stamps and '
            '/clock, paced at rate x the recorded time (the stand-in for ros2 bag play --clock '
            'where ros2cli is missing). Exits 0 at the end of the bag.',
    publishes=(
        Endpoint('imu/data_raw', 'sensor_msgs/msg/Imu', 'the bag\'s bag_imu_topic'),
        Endpoint('joint_states', 'sensor_msgs/msg/JointState', 'the bag\'s bag_joint_topic'),
        Endpoint('/clock', 'rosgraph_msgs/msg/Clock', 'the recorded time')))


def main(args: list[str] | None = None) -> int:
    """Console-script entry point (``bag_player --ros-args -p bag:=BAG -p rate:=2.0``)."""
    if print_help_if_asked(INTERFACE, args):
        return 0
    rclpy.init(args=args if args is not None else sys.argv)
    node: BagPlayer | None = None
    status = 0
    try:
        node = BagPlayer()
        node.play()
        time.sleep(0.2)  # let reliable writers hand over the last messages
    except (KeyboardInterrupt, ExternalShutdownException):
        pass  # stopped on request (SIGINT/SIGTERM), like the other nodes: status 0
    except ImuCalibError as exc:
        print(f'bag_player: error: {exc}', file=sys.stderr, flush=True)
        status = 2
    finally:
        if node is not None:
            if status == 0:  # after an error the error line says it all
                # print, not the logger: after a signal the context (and /rosout) is gone
                print(f'bag_player: published {node.published} messages', file=sys.stderr,
                      flush=True)
            node.destroy_node()
        rclpy.try_shutdown()
    return status


if __name__ == '__main__':
    sys.exit(main())
