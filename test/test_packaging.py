"""It stays a real ament_python package: package.xml format 3, resource marker, data files,
script dirs for `ros2 run`, launch files that at least compile, console scripts installed."""
from __future__ import annotations

import configparser
import shutil
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NODES = ('calibration', 'compensator', 'turntable_sim', 'turntable_driver', 'bag_player',
         'modulation')


def test_package_xml_is_format_3_ament_python_with_runtime_deps() -> None:
    root = ET.parse(ROOT / 'package.xml').getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    assert root.findtext('name') == 'imu_calib_ros'
    assert root.find('export/build_type').text == 'ament_python'
    deps = {e.text for e in root.findall('exec_depend')}
    assert {'rclpy', 'sensor_msgs', 'geometry_msgs', 'std_msgs', 'std_srvs', 'diagnostic_msgs',
            'trajectory_msgs', 'python3-numpy', 'python3-scipy'} <= deps


def test_resource_marker_script_dirs_and_entry_points() -> None:
    assert (ROOT / 'resource' / 'imu_calib_ros').is_file()
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / 'setup.cfg')
    assert cfg['develop']['script_dir'] == '$base/lib/imu_calib_ros'
    assert cfg['install']['install_scripts'] == '$base/lib/imu_calib_ros'
    setup = (ROOT / 'setup.py').read_text()
    assert "'share/ament_index/resource_index/packages'" in setup
    for name in ('imu-calib', *NODES):
        assert f"'{name} = imu_calib_ros." in setup, name
        # installed into the venv this suite runs in (pip -e .)
        assert shutil.which(name, path=str(Path(sys.executable).parent)), name


def test_launch_files_compile() -> None:
    files = sorted((ROOT / 'launch').glob('*.launch.py'))
    assert len(files) >= 2
    for f in files:
        compile(f.read_text(), str(f), 'exec')  # syntax only: no launch wheels here
        assert 'generate_launch_description' in f.read_text()


def test_both_top_level_packages_are_packaged() -> None:
    """msg_adapters sits beside imu_calib_ros (issue 14 item 7): setup.py ships both."""
    setup = (ROOT / 'setup.py').read_text()
    assert "'msg_adapters'" in setup and "'imu_calib_ros'" in setup
    import msg_adapters
    assert Path(msg_adapters.__file__).resolve().parent == ROOT / 'msg_adapters'
