"""Shared plumbing of the filter and learner topic-level tests (not a test module).

The session's ROS_DOMAIN_ID and loopback-only discovery come from test/conftest.py
(set before any rclpy.init); ``ros_context`` re-asserts them in case these modules
run without it. Each test module runs its nodes in its own rclpy Context, spun by
hand with deadlines (never sleep-and-hope).
"""
from __future__ import annotations

import os
import time

import pytest

from supersafe_ros.rosenv import ensure_local_ros_env


def ensure_session_domain() -> int:
    """The session's domain: conftest's, else one derived from the pid (set once)."""
    if 'SUPERSAFE_TEST_DOMAIN_SET' not in os.environ:
        os.environ['ROS_DOMAIN_ID'] = str(110 + os.getpid() % 90)
        os.environ['SUPERSAFE_TEST_DOMAIN_SET'] = '1'
    return int(os.environ['ROS_DOMAIN_ID'])


@pytest.fixture(scope='module')
def ros_context(tmp_path_factory):
    ensure_local_ros_env()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    ensure_session_domain()
    # value-function cache shared by the tests (conftest sets one; coarse grids solve in ~0.2 s)
    os.environ.setdefault('SUPERSAFE_CACHE', str(tmp_path_factory.getbasetemp() / 'vf-cache'))
    import rclpy
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    ctx.try_shutdown()


class Spinner:
    """Spins a set of nodes in one executor until a condition holds or a deadline passes."""

    def __init__(self, ctx, *nodes):
        from rclpy.executors import SingleThreadedExecutor
        self.executor = SingleThreadedExecutor(context=ctx)
        for n in nodes:
            self.executor.add_node(n)

    def add(self, node):
        self.executor.add_node(node)

    def remove(self, node):
        self.executor.remove_node(node)

    def until(self, condition, timeout=5.0, what='condition'):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return
            self.executor.spin_once(timeout_sec=0.01)
        if condition():
            return
        raise AssertionError(f'timed out after {timeout} s waiting for {what}')

    def spin_for(self, seconds):
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)

    def shutdown(self):
        self.executor.shutdown()


def matched(*endpoints):
    """True when every publisher has a subscriber and every subscription a publisher."""
    for e in endpoints:
        count = e.get_subscription_count() if hasattr(e, 'get_subscription_count') else e.get_publisher_count()
        if count < 1:
            return False
    return True
