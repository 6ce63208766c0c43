"""ament_python package definition for supersafe_ros."""
from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'supersafe_ros'

# One console script per node (ros2 run supersafe_ros <name>), plus the `supersafe` tool.
NODES = [
    'dubins_robot_node',
    'world_node',
    'planner_node',
    'safety_filter_node',
    'fleet_safety_filter_node',
    'learner_node',
    'supervisor_node',
    'sim_clock_node',
    'rviz_intervention_node',
    'supervisor_console_node',
]

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'bench']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        (os.path.join('share', package_name, 'config'), glob('config/*.yaml')),
        (os.path.join('share', package_name, 'launch'), glob('launch/*.launch.py')),
        # the console's page, scripts and styles (no build step, nothing from a CDN)
        (os.path.join('share', package_name, 'console', 'static'),
         glob('supersafe_ros/console/static/*')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'matplotlib', 'pyyaml', 'aiohttp'],
    # colcon test runs pytest (not unittest, which finds 0 tests here) when setup.py names pytest
    # as a test dependency; setup.cfg's testpaths points it at test/ (README, "In a ROS 2 Jazzy install")
    extras_require={'test': ['pytest']},
    # the calibrated paper-like population (supersafe study --population paper)
    package_data={'supersafe_ros.console': ['static/*'], 'supersafe_ros.study': ['data/*.json']},
    zip_safe=True,
    maintainer='supersafe_ros developers',
    maintainer_email='supersafe@example.org',
    description='Supervisor safe sets for robot teams (HJI reachability, learning, safety filter).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'supersafe = supersafe_ros.cli:main',
            # the safety filter as a managed (lifecycle) node, for Nav2's lifecycle_manager
            'managed_safety_filter = supersafe_ros.nodes.safety_filter_node:main_managed',
            'managed_fleet_safety_filter = supersafe_ros.nodes.fleet_safety_filter_node:main_managed',
        ] + [f'{name} = supersafe_ros.nodes.{name}:main' for name in NODES],
    },
)
