"""``python -m imu_calib_ros`` is ``imu-calib``."""
import sys

from .cli import main

sys.exit(main())
