"""Record every topic of a running graph into a rosbag2 bag (MCAP storage, rosbags' writer).

``start_recorder(path, domain_id=None) -> RecorderHandle`` starts an rclpy node of its
own (BackgroundNode: own context, daemon thread) that polls the graph every
``poll_period`` s, subscribes to each new topic with ``raw=True`` (the CDR bytes go to
the bag unchanged) and a QoS adapted to the publishers' offers, as ``ros2 bag record``
does (reliable only if every publisher is reliable, transient local only if every
publisher is, so latched topics such as /obstacle_markers arrive in full), and writes
each message with its receive time (system clock).
``handle.stop()`` takes what is still queued, ends the subscriptions and closes the bag
(metadata.yaml written);
it returns the BagInfo. Topics with several types, or whose type ROS 2 Jazzy's typestore
(rosbags) does not describe, are skipped with a warning (``handle.skipped``).

    from supersafe_ros.ros_io.bag_recorder import start_recorder
    rec = start_recorder('runs/p01_bag')          # before or after the graph starts
    ...
    info = rec.stop()                             # BagInfo: path, mcap_path, counts

The recorder sees only topics that have a publisher: it joins a topic within one poll
period of its first publisher appearing, and a volatile message sent before that is not
in the bag. To start a run only once the recorder listens, give ``ready_after`` (topics):
when it has subscribed to each of them and matched a publisher there, it creates a
publisher on READY_TOPIC (std_msgs/Empty, latched, one message), which a sim clock can
wait for (sim_clock_node ``wait_for_publishers: ['/bag_recorder/ready=1', ...]``; this is
what ``supersafe team --record`` does). ``handle.wait_until_recording(topics, timeout)``
waits for given topics from the calling thread.
"""
from __future__ import annotations

import importlib
import logging
import os
import threading
import time

from ..recording.bag import BagWriter, DefinitionNotFound, qos_profile

LOG = logging.getLogger(__name__)
SUBSCRIPTION_DEPTH = 1000   # deep: a Python callback may lag a burst of poses; nothing is dropped
READY_TOPIC = '/bag_recorder/ready'


def message_class(type_name: str):
    """'pkg/msg/Type' -> the rclpy message class."""
    package, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def _policy_name(policy) -> str:
    return policy.name.lower()    # rclpy enums: KEEP_LAST, RELIABLE, TRANSIENT_LOCAL, AUTOMATIC


def offered_profile(qos) -> dict:
    """A publisher's rclpy QoSProfile as rosbag2's offered_qos_profiles entry."""
    ns = lambda d: getattr(d, 'nanoseconds', 0)  # noqa: E731
    return qos_profile(history=_policy_name(qos.history), depth=qos.depth,
                       reliability=_policy_name(qos.reliability),
                       durability=_policy_name(qos.durability),
                       deadline_ns=ns(qos.deadline), lifespan_ns=ns(qos.lifespan),
                       liveliness=_policy_name(qos.liveliness),
                       lease_ns=ns(qos.liveliness_lease_duration),
                       avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions)


