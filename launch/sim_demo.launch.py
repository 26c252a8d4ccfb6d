"""Simulated turntable + calibration node (normal ROS 2 install only; here use `make demo`)."""
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        Node(package='imu_calib_ros', executable='turntable_sim', name='turntable_sim',
             parameters=[{'fixture': 'three_axis', 'plan': 'demo_short', 'speed': 4.0,
                          'wait_for_subscribers': 1}]),
        Node(package='imu_calib_ros', executable='calibration', name='calibration',
             parameters=[{'use_sim_time': True, 'fixture': 'three_axis'}]),
    ])
