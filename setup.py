"""ament_python package definition (builds with colcon, installs with pip)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'imu_calib_ros'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config/fixtures', glob('config/fixtures/*.yaml')),
        ('share/' + PACKAGE + '/config/plans', glob('config/plans/*.yaml')),
        ('share/' + PACKAGE + '/config/imus', glob('config/imus/*.yaml')),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.py')),
    ],
    include_package_data=True,
    install_requires=['setuptools'],
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
