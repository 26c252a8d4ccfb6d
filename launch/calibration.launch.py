"""Live calibration next to a turntable (normal ROS 2 install only: `launch` is not in .venv).

Not runnable in this repository's venv (no launch/launch_ros wheels); kept trivial on purpose.
ros2 launch imu_calib_ros calibration.launch.py fixture:=/path/table.yaml
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    params = PathJoinSubstitution([FindPackageShare('imu_calib_ros'), 'config',
                                   'calibration_node.yaml'])
    return LaunchDescription([
        # no default: the node refuses to start without the fixture of the table in use
        DeclareLaunchArgument('fixture', description='fixture file (CONTRACT 2) of the table, '
                              'or a shipped name such as three_axis'),
        DeclareLaunchArgument('use_sim_time', default_value='false'),
        Node(package='imu_calib_ros', executable='calibration', name='calibration',
             parameters=[params, {'fixture': LaunchConfiguration('fixture'),
                                  'use_sim_time': LaunchConfiguration('use_sim_time')}]),
    ])
