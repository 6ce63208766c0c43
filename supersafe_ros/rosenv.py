"""Keep DDS on this machine: every entry point calls this before rclpy.init().

DDS multicasts discovery on every interface by default; supersafe_ros processes
restrict it to loopback unless the user already chose LOCALHOST or OFF. The one
exception is a process that `supersafe team --hosts` placed in one of its private
network namespaces ($SUPERSAFE_NETNS names it, and the process really is in it):
there SUBNET reaches only the other test hosts, so it is kept.
"""
from __future__ import annotations

import os

LOCAL_RANGES = ('LOCALHOST', 'OFF')
NETNS_VAR = 'SUPERSAFE_NETNS'


def in_private_netns(env=None) -> bool:
    """True if $SUPERSAFE_NETNS names a namespace of supersafe's and this thread is in it."""
    from .hosts.netns import PREFIX, current_namespace_is
    name = (os.environ if env is None else env).get(NETNS_VAR, '')
    return name.startswith(f'{PREFIX}-') and current_namespace_is(name)


def ensure_local_ros_env(environ=None) -> dict:
    """Force loopback-only discovery and name the rmw; returns the environment used."""
    env = os.environ if environ is None else environ
    allowed = LOCAL_RANGES + (('SUBNET',) if in_private_netns(env) else ())
    if env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').upper() not in allowed:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    return env
