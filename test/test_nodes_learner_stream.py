"""learner_node on a stream it did not make (issue 21): the honest stream of
test/honest_stream_support (poses at 20 Hz on a sim clock, stamped obstacle sets, each
intervention 1 ms after the pose it judged, the obstacle cleared 10 ms later, the robot
teleported to the next scene 1 s later; 126 scenes, hidden w 0.5, mu 1.0, sigma 0.3),
published topic by topic in an order shuffled across topics. The node must fit every
encounter, the last one included without more data, and find what the ROS-free builder
and estimator find on the same stream: w 0.5 exactly, mu within 0.1."""
import math

import numpy as np
import pytest
from rclpy.parameter import Parameter

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from visualization_msgs.msg import MarkerArray

from supersafe_ros.learning.encounters import EncounterBuilder, EncounterRecord
from supersafe_ros.learning.estimators import encounter_intervals, fit_first_passage_intervals
from supersafe_ros.learning.phase2_stream import feed
from supersafe_ros.nodes.learner_node import FIT_TOPIC, QOS_EVERY_OBSTACLE_SET, LearnerNode
from supersafe_ros.nodes.markers import obstacles_to_markers
from supersafe_ros.reach.library import PAPER_OMEGAS
from supersafe_ros.ros_io import rosmsg

from graph_support import Spinner, matched
from honest_stream_support import MU, W, honest_stream, shuffled_across_topics

pytestmark = pytest.mark.ros   # rclpy nodes in this process

SHAPE = [41, 41, 24]
SEED = 1


def stamp_of(t):
    from builtin_interfaces.msg import Time
    sec = math.floor(t)
    return Time(sec=sec, nanosec=min(int(round((t - sec) * 1e9)), 999_999_999))


def test_the_learner_node_reads_a_foreign_honest_stream_in_any_cross_topic_order(ros_context, tmp_path):
    from rclpy.node import Node
    node = LearnerNode(context=ros_context, parameter_overrides=[
        Parameter(k, value=v) for k, v in dict(store_path=str(tmp_path / 's.jsonl'), estimator='first-passage',
                                               robots=['robot_0'], library_shape=SHAPE,
                                               library_omegas=[float(w) for w in PAPER_OMEGAS]).items()])
    driver = Node('foreign_stream', context=ros_context)
    pose_pub = driver.create_publisher(PoseStamped, '/robot_0/pose', rosmsg.QOS_EVENTS)
    markers_pub = driver.create_publisher(MarkerArray, '/obstacle_markers', QOS_EVERY_OBSTACLE_SET)
    iv_pub = driver.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
    fits = []
    fit_sub = driver.create_subscription(DiagnosticStatus, FIT_TOPIC,
                                         lambda m: fits.append(rosmsg.diagnostic_values(m)), rosmsg.QOS_LATCHED)
    spin = Spinner(ros_context, node, driver)
    try:
        spin.until(lambda: matched(pose_pub, markers_pub, iv_pub, fit_sub), 20.0, 'learner topics')
        vf_s = next(e for e in node.entries if e.meta['omega_max'] == W)
        events, _ = honest_stream(vf_s, seed=SEED)
        arrival = shuffled_across_topics(events, seed=SEED)
        assert arrival != events
        # published a scene's worth at a time (a new scene's obstacle set starts a chunk), each
        # chunk read before the next: the order within a chunk is the shuffled arrival order
        chunks, chunk = [], []
        for ev in arrival:
            if ev[0] == 'obstacles' and len(ev[2]) and chunk:
                chunks.append(chunk)
                chunk = []
            chunk.append(ev)
        chunks.append(chunk)
        sent = 0
        for chunk in chunks:
            for ev in chunk:
                if ev[0] == 'pose':
                    pose_pub.publish(rosmsg.state_to_pose(ev[3], stamp_of(ev[2])))
                elif ev[0] == 'obstacles':
                    markers_pub.publish(obstacles_to_markers(ev[2], ev[3], 1.8, stamp_of(ev[1])))
                else:
                    iv_pub.publish(rosmsg.state_to_pose(ev[3], stamp_of(ev[2]), rosmsg.obstacle_frame(ev[1])))
                    sent += 1
            last = max((ev[2] for ev in chunk if ev[0] == 'pose'), default=None)
            spin.until(lambda: (last is None or node.builder.newest >= last - 1e-6) and node.store.count >= sent,
                       30.0, 'the learner reading the chunk')
        # no park pose, no more data: the last encounters become final by themselves
        try:
            spin.until(lambda: fits and fits[-1].get('fitted_encounters') == '126', 60.0,
                       'a fit on all 126 encounters')
        except AssertionError as exc:
            raise AssertionError(f'{exc}; last status {fits[-1] if fits else None}; '
                                 f'builder {node.builder.counts}') from None
        fit = fits[-1]
        assert fit['unmatched_interventions'] == '0' and int(fit['fitted_interventions']) == sent
        # the same stream through the ROS-free builder and estimator, in publication order
        b = EncounterBuilder(node.lo, node.hi, **node.builder_args)
        feed(b, events)
        b.finish_all()
        records = b.pop_finished()
        offline = fit_first_passage_intervals(node.entries, encounter_intervals(
            node.entries, [r.to_encounter() for r in records]), admissible=node.admissible)
        # the node's encounters are the builder's (stamps through ROS time: to the nanosecond)
        stored = sorted((EncounterRecord.from_json(line) for line in
                         (tmp_path / 's.encounters.jsonl').read_text().splitlines()), key=lambda r: r.obstacle)
        records.sort(key=lambda r: r.obstacle)
        assert [(r.obstacle, r.intervened, r.reason, len(r.t)) for r in stored] == \
            [(r.obstacle, r.intervened, r.reason, len(r.t)) for r in records]
        for a, b in zip(stored, records):
            assert a.t == pytest.approx(b.t, abs=1e-6) and np.allclose(a.frames, b.frames, atol=1e-9)
        assert float(fit['omega_max']) == offline.omega_max == W
        assert float(fit['mu']) == pytest.approx(offline.mu, abs=1e-3) and abs(offline.mu - MU) <= 0.1
    finally:
        spin.shutdown()
        node.close()
        node.destroy_node()
        driver.destroy_node()
