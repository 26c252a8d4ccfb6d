"""imu_calib_ros: turntable calibration of inertial measurement units for ROS 2.

Layout (functional core, thin shell):

- ``imu_calib_ros.core``: earth model, fixture kinematics, sensor model, strapdown,
  estimator, methods, simulator. Pure numpy/scipy; never imports rclpy.
- ``imu_calib_ros.msg_adapters``: the only code that knows ROS message classes
  (rclpy and rosbags), mapping them onto ``core.types`` samples; bag I/O.
- ``imu_calib_ros.nodes``: rclpy nodes (thin shells over the core).
- ``imu_calib_ros.cli``: the ``imu-calib`` command.
"""

__version__ = '0.1.0'
