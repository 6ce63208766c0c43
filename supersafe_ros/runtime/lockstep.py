"""When the filter of a lockstepped robot answers a pose: now, later, or not at all.

A lockstepped robot (under sim_clock_node) acknowledges its step on the first
command that arrives after its pose, and the clock then advances. So the filter
answers each pose once, on that pose (docs/graph_safety.md), and ``LockstepAnswers``
decides, from times and what the filter reported, what happens to that answer:

* a pose the clock has already passed is skipped (``clock_passed``): its step went
  on without this answer, and answering it would acknowledge the robot's newer step
  with a decision on the older pose;
* while a cluster near the robot is being solved (``FilterOutput.clusters_solving``)
  the answer is held (``judge`` says HOLD; the watchdog decides again at the held
  pose's time, ``held_pose_time``), so sim time waits for the union value; it goes
  out once no cluster is solving, or after ``hold_timeout`` steady seconds with the
  fallback (GIVE_UP). After a hold that timed out there is no other hold until
  nothing is solving, so a stuck solver cannot stall every step;
* the watchdog keeps quiet for ``silence`` steady seconds after a pose (``quiet``):
  the pose's answer is the robot's command.

No ROS here: the node passes the times in (steady seconds, filter time, nanoseconds).
"""
from __future__ import annotations

from dataclasses import dataclass

ANSWER = 'answer'      # publish the decision now
HOLD = 'hold'          # keep it back: the watchdog decides again at the held pose's time
GIVE_UP = 'give_up'    # publish it now, with the fallback: the hold timed out


@dataclass(frozen=True)
class Verdict:
    """What to do with a decision, and why."""

    action: str                       # ANSWER | HOLD | GIVE_UP
    why: str
    held_for: float | None = None     # steady seconds a held answer waited (when it goes out)

    @property
    def publish(self) -> bool:
        return self.action != HOLD


class LockstepAnswers:
    """The answering rules of one lockstepped filter (one robot), with their statistics."""

    def __init__(self, hold_timeout: float, silence: float, now: float):
        self.hold_timeout = float(hold_timeout)   # 0 = never hold (the fallback acts)
        self.silence = float(silence)
        self.holds = 0               # answers held for a cluster solve
        self.poses_skipped = 0       # poses the clock had passed (not answered)
        self._last_pose = now        # steady seconds
        self._held = None            # (filter time, steady time held since) of the held answer
        self._spent = False          # a hold timed out: no other hold until nothing is solving

    # -- poses ------------------------------------------------------------------------------
    def new_pose(self, now: float) -> None:
        """A pose arrived at steady time ``now``: a held answer to an older pose is dropped."""
        self._last_pose = now
        self._held = None

    def clock_passed(self, stamp_ns: int, clock_ns: int | None) -> bool:
        """True (and counted) if /clock (``clock_ns``; None with wall time) is already past
        the pose stamped ``stamp_ns``. The clock cannot pass a step before the robot
        acknowledges it, so such a pose was acknowledged without this filter's answer (a
        parked or timed-out robot acknowledges by itself; so does a reply to an older pose)
        and the robot is already at a newer pose, queued behind this one. Unstamped poses
        and wall time are always answered."""
        if clock_ns is None or stamp_ns <= 0 or stamp_ns >= clock_ns:
            return False
        self.poses_skipped += 1
        return True

    # -- the watchdog -----------------------------------------------------------------------
    @property
    def held_pose_time(self) -> float | None:
        """The filter time of the pose whose answer is held (None: none held)."""
        return None if self._held is None else self._held[0]

    def quiet(self, now: float) -> bool:
        """The watchdog must not command: a pose came less than ``silence`` ago."""
        return now - self._last_pose < self.silence

    # -- the decision -------------------------------------------------------------------------
    def judge(self, t: float, now: float, clusters_solving: int, answers_pose: bool) -> Verdict:
        """What to do with a decision made at filter time ``t`` (steady time ``now``) while
        ``clusters_solving`` clusters near the robot are being solved. ``answers_pose``:
        it is the answer to a pose just taken (only those are held); a held answer's
        decision again is judged as such whatever it says."""
        if not clusters_solving:
            self._spent = False
            if self._held is not None:
                since, self._held = self._held[1], None
                return Verdict(ANSWER, 'the cluster value is in force', held_for=now - since)
            return Verdict(ANSWER, 'no cluster is being solved')
        if self._held is not None:
            since = self._held[1]
            if now - since < self.hold_timeout:
                self._held = (t, since)
                return Verdict(HOLD, 'a cluster near the robot is still being solved')
            # one hold per solve: a solve this slow must not stall every step after it
            self._spent, self._held = True, None
            return Verdict(GIVE_UP, f'a cluster value still solving after {self.hold_timeout:g} s',
                           held_for=now - since)
        if not answers_pose:
            return Verdict(ANSWER, 'not the answer to a pose: never held')
        if not self.hold_timeout > 0.0:
            return Verdict(ANSWER, 'holding is off (hold timeout 0)')
        if self._spent:
            return Verdict(ANSWER, 'a hold already timed out while this solve runs')
        self.holds += 1
        self._held = (t, now)
        return Verdict(HOLD, 'a cluster near the robot is being solved')
