"""Drivers of learner_node in the Phase II layout (not a test module): for
test_nodes_learner_first_passage.py, test_nodes_learner_clicks.py and bench/bench_learner.py.

``Driver`` publishes Phase II events (robot poses, obstacle markers, interventions) and
records the learner's fits; ``play`` publishes them scene by scene; ``click_flood`` makes
hasty and far clicks; ``JunkSender`` publishes junk interventions and reads /rosout.
"""
import math

import numpy as np
from rclpy.parameter import Parameter

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import Float32MultiArray
from std_srvs.srv import Empty
from visualization_msgs.msg import MarkerArray

from supersafe_ros.nodes.learner_node import FIT_TOPIC, VALUE_FUNCTION_TOPIC, LearnerNode
from supersafe_ros.nodes.markers import obstacles_to_markers
from supersafe_ros.reach.library import PAPER_OMEGAS
from supersafe_ros.ros_io import rosmsg

from graph_support import Rosout, Spinner, matched

SHAPE = [41, 41, 24]
OMEGAS = [float(w) for w in PAPER_OMEGAS]
STEP = 0.2
FAR = 4               # clicks on obstacles far from the robot (outside the grid)


def make_learner(ctx, store, **extra):
    """A learner_node on the coarse test library, storing in ``store``; ``extra``: more parameters."""
    params = dict(store_path=str(store), library_shape=SHAPE, library_omegas=OMEGAS)
    params.update(extra)
    return LearnerNode(context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])


def stamp_of(t):
    from builtin_interfaces.msg import Time
    sec = math.floor(t)
    return Time(sec=sec, nanosec=min(int(round((t - sec) * 1e9)), 999_999_999))


class Driver:
    def __init__(self, ctx):
        from rclpy.node import Node
        self.node = Node('phase2_driver', context=ctx)
        self.pose_pub = self.node.create_publisher(PoseStamped, '/robot_0/pose', rosmsg.QOS_STREAM)
        self.markers_pub = self.node.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
        self.iv_pub = self.node.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        self.fits, self.vfs = [], []
        self.fit_sub = self.node.create_subscription(DiagnosticStatus, FIT_TOPIC,
                                                     lambda m: self.fits.append(rosmsg.diagnostic_values(m)),
                                                     rosmsg.QOS_LATCHED)
        self.vf_sub = self.node.create_subscription(Float32MultiArray, VALUE_FUNCTION_TOPIC, self.vfs.append,
                                                    rosmsg.QOS_LATCHED)
        self.reset = self.node.create_client(Empty, '/learner/reset')

    def publish(self, ev):
        if ev[0] == 'pose':
            self.pose_pub.publish(rosmsg.state_to_pose(ev[3], stamp_of(ev[2])))
        elif ev[0] == 'obstacles':
            self.markers_pub.publish(obstacles_to_markers(ev[2], ev[3], 1.8, stamp_of(ev[1])))
        else:
            self.iv_pub.publish(rosmsg.state_to_pose(ev[3], stamp_of(ev[2]), rosmsg.obstacle_frame(ev[1])))

    def fit(self):
        return self.fits[-1] if self.fits else {}

    def wait_for(self, spin, *more):
        """Until the learner has matched every topic of the driver's (and ``more`` endpoints)."""
        spin.until(lambda: matched(self.pose_pub, self.markers_pub, self.iv_pub, self.fit_sub, *more), 20.0,
                   'learner topics')


def drive(ctx, node):
    """A Driver for ``node`` and a Spinner over both."""
    driver = Driver(ctx)
    return driver, Spinner(ctx, node, driver.node)


def play(spin, node, driver, events):
    """Publish scene by scene; each scene is published at once (the topics then arrive in
    any interleaving) and the next one waits until the learner has read this one's poses."""
    scenes, scene, n_iv = [], [], 0
    for ev in events:
        scene.append(ev)
        if ev[0] == 'pose' and ev[3][0] < -20:      # parked: the scene is over
            scenes.append(scene)
            scene = []
    scenes.append(scene)
    for sc in scenes:
        for ev in sc:
            driver.publish(ev)
            n_iv += ev[0] == 'intervention'
        last = max(ev[2] for ev in sc if ev[0] == 'pose') if any(e[0] == 'pose' for e in sc) else None
        if last is not None:
            spin.until(lambda: node.builder.newest >= last - 1e-6 and node.store.count >= n_iv, 30.0,
                       'the learner reading the scene')
    return n_iv


def click_flood(t0, first_obstacle, offsets=(2.0, -2.5, 3.0, -2.2, 2.5, -3.0)):
    """Scenes in the Phase II layout where the person clicks the obstacle only once the robot
    has passed it (the first pose with x > 0, its stamp and state: what the console sends),
    and clicks obstacles that are nowhere near the robot (their state far outside the grid)."""
    t, oid = float(t0), int(first_obstacle)
    yield ('pose', 'robot_0', t, (-30.0, 0.0, 0.0))
    for k, y0 in enumerate(offsets):
        t += STEP
        yield ('obstacles', t, [oid], np.zeros((1, 2)))
        x = -8.0
        while True:
            t += STEP
            yield ('pose', 'robot_0', t, (x, y0, 0.0))
            if x > 0.0:
                yield ('intervention', oid, t, (x, y0, 0.0))
                break
            x += 3.0 * STEP
        if k < FAR:     # a far click: another obstacle, the robot 25 m away from it
            yield ('intervention', 900 + k, t, (-25.0, 4.0, 0.0))
        t += STEP
        yield ('obstacles', t, [], np.zeros((0, 2)))
        t += STEP
        yield ('pose', 'robot_0', t, (-30.0, 0.0, 0.0))
        oid += 1


class JunkSender:
    """A node that publishes on /interventions and reads /rosout, spun with the learner."""

    def __init__(self, ctx, learner):
        from rclpy.node import Node
        self.node = Node('junk_sender', context=ctx)
        self.pub = self.node.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        self.rosout = Rosout(self.node)
        self.spin = Spinner(ctx, learner, self.node)
        self.spin.until(lambda: matched(self.pub, self.rosout.sub), 20.0, 'the learner')