def adapted_qos(publisher_qos: list):
    """Subscription QoS that matches every offer: rosbag2's Rosbag2QoS::adapt_request_to_offers."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    reliable = bool(publisher_qos) and all(q.reliability == ReliabilityPolicy.RELIABLE for q in publisher_qos)
    latched = bool(publisher_qos) and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL
                                          for q in publisher_qos)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SUBSCRIPTION_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class TopicRecorder:
    """Wiring on a given node: graph polling, raw subscriptions, and the bag writer."""

    def __init__(self, node, bag: BagWriter, poll_period: float = 0.5, exclude=(), ready_after=()):
        from rclpy.clock import Clock, ClockType
        self.node = node
        self.bag = bag
        self.exclude = set(exclude) | {READY_TOPIC}
        self.subscriptions = {}
        self.skipped: dict[str, str] = {}
        self.ready_after = list(ready_after)
        self.ready_pub = None
        self._system = Clock(clock_type=ClockType.SYSTEM_TIME)
        self.poll()
        self.timer = node.create_timer(poll_period, self.poll,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))

    def poll(self):
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self.subscriptions or topic in self.skipped or topic in self.exclude:
                continue
            if len(types) != 1:
                self._skip(topic, f'several types {types}')
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue   # only subscribers so far: nothing to record, and no QoS to match
            try:
                cls = message_class(types[0])
                type_hash = str(infos[0].topic_type_hash)
                self.bag.add_topic(topic, types[0], [offered_profile(i.qos_profile) for i in infos],
                                   type_hash if type_hash.startswith('RIHS') else None)
            except (DefinitionNotFound, ImportError, AttributeError, ValueError) as exc:
                self._skip(topic, str(exc))
                continue
            self.subscriptions[topic] = self.node.create_subscription(
                cls, topic, lambda data, info, topic=topic: self.on_message(topic, data, info),
                adapted_qos([i.qos_profile for i in infos]), raw=True)
        if self.ready_after and self.ready_pub is None and all(
                t in self.subscriptions and self.subscriptions[t].get_publisher_count() > 0
                for t in self.ready_after):
            from std_msgs.msg import Empty
            from .rosmsg import QOS_LATCHED
            self.ready_pub = self.node.create_publisher(Empty, READY_TOPIC, QOS_LATCHED)
            self.ready_pub.publish(Empty())

    def _skip(self, topic, why):
        self.skipped[topic] = why
        self.node.get_logger().warn(f'not recording {topic}: {why}')

    def on_message(self, topic, data: bytes, info):
        self.bag.write(topic, data, self._system.now().nanoseconds)


class RecorderHandle:
    """A running recorder; ``stop()`` closes the bag and returns its BagInfo."""

    def __init__(self, ros, recorder: TopicRecorder):
        self._ros = ros
        self.recorder = recorder
        self.path = recorder.bag.path
        self._info = None
        self._lock = threading.Lock()

    @property
    def topics(self) -> list[str]:
        return sorted(self.recorder.subscriptions)

    @property
    def skipped(self) -> dict:
        return dict(self.recorder.skipped)

    def message_count(self, topic: str | None = None) -> int:
        bag = self.recorder.bag
        if topic is None:
            return bag.message_count
        t = bag.topics.get(topic)
        return t.count if t else 0

    def wait_until_recording(self, topics, timeout: float = 30.0) -> bool:
        """True once every topic in ``topics`` is subscribed (False at the deadline)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(t in self.recorder.subscriptions for t in topics):
                return True
            time.sleep(0.05)
        return False

    def stop(self, quiet: float = 0.3, max_wait: float = 5.0):
        """Take what is still queued (until no message came for ``quiet`` s, at most
        ``max_wait`` s), then stop the node and close the bag; returns the BagInfo."""
        with self._lock:
            if self._info is None:
                deadline = time.monotonic() + max_wait
                count = -1
                while count != self.recorder.bag.message_count and time.monotonic() < deadline:
                    count = self.recorder.bag.message_count
                    time.sleep(quiet)
                self._ros.close()       # no callback runs after this
                self._info = self.recorder.bag.close()
            return self._info

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()


def start_recorder(path, domain_id: int | None = None, poll_period: float = 0.5,
                   exclude=(), node_name: str = 'bag_recorder', ready_after=()) -> RecorderHandle:
    """Record every topic of the graph on ``domain_id`` (default $ROS_DOMAIN_ID) into a new
    bag folder ``path`` (must not exist or be empty). Returns a RecorderHandle.
    ``ready_after``: topics after which READY_TOPIC gets a publisher (see the module doc)."""
    from .background_node import BackgroundNode
    bag = BagWriter(path)
    ros = None
    try:
        ros = BackgroundNode(node_name, int(os.environ.get('ROS_DOMAIN_ID', '0')
                                            if domain_id is None else domain_id))
        recorder = TopicRecorder(ros.node, bag, poll_period, exclude, ready_after)
        ros.start()
    except Exception:
        if ros is not None:
            ros.close()
        bag.close()
        raise
    return RecorderHandle(ros, recorder)
