"""A watcher process for a team on hosts: prints what it hears as JSON lines.

    python -m supersafe_ros.hosts.probe [--graph PERIOD] TOPIC=KIND:QOS ...

KIND is ``diag`` (diagnostic_msgs/DiagnosticStatus: its key/values) or ``pose``
(geometry_msgs/PoseStamped: stamp, x, y); QOS names a profile of ros_io.rosmsg
(stream, latched, log, events). Each line holds ``t`` (CLOCK_MONOTONIC seconds, the
same clock in every process of the machine), ``topic`` and the values; with
``--graph`` it also prints the topic counts {topic: [publishers, subscriptions]} every
PERIOD seconds. Started with ``ip netns exec`` it watches from inside one host:
a DDS participant only talks on the network of the namespace it was made in, and a
process's first participant fixes that for the whole process, so each host gets
its own watcher process.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

from ..nodes.common import run_node
from ..ros_io import rosmsg

QOS = {'stream': rosmsg.QOS_STREAM, 'latched': rosmsg.QOS_LATCHED, 'log': rosmsg.QOS_LOG,
       'events': rosmsg.QOS_EVENTS}
IGNORED = ('/rosout', '/parameter_events')


def parse_watch(item: str) -> tuple[str, str, str]:
    topic, sep, rest = item.partition('=')
    kind, _, qos = rest.partition(':')
    if not sep or kind not in ('diag', 'pose') or (qos or 'stream') not in QOS:
        raise ValueError(f"watch '{item}' is not TOPIC=diag|pose[:{'|'.join(QOS)}]")
    return topic, kind, qos or 'stream'


def emit(record: dict) -> None:
    sys.stdout.write(json.dumps(record) + '\n')
    sys.stdout.flush()


def make_node(watches, graph_period):
    from rclpy.node import Node

    class Probe(Node):
        def __init__(self):
            super().__init__('hosts_probe')
            for topic, kind, qos in watches:
                if kind == 'diag':
                    from diagnostic_msgs.msg import DiagnosticStatus
                    self.create_subscription(DiagnosticStatus, topic, lambda m, t=topic: emit(
                        {'t': time.monotonic(), 'topic': t, 'name': m.name,
                         'values': rosmsg.diagnostic_values(m)}), QOS[qos])
                else:
                    from geometry_msgs.msg import PoseStamped
                    self.create_subscription(PoseStamped, topic, lambda m, t=topic: emit(
                        {'t': time.monotonic(), 'topic': t,
                         'stamp': m.header.stamp.sec + m.header.stamp.nanosec * 1e-9,
                         'x': m.pose.position.x, 'y': m.pose.position.y}), QOS[qos])
            if graph_period > 0:
                # a wall-clock timer: the graph is watched before sim time starts
                from rclpy.clock import Clock, ClockType
                self.create_timer(graph_period, self.graph, clock=Clock(clock_type=ClockType.STEADY_TIME))
            emit({'t': time.monotonic(), 'ready': True})

        def graph(self):
            counts = {t: [self.count_publishers(t), self.count_subscribers(t)]
                      for t, _ in self.get_topic_names_and_types() if t not in IGNORED}
            emit({'t': time.monotonic(), 'graph': counts})

    return Probe


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(prog='python -m supersafe_ros.hosts.probe')
    parser.add_argument('--graph', type=float, default=0.0, help='seconds between graph counts')
    parser.add_argument('watch', nargs='*', help='TOPIC=diag|pose[:QOS]')
    args = parser.parse_args(argv)
    watches = [parse_watch(w) for w in args.watch]
    return run_node(make_node(watches, args.graph), args=['probe'])


if __name__ == '__main__':
    raise SystemExit(main())
