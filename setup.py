"""ament_python package definition; also installs with plain pip into a venv."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'map_consistency_ros'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench']),
    package_data={PACKAGE: ['data/*', 'io/msg/slam_toolbox/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.yaml')),
        (f'share/{PACKAGE}/launch', glob('launch/*.launch.py')),
        (f'share/{PACKAGE}/rviz', glob('rviz/*.rviz')),
    ],
    python_requires='>=3.10',
    install_requires=[
        'numpy>=1.26',
        'scipy>=1.11',
        'numba>=0.59',
        'rosbags>=0.11',
        'matplotlib>=3.8',
    ],
    extras_require={
        'ros': [
            'ros-jazzy-rclpy',
            'ros-jazzy-common-interfaces',
            'ros-jazzy-rmw-fastrtps-cpp',
        ],
        # `batch --scheduler`: the inputs judged on a Dask cluster (imported on that path only)
        'distributed': ['dask[distributed]>=2024.1'],
        # the test of `batch --scheduler` starts a Dask LocalCluster: CI runs it
        'test': ['pytest>=8', 'shapely>=2.0', 'gtsam==4.3.0', 'pyyaml',
                 'dask[distributed]>=2024.1'],
    },
    zip_safe=True,
    maintainer='map_consistency_ros maintainers',
    maintainer_email='maintainers@map-consistency-ros.invalid',
    description='Statistical map-consistency test and DCS tuning for 2D-laser SLAM.',
    license='BSD-3-Clause',
    entry_points={
        'console_scripts': [
            'map-consistency = map_consistency_ros.cli.main:main',
            'map_consistency_node = map_consistency_ros.ros.node:main',
        ],
    },
)
