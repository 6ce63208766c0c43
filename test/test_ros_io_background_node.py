"""BackgroundNode.close: the teardown (executor shutdown, node destruction) finishes, or, blocked,
is left to its daemon thread with a WARNING while the caller goes on (a session's main thread was
seen stuck for good in rclpy's destroy_when_not_in_use under load)."""
import logging
import os
import threading

import pytest

pytestmark = pytest.mark.ros


def make(name):
    from supersafe_ros.ros_io.background_node import BackgroundNode
    ros = BackgroundNode(name, int(os.environ['ROS_DOMAIN_ID']))
    ros.start()
    return ros


def test_close_destroys_the_node():
    ros = make('background_close')
    destroyed = []
    destroy = ros.node.destroy_node
    ros.node.destroy_node = lambda: (destroyed.append(True), destroy())[1]
    assert ros.close(teardown_timeout=None) is True
    assert destroyed == [True]


def test_a_blocked_teardown_does_not_hold_the_caller(caplog):
    ros = make('background_blocked')
    release = threading.Event()
    destroy = ros.node.destroy_node
    ros.node.destroy_node = lambda: (release.wait(), destroy())[1]
    with caplog.at_level(logging.WARNING, logger='supersafe_ros.ros_io.background_node'):
        assert ros.close(teardown_timeout=0.2) is False
    assert any('background_blocked' in r.getMessage() and 'daemon thread' in r.getMessage()
               for r in caplog.records)
    release.set()           # the daemon thread finishes the destruction
