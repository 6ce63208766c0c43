"""The filter node's batched topics: every robot at once, row i robot i (``batched_topics``;
docs/fleet.md, ``ros_io.fleetmsg``), for a fleet manager or simulator that holds every robot's state.

``FleetTopics(node, io, n, on_poses, require_detections)``: ``fleet/poses`` (a callback of the node's:
each message is a tick of every robot; the newest of those waiting, ``newest_poses``, read by
``take_poses``), ``fleet/detections`` and ``fleet/cmd_vel_nav`` (on the node's helper node ``io``,
taken by the tick: ``take_waiting``), ``fleet/cmd_vel`` and ``fleet/safety_filter/state``.

Bad input is refused with a logged reason and made safe: a whole bad pose message fails every robot
safe (their newest pose is rejected), a bad row only its robot; a bad command message or row keeps
the previous command; bad detections fail every robot safe until valid ones come.
"""
from __future__ import annotations

import numpy as np

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from std_msgs.msg import Float64MultiArray

from ..filter import update_commands, update_detections_all, update_poses
from ..ros_io import cdr, fleetmsg, rosmsg
from ..ros_io.take import take_all, take_newest
from .filter_diagnostics import array_bytes
from .filter_sources import NO_DETECTIONS


class FleetTopics:
    """The batched topics (see the module). ``on_poses(data)``: the node's callback of a serialized
    ``fleet/poses``; ``take_waiting()`` -> (every fleet/detections message waiting, every
    fleet/cmd_vel_nav message waiting) taken into the robots' filters."""

    def __init__(self, node, io, n, on_poses, require_detections):
        self.node, self.n = node, n
        noop = lambda msg: None  # noqa: E731  (taken by the tick, never by an executor)
        fleet = node.resolve_topic_name
        self.detections_sub = (io.create_subscription(PoseArray, fleet('fleet/detections'), noop,
                                                      rosmsg.QOS_STREAM, raw=True) if require_detections else None)
        self.commands_sub = io.create_subscription(Float64MultiArray, fleet('fleet/cmd_vel_nav'), noop,
                                                   rosmsg.QOS_STREAM)
        # raw: the poses are read straight from the CDR buffer (fleetmsg.posearray_cdr_to_states)
        self.poses_sub = node.create_subscription(PoseArray, 'fleet/poses', on_poses, rosmsg.QOS_STREAM, raw=True)
        self.cmd_pub = node.create_publisher(Float64MultiArray, 'fleet/cmd_vel', rosmsg.QOS_STREAM)
        self.state_pub = node.create_publisher(DiagnosticArray, 'fleet/safety_filter/state', rosmsg.QOS_STREAM)
        self.last_poses = -1e18       # steady s: the last fleet/poses tick
        self.superseded = 0           # fleet/poses superseded by newer ones before they were decided

    def inputs(self) -> list:
        """(topic, message class) of each batched input (for the graph watch)."""
        out = [('fleet/poses', PoseArray), ('fleet/cmd_vel_nav', Float64MultiArray)]
        return out + ([('fleet/detections', PoseArray)] if self.detections_sub is not None else [])

    def flowing(self, now, period) -> bool:
        """The poses are ticking (one came within 1.5 periods: a late one is not a missing one)."""
        return now - self.last_poses < period * 1.5

    def send(self, decisions) -> None:
        self.cmd_pub.publish(fleetmsg.commands_to_msg(np.column_stack([decisions.linear, decisions.omega])))

    def send_zero(self) -> None:
        self.cmd_pub.publish(fleetmsg.commands_to_msg(np.zeros((self.n, 2))))

    def say_states(self, states) -> None:
        self.state_pub.publish(array_bytes(self.node, states))

    # -- the inputs, read and checked, into the robots' filters -----------------------------------------
    def newest_poses(self, data, complain):
        """The newest fleet/poses waiting (``data`` if none came after it): the others were superseded
        while the node decided, counted and said."""
        newer, superseded = take_newest(self.poses_sub)
        if newer is None:
            return data
        self.superseded += superseded
        complain('fleet poses behind', f'fleet/poses: {self.superseded} message(s) superseded so far by newer '
                 'ones that came while the filter decided (it is slower than the poses); deciding on the newest')
        return newer

    def take_poses(self, data, filters, wiring, t, complain_robot):
        """A serialized fleet/poses (a PoseArray object is taken too) into the robots' filters at ``t``."""
        w = wiring
        try:
            if isinstance(data, PoseArray):
                states, bad = fleetmsg.posearray_to_states(data, self.n, w.frame)
                header_stamp = data.header.stamp
            else:
                states, bad, header_stamp = fleetmsg.posearray_cdr_to_states(data, self.n, w.frame)
            stamp = w.stamp(header_stamp, t)
        except ValueError as exc:
            for f in filters:
                f.reject_pose(str(exc), t)
            w.complain('fleet poses', f'fleet/poses rejected: {exc}; failing safe (every robot)', level='error')
            return
        for i, why in enumerate(bad):
            if why:
                filters[i].reject_pose(why, t)
                complain_robot(i, 'fleet pose', f'fleet/poses row rejected: {why}; failing safe', level='error')
        update_poses(filters, states, t, stamp=stamp, skip=bad)   # the good rows, validated at once
        if self.detections_sub is None:     # no obstacle sensor: every pose comes with "no obstacle"
            update_detections_all(filters, NO_DETECTIONS, t, w.safe_set)

    def take_waiting(self, filters, wiring, complain_robot):
        """Every fleet/detections and fleet/cmd_vel_nav message waiting, oldest first, each checked (or
        refused, and logged) as its own callback would; they count as arrived now, at most a period after
        they came. (the robots whose new commands were beyond their limits, whether valid detections came)."""
        t = wiring.now()
        ready = False
        for msg in take_all(self.detections_sub) if self.detections_sub is not None else ():
            ready = self._take_detections(msg, filters, wiring, t) or ready
        commands = take_all(self.commands_sub)
        beyond = self._take_commands(commands, filters, wiring, t, complain_robot) if commands else []
        return beyond, ready

    def _take_detections(self, msg, filters, wiring, t) -> bool:
        """A serialized fleet/detections PoseArray (a PoseArray is taken too), read as one array shared by
        every robot; at most ``max_detections`` kept, the nearest to the robots. False if refused."""
        w = wiring
        try:
            xy = (rosmsg.posearray_to_xy(msg, w.frame) if isinstance(msg, PoseArray) else
                  rosmsg.checked_xy(*cdr.pose_array_xy(msg, 'fleet detections'), w.frame))
        except ValueError as exc:
            for f in filters:
                f.reject_detections(str(exc), t)
            w.complain('fleet detections', f'fleet/detections rejected: {exc}; failing safe', level='error')
            return False
        update_detections_all(filters, xy, t, w.safe_set)     # one array shared by every robot
        d = filters[0].detections
        if d.dropped:
            w.complain('fleet/detections dropped', f'fleet/detections: {d.note}',
                       level='warn' if d.dropped_safely else 'error')
        return True

    def _take_commands(self, msgs, filters, wiring, t, complain_robot) -> list:
        """fleet/cmd_vel_nav messages, oldest first, as if each were taken in turn: a message or row refused
        is said and keeps the previous command; of the rest, each robot's newest row is its command (the
        older rows, arrived at the same time, would be replaced by it at once: each robot's command is
        updated once, however many messages waited). The robots whose commands were beyond their limits."""
        w, n = wiring, self.n
        newest = None                           # (N, 2): each robot's newest good row
        taken = np.zeros(n, bool)               # robots with a good row in some message
        newest_bad = ()                         # why each row of the newest readable message was refused
        for msg in msgs:
            try:
                commands, bad = fleetmsg.msg_to_commands(msg, n)
            except ValueError as exc:
                w.complain('fleet cmd', f'fleet/cmd_vel_nav rejected: {exc}; keeping the previous commands',
                           level='error')
                continue
            good = np.fromiter((not why for why in bad), dtype=bool, count=n)
            for i in np.flatnonzero(~good).tolist():
                complain_robot(i, 'fleet cmd', f'fleet/cmd_vel_nav row rejected: {bad[i]}; keeping the previous '
                               'command', level='error')
            if newest is None:
                newest = np.array(commands, dtype=float)
            else:
                newest[good] = commands[good]
            taken |= good
            newest_bad = bad
        if newest is None:
            return []
        # the good rows, validated at once
        beyond = update_commands(filters, newest[:, 1], t, skip=~taken, linears=newest[:, 0])
        for f, why in zip(filters, newest_bad):
            if why:     # (after the update: the newest message's word stays, as in turn)
                f.command.note = f'{why}: rejected, the previous command kept'
        return list(beyond)
