"""Taking a subscription's messages outside the executor: the one place that calls rclpy's
``handle.take_message`` (the binding its executors call; ``rclpy.wait_for_message`` too).

* ``take(sub)`` -> the next message waiting (decoded, or its bytes if ``sub.raw``), None if none;
* ``take_all(sub, limit)`` -> every message waiting, oldest first (at most ``limit``);
* ``take_newest(sub, limit)`` -> (the newest message's bytes or None, how many were waiting): the
  older ones dropped undecoded.

Each take holds the handle (``with sub.handle``, as the executor does), so a subscription being
destroyed is not taken from. A failed take raises (rclpy's RCLError); the caller says so and goes
on. Who takes this way, and why (a callback through rclpy's executor costs its wake-up over every
entity of the node, about 0.1-1 ms on this class of machine, docs/fleet.md):

* ``ros_io.direct_take``: a filter's pose, detections and command on a thread of their own
  (bench/results/take.md: the filter's CPU per decision 1.25-1.88 against 1.67-2.30 ms);
* the filter node deciding on ticks (a fleet): each tick takes the newest sample of every robot's
  pose, detections and command, every range-sensor message and every batched message waiting,
  from subscriptions of a node that is never spun (60 robots x 3 topics at 50 Hz would be 9,000
  callbacks a second; bench/bench_headroom.py prints the tick's figures);
* learner_node: the interventions and markers that wait, taken together before it fits
  (a fit answers every intervention that came with it).
"""
from __future__ import annotations


def take(sub):
    """The next message waiting on ``sub`` (decoded, or serialized if ``sub.raw``), None if none."""
    with sub.handle:
        got = sub.handle.take_message(sub.msg_type, sub.raw)
    return None if got is None else got[0]


def take_all(sub, limit: int = 1_000_000) -> list:
    """Every message waiting on ``sub``, oldest first (at most ``limit``: the rest wait)."""
    out = []
    with sub.handle:
        handle, msg_type, raw = sub.handle, sub.msg_type, sub.raw
        while len(out) < limit:
            got = handle.take_message(msg_type, raw)
            if got is None:
                break
            out.append(got[0])
    return out


def take_newest(sub, limit: int = 1_000_000):
    """(the newest message waiting on ``sub``, serialized, or None; how many were waiting, at most
    ``limit``): the older ones are dropped undecoded (the caller decodes the newest)."""
    newest, count = None, 0
    with sub.handle:
        handle, msg_type = sub.handle, sub.msg_type
        while count < limit:
            got = handle.take_message(msg_type, True)
            if got is None:
                break
            newest, count = got[0], count + 1
    return newest, count
