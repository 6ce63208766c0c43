"""/diagnostics of a filter node (diagnostic_msgs/DiagnosticArray, for the diagnostic aggregator)
and a watch over who publishes what on its input topics.

``FilterDiagnostics(node, statuses, inputs)`` publishes every ``period`` steady seconds (1 Hz)
one DiagnosticStatus per robot: ``statuses()`` gives them (the robot's last state message: OK
pass, WARN override, ERROR fail safe, the reason saying which input is stale or refused),
named ``<node>: <robot>``. Before the same publish it looks at the graph: a publisher on an
input topic whose type is not the one the filter reads (a TwistStamped planner on
``cmd_vel_nav`` while Twist is expected), or more than one publisher of it (a second driver
beside the real one, a replay, a spoof), is logged as a WARN naming the types or the nodes,
and every status of the node says so (at least WARN) while it stays.

A node that publishes /diagnostics itself (``publishes_diagnostics`` true: a managed filter,
nodes/managed.py, whose publisher and timer are there in every lifecycle state) gets neither
from here: it publishes ``array()`` while active.
"""
from __future__ import annotations

from rclpy.clock import Clock, ClockType

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from ..ros_io import cdr, rosmsg
from .filter_state import Status

DIAGNOSTICS_TOPIC = '/diagnostics'
WARN = DiagnosticStatus.WARN[0]


def type_name(msg_type) -> str:
    """'geometry_msgs/msg/Twist' for the class geometry_msgs.msg.Twist (the graph's spelling)."""
    module = msg_type.__module__.split('.')
    return f'{module[0]}/msg/{msg_type.__name__}'


def foreign_publishers(node, topic: str, expected: str) -> list:
    """Types of the publishers on ``topic`` (as ``node`` resolves it) other than ``expected``."""
    return publishers_of(node, topic, expected)[0]


def publishers_of(node, topic: str, expected: str):
    """(the types of the publishers on ``topic`` other than ``expected``, the fully qualified names
    of the nodes publishing ``expected`` there, one per publisher, sorted)."""
    infos = node.get_publishers_info_by_topic(node.resolve_topic_name(topic))
    names = sorted(_qualified(i.node_namespace, i.node_name) for i in infos if i.topic_type == expected)
    return sorted({i.topic_type for i in infos} - {expected}), names


def _qualified(namespace: str, name: str) -> str:
    return f'{namespace.rstrip("/")}/{name}' if namespace else f'/{name}'


def status_copy(state: Status, name: str, hardware_id: str, message: str | None = None) -> Status:
    """A robot's /diagnostics status from its state message: the state's level and values (shared,
    not copied: a state is never changed once made), named for the aggregator."""
    return Status(state.level, name, state.message if message is None else message, hardware_id, state.values,
                  state.encoded)


def array_bytes(node, statuses) -> bytes:
    """A serialized DiagnosticArray of ``statuses`` (``Status``), stamped with ``node``'s clock now."""
    sec, nanosec = divmod(node.get_clock().now().nanoseconds, 1_000_000_000)
    return cdr.diagnostic_array_bytes(sec, nanosec, statuses)


class FilterDiagnostics:
    """See the module. ``inputs``: [(topic, message class)] the node subscribes; at most
    ``checks`` of them are looked up in the graph per publish, in turn (a fleet's thousands of
    topics cost the same each second as one robot's few)."""

    def __init__(self, node, statuses, inputs, complain, period: float = 1.0, checks: int = 24):
        self.node = node
        self.statuses = statuses
        self.inputs = [(topic, type_name(t)) for topic, t in inputs]
        self.complain = complain
        self.checks = int(checks)
        self._next = 0             # the first input of the next look
        self._found = {}           # topic -> its note, while a foreign publisher stays
        self.notes = []            # the input topics' foreign publishers, said in every status
        self.published = 0
        self.pub = self.timer = None
        if not getattr(node, 'publishes_diagnostics', False):
            self.pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, rosmsg.QOS_STREAM)
            self.timer = node.create_timer(period, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def check_graph(self) -> list:
        n = len(self.inputs)
        for k in range(min(n, self.checks)):
            topic, expected = self.inputs[(self._next + k) % n]
            others, names = publishers_of(self.node, topic, expected)
            notes = []
            if others:
                notes.append(f'{topic} has a publisher of {", ".join(others)}; this filter reads {expected} there '
                             '(its messages are not received: the input looks silent)')
            if len(names) > 1:
                # two sources on one input: a second driver, a replay, a spoof; their messages mix
                notes.append(f'{topic} has {len(names)} publishers ({", ".join(names)}): their messages are '
                             'taken as one source; check that only one should publish there')
            if notes:
                self._found[topic] = '; '.join(notes)
            else:
                self._found.pop(topic, None)
        self._next = (self._next + min(n, self.checks)) % n if n else 0
        self.notes = list(self._found.values())
        for note in self.notes:
            self.complain(f'type {note}', note, level='warn')
        return self.notes

    def array(self) -> bytes:
        """The node's statuses now, serialized (a DiagnosticArray), each raised to WARN and noted while
        a foreign publisher stays."""
        notes = self.check_graph()
        statuses = self.statuses()
        if notes:
            for status in statuses:
                status.level = max(status.level, WARN)
                status.message = '; '.join([status.message, *notes]) if status.message else '; '.join(notes)
        return array_bytes(self.node, statuses)

    def publish(self):
        self.pub.publish(self.array())
        self.published += 1
