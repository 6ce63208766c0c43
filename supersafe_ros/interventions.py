"""A person's intervention, from a click to the message the simulated supervisor sends.

Shared by the RViz node (``/clicked_point``) and the web console (a click on an
obstacle): both publish on /interventions exactly what supervisor_node publishes, the
state of the robot the intervention concerns relative to the obstacle (obstacle at
the origin, axes as map, heading as in map), in frame ``obstacle_<id>``. ROS-free:

    obstacle_under_point(point, obstacles, radii, tolerance) -> obstacle id (or NoIntervention)
    intervention_on_obstacle(obstacle_id, obstacles, robots) -> Intervention
    intervention_at_point(point, obstacles, radii, robots, tolerance) -> Intervention

``obstacles``: {id: (x, y)} centres in map; ``radii``: {id: r} or one radius for all;
``robots``: {name: (x, y, theta)} newest poses in map. The robot concerned is the one
nearest the obstacle's centre: the one the person is watching approach it.
A click that cannot be an intervention raises ``NoIntervention`` with the reason,
for the caller to log or show; nothing is sent then.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Mapping


class NoIntervention(ValueError):
    """The click names no obstacle, or no robot it could concern; the message says why."""


@dataclass(frozen=True)
class Intervention:
    obstacle_id: int
    robot: str
    rel_state: tuple        # (x - cx, y - cy, theta) of the robot
    robot_distance: float   # robot to obstacle centre [m]


def _finite(*values) -> bool:
    return all(math.isfinite(float(v)) for v in values)


def obstacle_under_point(point, obstacles: Mapping[int, tuple], radii, tolerance: float = 0.0) -> int:
    """The obstacle whose disc, grown by ``tolerance``, holds ``point`` (x, y); the one with
    the nearest centre if several do. Raises NoIntervention otherwise."""
    px, py = float(point[0]), float(point[1])
    if not _finite(px, py):
        raise NoIntervention(f'clicked point ({px}, {py}) is not finite')
    if not obstacles:
        raise NoIntervention(f'no obstacles: the point ({px:.2f}, {py:.2f}) is on none')
    best, best_d, nearest = None, math.inf, (None, math.inf)
    for oid, (cx, cy) in obstacles.items():
        d = math.hypot(px - cx, py - cy)
        r = radii[oid] if isinstance(radii, Mapping) else float(radii)
        if d - r < nearest[1]:
            nearest = (oid, d - r)
        if d <= r + tolerance and d < best_d:
            best, best_d = oid, d
    if best is None:
        raise NoIntervention(f'the point ({px:.2f}, {py:.2f}) is on no obstacle: the nearest, '
                             f'{nearest[0]}, is {nearest[1]:.2f} m beyond its rim '
                             f'(tolerance {tolerance:g} m)')
    return int(best)


def intervention_on_obstacle(obstacle_id: int, obstacles: Mapping[int, tuple],
                             robots: Mapping[str, tuple]) -> Intervention:
    """The intervention message's content for an obstacle: the nearest robot's state relative
    to it. Raises NoIntervention for an unknown obstacle (already removed) or no robot pose."""
    if obstacle_id not in obstacles:
        raise NoIntervention(f'obstacle {obstacle_id} does not exist (already removed?)')
    cx, cy = (float(v) for v in obstacles[obstacle_id])
    poses = {name: s for name, s in robots.items() if s is not None and _finite(*s)}
    if not poses:
        raise NoIntervention(f'no robot pose known: an intervention on obstacle {obstacle_id} '
                             'would concern no robot')
    name = min(poses, key=lambda n: (math.hypot(poses[n][0] - cx, poses[n][1] - cy), n))
    x, y, theta = (float(v) for v in poses[name])
    return Intervention(int(obstacle_id), name, (x - cx, y - cy, theta), math.hypot(x - cx, y - cy))


def intervention_at_point(point, obstacles: Mapping[int, tuple], radii, robots: Mapping[str, tuple],
                          tolerance: float = 0.0) -> Intervention:
    """A click at ``point`` (x, y, map) as an intervention (see the module doc)."""
    return intervention_on_obstacle(obstacle_under_point(point, obstacles, radii, tolerance),
                                    obstacles, robots)
