"""``python -m imu_calib_ros.cli`` is ``imu-calib``."""
import sys

from . import main

sys.exit(main())
