"""Shared plumbing of the filter and learner topic-level tests (not a test module).

The same plumbing as the sim-graph tests: each module runs its nodes in its own
rclpy Context (``ros_context``), spun by hand with deadlines (``Spinner``), after
the session's ROS_DOMAIN_ID and loopback-only discovery were set by conftest.
"""
from test_graph_support import Spinner, matched, ros_context  # noqa: F401

__all__ = ['Spinner', 'matched', 'ros_context']
