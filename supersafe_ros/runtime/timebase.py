"""The filter's time base: ages that stay honest whatever ``use_sim_time`` says.

The filter judges staleness (pose, detections, planner command) as ``t - arrival``
on one clock. Which clock?

* Wall time (``use_sim_time`` false): the steady clock. It never jumps (NTP, a
  user setting the date), unlike the ROS system clock.
* Sim time: a lockstepped simulation may run slower or faster than real time
  (``rate_factor`` 0 = as fast as it can), so a pose one sim step old may be 5 s old
  on the wall (a slow sim) or 1 ms old (a fast one): ages must be in sim time. But
  with ``use_sim_time`` and no ``/clock`` (or a ``/clock`` that stopped) ROS time
  stands still, every age stays 0, and a stale pose would never be detected.

``FilterTime`` is a virtual clock tau built from both: it advances with ROS time
while ROS time advances, and with the steady clock once ROS time has stood still
for longer than ``stall_timeout`` steady seconds (counted from when it last moved,
so a stall counts in full). So:

* sim running at any rate: tau = sim time, ages are sim ages;
* no /clock at all (ROS time 0): tau follows the steady clock, an input that stopped
  is stale ``timeout`` wall seconds after its last arrival;
* /clock stopped: tau follows the wall from the stall's start once the stall is
  seen, so an input that stopped is stale ``max(timeout, stall_timeout)`` wall
  seconds after its last arrival;
* wall mode (``sim=False``): tau = the steady clock.

A sim slower than one step per ``stall_timeout`` wall seconds looks stopped
between its steps (set ``stall_timeout`` above its wall step). ROS time jumping
backwards (a simulator reset) is ignored: tau only moves forwards.

Pose stamps are on the ROS clock; ``stamp_to_tau`` maps one onto tau by its age
at arrival, so the filter can propagate a pose from the time it describes.
"""
from __future__ import annotations

import math


class FilterTime:
    """Virtual clock tau (seconds) from ROS-clock and steady-clock readings."""

    def __init__(self, sim: bool, stall_timeout: float = 1.0):
        if not (math.isfinite(stall_timeout) and stall_timeout > 0):
            raise ValueError(f'stall_timeout must be finite and > 0, got {stall_timeout}')
        self.sim = bool(sim)
        self.stall_timeout = float(stall_timeout)
        self._tau = 0.0
        self._ros = None            # last ROS time seen [s]
        self._steady = None         # steady time of the last reading [s]
        self._moved_steady = None   # steady time ROS time last moved
        self._moved_tau = 0.0       # tau then
        self.stalled = False

    def now(self, ros_s: float, steady_s: float) -> float:
        """tau at this reading of both clocks (call it with the current readings)."""
        if self._steady is None:
            self._ros, self._steady, self._moved_steady, self._moved_tau = ros_s, steady_s, steady_s, 0.0
            return self._tau
        if not self.sim:
            self._tau += max(0.0, steady_s - self._steady)
            self._steady = steady_s
            return self._tau
        if ros_s > self._ros:
            if self.stalled:
                self.stalled = False      # tau already followed the wall: resume from there
            else:
                self._tau += ros_s - self._ros
            self._ros, self._moved_steady, self._moved_tau = ros_s, steady_s, self._tau
        elif ros_s < self._ros:
            self._ros = ros_s             # time went back (reset): continue from the new value
        else:
            stalled_for = steady_s - self._moved_steady
            # ROS time 0 = no /clock received at all: no clock to wait for
            if stalled_for > self.stall_timeout or ros_s == 0.0:
                self.stalled = True
                self._tau = max(self._tau, self._moved_tau + stalled_for)
        self._steady = steady_s
        return self._tau

    def stamp_to_tau(self, stamp_s: float, ros_s: float, tau: float) -> float | None:
        """A ROS-clock stamp on tau (None when unstamped or ROS time is not usable for ages)."""
        if stamp_s <= 0.0 or not math.isfinite(stamp_s) or self.stalled or ros_s <= 0.0:
            return None
        return tau - max(0.0, ros_s - stamp_s)
