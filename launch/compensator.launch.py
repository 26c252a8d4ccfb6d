"""Robot-side compensator (normal ROS 2 install only: `launch` is not in .venv)."""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument('calibration_file'),
        Node(package='imu_calib_ros', executable='compensator', name='compensator',
             parameters=[{'calibration_file': LaunchConfiguration('calibration_file')}]),
    ])
