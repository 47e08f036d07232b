"""laser_tracker: an ament_python package that also installs with plain pip.

The ROS 2 client libraries are *not* hard requirements: on a robot they come from apt
(ROS 2 Jazzy), elsewhere from PyPI wheels through the ``wheels`` extra (see the Makefile).
"""
import os
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'laser_tracker'


def bag_data_files():
    """The bundled recordings (rosbag2 folders) go to share/laser_tracker/bags/<name>/."""
    entries = []
    for folder in sorted(glob('bags/*/')):
        files = [f for f in glob(folder + '*') if os.path.isfile(f)]
        if files:
            entries.append(('share/' + PACKAGE + '/' + folder.rstrip('/'), files))
    return entries

NODES = {
    'sick_lms_driver': 'laser_tracker.nodes.sick_lms_driver:main',
    'ego_motion': 'laser_tracker.nodes.ego_motion:main',
    'detection': 'laser_tracker.nodes.detection:main',
    'tracking': 'laser_tracker.nodes.tracking:main',
    'active_head': 'laser_tracker.nodes.active_head:main',
    'laser_tracker_all': 'laser_tracker.nodes.composed:main',
}

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
    ] + bag_data_files(),
    python_requires='>=3.10',
    install_requires=[
        'setuptools',
        'numpy',
        'scipy',
        'pyserial',
        'rosbags',
        'pyyaml',
        'tqdm',
        'matplotlib',
    ],
    extras_require={
        # ROS 2 Jazzy from PyPI wheels, for machines without an apt ROS install.
        'wheels': ['ros-jazzy-rclpy[fastrtps]', 'ros-jazzy-common-interfaces'],
        # CLEAR MOT evaluation.
        'eval': ['motmetrics'],
        # Comparison baseline for the ego-motion benchmark.
        'bench': ['kiss-icp'],
        'test': ['pytest', 'pytest-timeout', 'colcon-core', 'ros-jazzy-ament-package'],
    },
    zip_safe=True,
    maintainer='laser_tracker maintainers',
    maintainer_email='maintainers@laser-tracker.invalid',
    description='Detect and track moving objects with a 2D laser scanner from a mobile robot.',
    license='BSD-3-Clause',
    entry_points={
        'console_scripts': [f'{name} = {target}' for name, target in NODES.items()]
        + ['laser-tracker = laser_tracker.cli:main'],
    },
)
