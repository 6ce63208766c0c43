"""Plumbing of the topic-level tests (not a test module).

Nodes run in-process in the module's own rclpy Context (conftest's ``ros_context``),
spun by hand with deadlines (``Spinner``); the session's ROS_DOMAIN_ID and loopback
discovery come from conftest.
"""
from __future__ import annotations

import time

from rclpy.parameter import Parameter

from rcl_interfaces.msg import Log
from rosgraph_msgs.msg import Clock

from supersafe_ros.ros_io import rosmsg


def params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


class Spinner:
    """One executor over the nodes of a test; spins until a condition or a deadline."""

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
        while True:
            if condition():
                return
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out after {timeout} s waiting for {what}')
            self.executor.spin_once(timeout_sec=0.005)

    def spin_for(self, seconds):
        """Spin a fixed time: only for checking that something does NOT happen."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.005)

    def shutdown(self):
        self.executor.shutdown()


class FilterRigs:
    """The filters a test makes, each with its stack's node and a Spinner over both; ``close()``
    ends them all (spinners first, then each filter's close and both nodes)."""

    def __init__(self, ctx):
        self.ctx, self.made = ctx, []

    def add(self, f, stack_node) -> Spinner:
        spin = Spinner(self.ctx, f, stack_node)
        self.made.append((spin, f, stack_node))
        return spin

    def close(self):
        for spin, f, stack_node in self.made:
            spin.shutdown()
            f.close()
            f.destroy_node()
            stack_node.destroy_node()


def matched(*endpoints) -> bool:
    """Every publisher has a subscriber and every subscription a publisher."""
    for e in endpoints:
        n = e.get_subscription_count() if hasattr(e, 'get_subscription_count') else e.get_publisher_count()
        if n < 1:
            return False
    return True


class Rosout:
    """Collects /rosout so tests can check that a rejection was logged with its reason."""

    def __init__(self, node):
        self.logs = []
        self.sub = node.create_subscription(Log, '/rosout', self.logs.append, 100)

    def has(self, node_name: str, *words) -> bool:
        return any(node_name in m.name and all(w in m.msg for w in words) for m in self.logs)


class ClockDriver:
    """Plays sim_clock_node for tests: publishes /clock steps and reads step_done acks."""

    def __init__(self, node, robots=('robot_0',)):
        self.pub = node.create_publisher(Clock, '/clock', rosmsg.QOS_CLOCK)
        self.acks = {r: -1 for r in robots}
        self.subs = [node.create_subscription(Clock, f'/{r}/step_done',
                                              lambda m, r=r: self._ack(r, m), rosmsg.QOS_ACK)
                     for r in robots]
        self.now_ns = 0

    def _ack(self, robot, msg):
        self.acks[robot] = max(self.acks[robot], msg.clock.sec * 1_000_000_000 + msg.clock.nanosec)

    def publish(self, t_ns):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        self.now_ns = int(t_ns)
        self.pub.publish(msg)

    def step(self, spinner, dt=0.05, timeout=5.0):
        """Advance by dt and wait until every robot acknowledged the new time."""
        self.publish(self.now_ns + int(round(dt * 1e9)))
        spinner.until(lambda: all(a >= self.now_ns for a in self.acks.values()), timeout,
                      f'step_done for t={self.now_ns * 1e-9:.3f}')


def set_parameters(spinner, client_node, node_name, timeout=15.0, **values):
    """What `ros2 param set` does: the node's SetParameters service, from another node.
    Returns the rcl_interfaces SetParametersResult of each value, in order."""
    from rcl_interfaces.srv import SetParameters
    client = client_node.create_client(SetParameters, f'{node_name}/set_parameters')
    try:
        spinner.until(client.service_is_ready, timeout, f'{node_name}/set_parameters')
        request = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg()
                                                    for k, v in values.items()])
        future = client.call_async(request)
        spinner.until(future.done, timeout, f'{node_name} to answer set_parameters')
        return future.result().results
    finally:
        client_node.destroy_client(client)


def live_and_read_only(node, live_names):
    """Parameters a node declares that are neither live nor read-only (should be none):
    a set of one of those would answer "successful" and change nothing."""
    silent = []
    for name in node._parameters:
        if name in ('use_sim_time', 'start_type_description_service'):
            continue                                     # rclpy's own, live
        if name not in live_names and not node.describe_parameter(name).read_only:
            silent.append(name)
    return silent
