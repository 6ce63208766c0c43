"""Keep DDS on this machine: every entry point calls this before rclpy.init().

DDS multicasts discovery on every interface by default; supersafe_ros processes
restrict it to loopback unless the user already chose LOCALHOST or OFF.
"""
from __future__ import annotations

import os

LOCAL_RANGES = ('LOCALHOST', 'OFF')


def ensure_local_ros_env(environ=None) -> dict:
    """Force loopback-only discovery and name the rmw; returns the environment used."""
    env = os.environ if environ is None else environ
    if env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').upper() not in LOCAL_RANGES:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    return env
