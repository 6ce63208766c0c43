"""/obstacle_markers <-> obstacle ids and centres.

The world publishes the whole obstacle set in every message: a DELETEALL marker
first, then one CYLINDER per obstacle (ns 'obstacles', id = obstacle id,
scale.x = scale.y = diameter), so a late joiner's single latched message is complete.

``level_set_markers``: a filter's level set in force as LINE_STRIPs (ns 'level_set').
"""
from __future__ import annotations

import math

import numpy as np

from geometry_msgs.msg import Point
from visualization_msgs.msg import Marker, MarkerArray

from ..ros_io import rosmsg

NAMESPACE = 'obstacles'


def obstacles_to_markers(ids, xy, radius: float, stamp=None, frame=rosmsg.MAP_FRAME) -> MarkerArray:
    out = MarkerArray()
    clear = Marker()
    clear.action = Marker.DELETEALL
    clear.ns = NAMESPACE
    if stamp is not None:   # an empty set still says when it took effect (the learner orders by it)
        clear.header.stamp = stamp
    out.markers.append(clear)
    ids = np.asarray(ids).reshape(-1)
    radii = np.broadcast_to(np.asarray(radius, dtype=float), ids.shape)     # one radius, or one each
    for oid, (x, y), r in zip(ids.tolist(), np.asarray(xy, dtype=float).reshape(-1, 2), radii.tolist()):
        m = Marker()
        m.header.frame_id = frame
        if stamp is not None:
            m.header.stamp = stamp
        m.ns = NAMESPACE
        m.id = int(oid)
        m.type = Marker.CYLINDER
        m.action = Marker.ADD
        m.pose.position.x = float(x)
        m.pose.position.y = float(y)
        m.pose.orientation.w = 1.0
        m.scale.x = m.scale.y = 2.0 * float(r)
        m.scale.z = 0.5
        m.color.r, m.color.g, m.color.b, m.color.a = 0.8, 0.2, 0.1, 0.9
        out.markers.append(m)
    return out


class ObstacleMarkers:
    """Current obstacles (id -> centre, radius) as seen through /obstacle_markers."""

    def __init__(self):
        self.centres: dict[int, tuple] = {}
        self.radii: dict[int, float] = {}

    def update(self, msg: MarkerArray) -> None:
        """Apply a MarkerArray; raises ValueError (and changes nothing) if it is malformed."""
        centres, radii = dict(self.centres), dict(self.radii)
        for m in msg.markers:
            if m.action == Marker.DELETEALL:
                centres.clear()
                radii.clear()
                continue
            if m.ns != NAMESPACE:
                continue
            if m.action == Marker.DELETE:
                centres.pop(m.id, None)
                radii.pop(m.id, None)
                continue
            if m.header.frame_id != rosmsg.MAP_FRAME:
                raise ValueError(f"obstacle {m.id} in frame '{m.header.frame_id}', expected 'map'")
            x, y, d = m.pose.position.x, m.pose.position.y, m.scale.x
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(d) and d > 0):
                raise ValueError(f'obstacle {m.id} has a non-finite centre or bad diameter')
            centres[m.id] = (float(x), float(y))
            radii[m.id] = 0.5 * float(d)
        self.centres, self.radii = centres, radii

    def arrays(self):
        ids = np.array(sorted(self.centres), dtype=int)
        xy = np.array([self.centres[i] for i in ids], dtype=float).reshape(-1, 2)
        return ids, xy


# -- the level set in force, around each detected obstacle ---------------------------------------
LEVEL_SET_NAMESPACE = 'level_set'
LEVEL_SET_COLORS = {'standard': (0.2, 0.4, 1.0), 'learned': (0.1, 0.8, 0.2)}
LEVEL_SET_OBSTACLES = 64      # drawn around at most this many detections, the nearest to the robot


def level_set_markers(contours, stamp=None, frame=rosmsg.MAP_FRAME, source: str = 'standard',
                      width: float = 0.06) -> MarkerArray:
    """DELETEALL, then one LINE_STRIP per polyline of ``contours`` (per obstacle, a list of
    (K, 2) map-frame polylines, as runtime.contours.level_sets_around returns), z = 0.05 so
    they show above the ground; blue for the standard set, green for a learned one."""
    out = MarkerArray()
    clear = Marker()
    clear.action = Marker.DELETEALL
    clear.ns = LEVEL_SET_NAMESPACE
    out.markers.append(clear)
    r, g, b = LEVEL_SET_COLORS.get(source, (1.0, 0.6, 0.0))
    marker_id = 0
    for lines in contours:
        for line in lines:
            m = Marker()
            m.header.frame_id = frame
            if stamp is not None:
                m.header.stamp = stamp
            m.ns = LEVEL_SET_NAMESPACE
            m.id = marker_id
            marker_id += 1
            m.type = Marker.LINE_STRIP
            m.action = Marker.ADD
            m.pose.orientation.w = 1.0
            m.scale.x = float(width)
            m.color.r, m.color.g, m.color.b, m.color.a = r, g, b, 1.0
            m.points = [Point(x=float(x), y=float(y), z=0.05) for x, y in np.asarray(line, dtype=float)]
            out.markers.append(m)
    return out


def level_set_lines(msg: MarkerArray) -> list[np.ndarray]:
    """The (K, 2) polylines of a level_set_markers message (for tests and tools)."""
    return [np.array([(p.x, p.y) for p in m.points], dtype=float).reshape(-1, 2)
            for m in msg.markers if m.ns == LEVEL_SET_NAMESPACE and m.type == Marker.LINE_STRIP]


class LevelSetMarkerPublisher:
    """On a filter node: each robot's ``safety_filter/level_set`` (MarkerArray) at ``rate`` Hz on the
    steady clock, the level set in force at the robot's heading around each detected obstacle (the
    LEVEL_SET_OBSTACLES nearest). ``robots``: [(its publisher, ``snapshot()`` -> (SafeSet, pose
    (x, y, theta) or None, detections (N, 2) or None))]. Nothing is computed for a robot no one
    watches, so the control path pays only when an operator watches."""

    def __init__(self, node, robots, rate: float = 2.0, refine: int = 2):
        from rclpy.clock import Clock, ClockType
        self.node = node
        self.robots = list(robots)
        self.refine = refine
        self.timer = node.create_timer(1.0 / rate, self.publish,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.published = 0

    def publish(self):
        for pub, snapshot in self.robots:
            if pub.get_subscription_count() > 0:
                self._publish(pub, snapshot)

    def _publish(self, pub, snapshot):
        from ..runtime.contours import level_sets_around
        safe_set, pose, detections = snapshot()
        contours = []
        if safe_set is not None and pose is not None and detections is not None:
            try:
                contours = level_sets_around(safe_set.vf, pose, detections, safe_set.alpha, self.refine,
                                             nearest=LEVEL_SET_OBSTACLES)
            except ValueError as exc:
                self.node.get_logger().error(f'level set markers: {exc}', throttle_duration_sec=5.0)
                return
        pub.publish(level_set_markers(contours, self.node.get_clock().now().to_msg(),
                                      source=safe_set.source if safe_set is not None else ''))
        self.published += 1
