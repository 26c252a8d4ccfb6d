"""ament_python package definition (builds with colcon, installs with pip)."""
import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = 'imu_calib_ros'
# The version is written once, in package.xml (what colcon and rosdep read); `imu-calib
# --version` and imu_calib_ros.__version__ read it back from the installed metadata.
VERSION = re.search(r'<version>\s*([^<\s]+)\s*</version>',
                    (Path(__file__).resolve().parent / 'package.xml').read_text()).group(1)

setup(
    name=PACKAGE,
    version=VERSION,
    # Two top-level packages: imu_calib_ros (core, nodes, cli) and msg_adapters (the only code
    # that knows ROS message classes; it imports imu_calib_ros.core, never the reverse).
    packages=find_packages(include=['imu_calib_ros', 'imu_calib_ros.*',
                                    'msg_adapters', 'msg_adapters.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config/fixtures', glob('config/fixtures/*.yaml')),
        ('share/' + PACKAGE + '/config/plans', glob('config/plans/*.yaml')),
        ('share/' + PACKAGE + '/config/imus', glob('config/imus/*.yaml')),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.py')),
        ('share/' + PACKAGE + '/docs', ['docs/CONTRACT.md']),
    ],
    include_package_data=True,
    install_requires=['setuptools', 'yourdfpy==0.0.60', 'distributed==2026.8.0'],
    zip_safe=True,
    maintainer='imu_calib_ros developers',
    maintainer_email='dev@imu-calib-ros.invalid',
    description='Turntable IMU calibration: strapdown + augmented-state EKF, simulator, ROS 2 nodes',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'imu-calib = imu_calib_ros.cli:main',
            'calibration = imu_calib_ros.nodes.calibration:main',
            'compensator = imu_calib_ros.nodes.compensator:main',
            'turntable_sim = imu_calib_ros.nodes.turntable_sim:main',
            'turntable_driver = imu_calib_ros.nodes.turntable_driver:main',
            'bag_player = imu_calib_ros.nodes.bag_player:main',
            'modulation = imu_calib_ros.nodes.modulation:main',
        ],
    },
)
