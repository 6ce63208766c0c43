"""Shared plumbing of the filter and learner topic-level tests (not a test module).

Every test session gets its own ROS_DOMAIN_ID (set in os.environ before any
rclpy.init) and loopback-only discovery; each test module runs its nodes in its
own rclpy Context, spun by hand with deadlines (never sleep-and-hope).
"""
from __future__ import annotations

import os
import time

import pytest

from supersafe_ros.rosenv import ensure_local_ros_env


def session_domain_id() -> int:
    """A domain for this pytest process: $SUPERSAFE_TEST_DOMAIN or one derived from the pid."""
    return int(os.environ.get('SUPERSAFE_TEST_DOMAIN', 130 + os.getpid() % 100))


@pytest.fixture(scope='module')
def ros_context(tmp_path_factory):
    ensure_local_ros_env()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_DOMAIN_ID'] = str(session_domain_id())
    # value-function cache shared by this session's tests (coarse grids solve in ~0.2 s)
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
