"""/diagnostics of a filter node (diagnostic_msgs/DiagnosticArray, for the diagnostic aggregator)
and a watch over who publishes what on its input topics.

``FilterDiagnostics(node, statuses, inputs)`` publishes every ``period`` steady seconds (1 Hz)
one DiagnosticStatus per robot: ``statuses()`` gives them (the robot's last state message: OK
pass, WARN override, ERROR fail safe, the reason saying which input is stale or refused),
named ``<node>: <robot>``. Before the same publish it looks at the graph: a publisher on an
input topic whose type is not the one the filter reads (a TwistStamped planner on
``cmd_vel_nav`` while Twist is expected) is logged as a WARN naming both types, and every
status of the node says so (at least WARN) while that publisher stays.
"""
from __future__ import annotations

from rclpy.clock import Clock, ClockType

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from ..ros_io import rosmsg

DIAGNOSTICS_TOPIC = '/diagnostics'
WARN = DiagnosticStatus.WARN[0]


def type_name(msg_type) -> str:
    """'geometry_msgs/msg/Twist' for the class geometry_msgs.msg.Twist (the graph's spelling)."""
    module = msg_type.__module__.split('.')
    return f'{module[0]}/msg/{msg_type.__name__}'


def foreign_publishers(node, topic: str, expected: str) -> list:
    """Types of the publishers on ``topic`` (as ``node`` resolves it) other than ``expected``."""
    infos = node.get_publishers_info_by_topic(node.resolve_topic_name(topic))
    return sorted({i.topic_type for i in infos} - {expected})


class FilterDiagnostics:
    """See the module. ``inputs``: [(topic, message class)] the node subscribes."""

    def __init__(self, node, statuses, inputs, complain, period: float = 1.0):
        self.node = node
        self.statuses = statuses
        self.inputs = [(topic, type_name(t)) for topic, t in inputs]
        self.complain = complain
        self.notes = []            # the input topics' foreign publishers, said in every status
        self.published = 0
        self.pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, rosmsg.QOS_STREAM)
        self.timer = node.create_timer(period, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def check_graph(self) -> list:
        notes = []
        for topic, expected in self.inputs:
            others = foreign_publishers(self.node, topic, expected)
            if others:
                notes.append(f'{topic} has a publisher of {", ".join(others)}; this filter reads {expected} '
                             'there (its messages are not received: the input looks silent)')
        for note in notes:
            self.complain(f'type {note}', note, level='warn')
        self.notes = notes
        return notes

    def publish(self):
        notes = self.check_graph()
        out = DiagnosticArray()
        out.header.stamp = self.node.get_clock().now().to_msg()
        for status in self.statuses():
            if notes:
                status.level = bytes([max(status.level[0], WARN)])
                status.message = '; '.join([status.message, *notes]) if status.message else '; '.join(notes)
            out.status.append(status)
        self.pub.publish(out)
        self.published += 1
