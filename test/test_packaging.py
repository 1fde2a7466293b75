"""ament_python packaging: what `colcon build` installs to share, and the package manifest."""
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]


def test_install_puts_config_launch_and_rviz_into_share(tmp_path):
    # the steps colcon runs for an ament_python package, on a copy of the sources
    source = _mkdir(tmp_path / 'src')
    for name in ('setup.py', 'setup.cfg', 'package.xml'):
        shutil.copy(REPO / name, source / name)
    for name in ('resource', 'config', 'launch', 'rviz', 'map_consistency_ros'):
        shutil.copytree(REPO / name, source / name,
                        ignore=shutil.ignore_patterns('__pycache__', '*.pyc'))
    build = _mkdir(tmp_path / 'build')
    done = subprocess.run(
        [sys.executable, 'setup.py', '-q', 'egg_info', '--egg-base', str(build), 'build',
         '--build-base', str(build), 'install', '--root', str(tmp_path / 'root'), '--prefix',
         '/ws', '--single-version-externally-managed', '--record', str(tmp_path / 'record')],
        cwd=source, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    share = tmp_path / 'root' / 'ws' / 'share' / 'map_consistency_ros'
    for relative in ('package.xml', 'config/map_consistency.yaml', 'rviz/map_consistency.rviz',
                     'launch/map_consistency.launch.py',
                     'launch/slam_toolbox_consistency.launch.py'):
        assert (share / relative).is_file(), relative
    assert (tmp_path / 'root' / 'ws' / 'share' / 'ament_index' / 'resource_index' / 'packages'
            / 'map_consistency_ros').is_file()


def _mkdir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


def test_launch_files_compile_and_rviz_config_parses():
    for launch in (REPO / 'launch').glob('*.launch.py'):
        compile(launch.read_text(), str(launch), 'exec')  # launch_ros is not in the pip set
        assert 'def generate_launch_description' in launch.read_text()
    rviz = yaml.safe_load((REPO / 'rviz' / 'map_consistency.rviz').read_text())
    topics = {display.get('Topic', {}).get('Value')
              for display in rviz['Visualization Manager']['Displays']}
    assert {'/map_consistency/markers', '/map_consistency/optimized_trajectory'} <= topics


def test_manifest_uses_rosdep_keys_not_pip_placeholders():
    manifest = ElementTree.parse(REPO / 'package.xml').getroot()
    keys = [element.text for element in manifest if element.tag.endswith('depend')]
    assert 'python3-numba' in keys and not any(key.endswith('-pip') for key in keys)
    assert manifest.find('version').text == _setup_version()


def _setup_version() -> str:
    text = (REPO / 'setup.py').read_text()
    return text.split("version='")[1].split("'")[0]
