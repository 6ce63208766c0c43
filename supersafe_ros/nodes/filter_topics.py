"""A robot's own outputs on the filter node (its Sink; the inputs are ``filter_sources``).

Every endpoint of a robot's own topics lives on the node's helper node ``<name>_io`` (same
namespace, no parameter services, never in the node's executor): a fleet's thousands of
publishers and subscriptions would otherwise be in every executor wake-up's wait set. Names are
resolved by the node itself first, so its remaps apply (``-r pose:=odom``).

* ``robot_topic(node, ns, name)``: a robot's topic, as the node resolves it: ``name`` relative
  to the node when the robot is in the node's own namespace, else under the robot's namespace;
* ``RobotTopics(node, io, ns, stamped)``: a robot's ``cmd_vel`` (through its ``CommandSink``),
  ``safety_filter/state``, ``safety_filter/level_set`` (with ``level_set_markers``) and the
  latched ``safety_filter/ready``, made once the robot's filter can judge (``say_ready``);
The batched topics, every robot at once: ``filter_batched``.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus
from std_msgs.msg import Empty
from visualization_msgs.msg import MarkerArray

from ..ros_io import cdr, rosmsg
from .filter_sources import CommandSink


def robot_topic(node, ns: str, name: str) -> str:
    """Robot ``ns``'s topic ``name`` as ``node`` resolves it (its remaps applied)."""
    return node.resolve_topic_name(name if ns == node.get_namespace() else f'{ns.rstrip("/")}/{name}')


class RobotTopics:
    """A robot's own outputs (see the module); ``sink`` keeps the planner's last header for its cmd_vel."""

    __slots__ = ('ns', 'io', 'sink', 'cmd_pub', 'state_pub', 'level_set_pub', 'ready', 'ready_topic')

    def __init__(self, node, io, ns, stamped, level_set=False):
        self.ns, self.io = ns, io
        self.sink = CommandSink(stamped)
        self.cmd_pub = io.create_publisher(self.sink.msg_type, robot_topic(node, ns, 'cmd_vel'), rosmsg.QOS_STREAM)
        self.state_pub = io.create_publisher(DiagnosticStatus, robot_topic(node, ns, 'safety_filter/state'),
                                             rosmsg.QOS_STREAM)
        self.level_set_pub = (io.create_publisher(MarkerArray, robot_topic(node, ns, 'safety_filter/level_set'),
                                                  rosmsg.QOS_STREAM) if level_set else None)
        self.ready, self.ready_topic = None, robot_topic(node, ns, 'safety_filter/ready')

    def send(self, f, t, action, linear, omega, clock_ns) -> None:
        """Robot filter ``f``'s decision at ``t`` on cmd_vel (``CommandSink.cmd_vel``)."""
        self.cmd_pub.publish(self.sink.cmd_vel(f, t, action, linear, omega, clock_ns))

    def send_zero(self, clock_ns) -> None:
        self.cmd_pub.publish(self.sink.bytes(0.0, 0.0, False, clock_ns))

    def say_state(self, state) -> None:
        self.state_pub.publish(cdr.diagnostic_status_bytes(state))

    def say_ready(self) -> None:
        """The latched ``safety_filter/ready``: made and sent once (a lockstep clock starts when every
        robot's filter has one)."""
        if self.ready is None:
            self.ready = self.io.create_publisher(Empty, self.ready_topic, rosmsg.QOS_LATCHED)
            self.ready.publish(Empty())
