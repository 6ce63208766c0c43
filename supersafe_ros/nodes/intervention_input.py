"""An /interventions message checked and turned into the record the learner stores.

``parse_intervention(msg, frame_prefix, receive_ns)`` returns a
``learning.intervention_store.Intervention`` or raises ``Rejected`` with a short reason
(one of ``REASONS``: the learner counts and logs per reason) and the details:

1. frame name at most ``MAX_FRAME_LENGTH`` characters (a 100 kB frame is refused unread);
2. frame is ``frame_prefix`` followed by 1-18 ASCII digits (leading zeros allowed:
   ``obstacle_007`` is obstacle 7, and a duplicate of ``obstacle_7`` at the same stamp);
3. stamp valid: ``sec >= 0``, ``0 <= nanosec < 1e9``; stamp 0 is unstamped: the receive
   time ``receive_ns()`` (the node's clock, or the steady clock when the node has no clock
   yet: use_sim_time without /clock), never a constant that would make the next unstamped
   intervention on that obstacle its duplicate;
4. position finite, quaternion finite and normalisable.

Whether the state is inside the library grid is not checked here: an intervention
outside it is a real event (the world removed the obstacle), kept in the store and set
aside from the fit by the learner.
"""
from __future__ import annotations

import re
import time

from ..learning.intervention_store import Intervention
from ..ros_io import rosmsg

MAX_FRAME_LENGTH = 64          # 'obstacle_' + an id: longer frame names are refused unread
REASONS = ('frame too long', 'frame names no obstacle', 'invalid stamp', 'invalid pose')


class Rejected(ValueError):
    """An intervention message that cannot be stored; ``reason`` is one of ``REASONS``."""

    def __init__(self, reason: str, details: str):
        super().__init__(details)
        self.reason = reason


def parse_intervention(msg, frame_prefix: str, receive_ns) -> Intervention:
    """The validated intervention of ``msg`` (geometry_msgs/PoseStamped); raises Rejected."""
    frame = msg.header.frame_id
    if len(frame) > MAX_FRAME_LENGTH:
        raise Rejected('frame too long', f'frame name is {len(frame)} characters long (limit '
                       f"{MAX_FRAME_LENGTH}): '{frame[:24]}...'")
    if not re.fullmatch(re.escape(frame_prefix) + r'[0-9]{1,18}', frame):
        raise Rejected('frame names no obstacle', f"frame '{frame}' does not name an obstacle "
                       f"('{frame_prefix}<int>')")
    sec, nanosec = msg.header.stamp.sec, msg.header.stamp.nanosec
    if sec < 0 or not (0 <= nanosec < 1_000_000_000):
        raise Rejected('invalid stamp', f'stamp ({sec} s, {nanosec} ns) is not a valid time')
    try:
        x, y, theta = rosmsg.pose_to_state(msg, frame=None)
    except ValueError as exc:
        raise Rejected('invalid pose', str(exc)) from None
    stamp_ns = sec * 1_000_000_000 + nanosec
    if stamp_ns == 0:
        stamp_ns = receive_ns()
    return Intervention(int(stamp_ns), frame, x, y, theta, time.time())


def receive_time_ns(clock) -> int:
    """Now on ``clock`` (an rclpy clock) in ns; the steady clock when that clock has not
    started (0: use_sim_time with no /clock yet)."""
    return clock.now().nanoseconds or time.monotonic_ns()
