"""imu_calib_ros: turntable calibration of inertial measurement units for ROS 2.

Layout (functional core, thin shell):

- ``imu_calib_ros.core``: earth model, fixture kinematics, sensor model, strapdown,
  estimator, methods, simulator. Pure numpy/scipy; never imports rclpy.
- ``msg_adapters`` (a top-level package beside this one): the only code that knows ROS
  message classes (rclpy and rosbags), mapping them onto ``core.types`` samples; bag I/O.
- ``imu_calib_ros.nodes``: rclpy nodes (thin shells over the core).
- ``imu_calib_ros.cli``: the ``imu-calib`` command.
"""


def __getattr__(name: str) -> str:
    """``__version__``, read when asked. The version is written once, in package.xml:
    read from it in a source tree (also an editable install), else from the installed
    package's metadata (which setup.py took from package.xml)."""
    if name != '__version__':
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    import re
    from pathlib import Path
    xml = Path(__file__).resolve().parents[1] / 'package.xml'
    if xml.is_file():
        found = re.search(r'<version>\s*([^<\s]+)\s*</version>', xml.read_text())
        if found:
            return found.group(1)
    from importlib import metadata
    return metadata.version(__name__)
