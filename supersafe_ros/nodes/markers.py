"""/obstacle_markers <-> obstacle ids and centres.

The world publishes the whole obstacle set in every message: a DELETEALL marker
first, then one CYLINDER per obstacle (ns 'obstacles', id = obstacle id,
scale.x = scale.y = diameter), so a late joiner's single latched message is complete.
"""
from __future__ import annotations

import math

import numpy as np

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
    for oid, (x, y) in zip(np.asarray(ids).tolist(), np.asarray(xy, dtype=float).reshape(-1, 2)):
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
        m.scale.x = m.scale.y = 2.0 * float(radius)
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
