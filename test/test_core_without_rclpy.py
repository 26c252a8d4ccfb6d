"""The core never imports rclpy (or any ROS message package): prove it in a clean interpreter."""
import pkgutil
import subprocess
import sys
from pathlib import Path

import imu_calib_ros.core as core

BLOCKER = r'''
import importlib, importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        root = name.split('.')[0]
        if root in ('rclpy', 'sensor_msgs', 'geometry_msgs', 'std_msgs', 'std_srvs',
                    'diagnostic_msgs', 'trajectory_msgs', 'rosgraph_msgs', 'builtin_interfaces'):
            raise ImportError('blocked ROS import: ' + name)
        return None
sys.meta_path.insert(0, Block())
for m in sys.argv[1:]:
    importlib.import_module(m)
print('imported', len(sys.argv) - 1)
'''


def core_modules() -> list[str]:
    root = Path(core.__file__).parent
    names = ['imu_calib_ros.core']
    for info in pkgutil.walk_packages([str(root)], prefix='imu_calib_ros.core.'):
        names.append(info.name)
    return names


def test_core_imports_with_ros_blocked() -> None:
    mods = core_modules()
    assert len(mods) >= 4
    out = subprocess.run([sys.executable, '-c', BLOCKER, *mods], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert f'imported {len(mods)}' in out.stdout
