"""The only code that knows ROS message classes (rclpy's and rosbags').

``convert`` maps ``sensor_msgs/Imu`` and ``sensor_msgs/JointState`` onto the core sample
types and back; ``bag`` reads and writes ROS 2 bags with rosbags. Neither imports rclpy at
module import time.
"""
