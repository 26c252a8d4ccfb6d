"""The only code that knows ROS message classes (rclpy's and rosbags').

``convert`` maps ``sensor_msgs/Imu`` and ``sensor_msgs/JointState`` onto the core sample
types and back; ``cdr`` holds their CDR byte layouts (one message and many); ``bag`` reads
and writes ROS 2 bags with rosbags, ``bag_raw`` brings it a bag's raw messages (indexed mcap
chunk by chunk). None imports rclpy at module import time.
"""

#: Longest wait, in log (receipt) time, for a message to be put back in header-stamp order
#: when a bag is read (rosbag2 logs receipt time; issue 17). Here, not in ``bag``, so that the
#: CLI can show it in ``--help`` without importing numpy.
DEFAULT_REORDER_WINDOW_S = 0.5
