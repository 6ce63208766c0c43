"""Subscriptions served by a thread of their own, off the node's executor.

rclpy's executors rebuild their wait set over every entity of their nodes on each wake-up
(the parameter services, timers, guard conditions, all subscriptions): about 0.3 ms on this
class of machine before a callback runs. ``DirectTake`` keeps a few latency-critical
subscriptions out of that: they live on a helper node (``<name>_io``, in the same namespace,
without parameter services) that the node's executor never sees, served by a thread of
their own that calls the callback under ``lock``. The node's executor keeps everything
else; callbacks that share state with these take the same lock.

The helper ignores the process's global ROS arguments (a ``__node:=`` remap would give it
the owner's name; ``use_sim_time`` would give it a /clock subscription it never reads): it
subscribes to the names the owner resolves, so the owner's remaps apply.

Two ways to serve them (``path``; the filter nodes' read-only parameter ``take_path``):

* ``'public'``: rclpy's public API only: the helper node is spun by a
  ``SingleThreadedExecutor`` of its own in its own thread. This is the fallback.
* ``'private'`` (the filter nodes' default): the thread waits on an rcl wait set holding only
  these subscriptions and a stop guard and takes what is ready; the wait set is rclpy's
  private binding ``_rclpy.WaitSet`` (the one ``rclpy.wait_for_message`` uses; this module
  is the one place that touches it). A raw subscription added with ``gil_free=True`` (the
  value function) is taken by rcl through ctypes with the GIL released
  (``ros_io.gil_free_take``) and handed over as a numpy uint8 array, so that a 50 MB message
  does not stop the process's other threads while it is copied (rclpy's take holds the GIL
  for the whole copy; such a subscription gets a DirectTake of its own, ``suffix``).

Why the private path is kept (``bench/bench_take.py``, bench/results/take.md, 2026-12-03,
26 alternating pairs of safety_filter_node processes on 2 shared cores, load 1-22, half
of them beside two CPU burners): the filter's CPU per decision 1.25-1.88 ms against
1.67-2.30 ms (lower in 25 of 26 pairs; one private run 2.75 ms), and the longest cmd_vel
gap while a 50 MB value function arrives lower in 24 of 26 (52-103 against 115-179 ms on
the quietest round). The pose -> cmd_vel median was lower in 19 of 26, the p99 in only 16
of 26 (none of the 3 beside burners in the last, most loaded run): no clear win there.
The gap is the GIL-free take's: a thread of the process stalled 5-56 ms while 50 MB were
taken without the GIL, 129-1,793 ms while rclpy took them, from the private wait set or
the public executor alike (22 rounds each).

The public path is the fallback: ``'private'`` turns into ``'public'`` with a WARN when
rclpy has no ``_rclpy.WaitSet``, the wait set cannot be made, or ctypes cannot reach rcl
(test/test_ros_io_direct_take.py forces each; the filter's topic-level tests run the
filter through the first).
"""
from __future__ import annotations

from contextlib import ExitStack
import threading
import time
import traceback

from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node

from .take import take

TAKE_PATHS = ('private', 'public')


class DirectTake:
    """``add(msg_type, topic, callback, qos, raw)`` subscriptions (before ``start()``), served
    until ``close()`` or the context's shutdown, on ``path`` (``'private'`` or ``'public'``,
    see the module; ``self.path`` says which one serves them after a fallback). A callback
    that raises is logged (with its traceback, once per kind of error) and the thread goes
    on; if the waiting itself fails the thread says so and ends (the owner's inputs then go
    stale: its watchdog fails safe)."""

    def __init__(self, node: Node, lock, suffix: str = '_io', path: str = 'private', io: Node | None = None):
        if path not in TAKE_PATHS:
            raise ValueError(f'take path must be one of {", ".join(TAKE_PATHS)}, got {path!r}')
        self.node = node
        self.lock = lock
        self.path = path
        # the helper node: ``io`` if given (its owner destroys it), else one of its own
        self._owns_io = io is None
        self.io = io if io is not None else helper_node(node, suffix)
        self._subs = []                      # (subscription, callback)
        self._gil_free = {}                  # subscription -> GilFreeTaker (private path)
        self._stop = self.io.create_guard_condition(lambda: None)
        self._wait_set = None
        self._executor = None
        self._closing = False
        self._closed = False
        self._started = False
        self._thread = None
        self._errors = set()
        self.taken = 0
        self._tick = None                    # (period s, callback): a watchdog served by this thread (``tick``)
        self._tick_timer = None
        if path == 'private' and not hasattr(_rclpy, 'WaitSet'):
            self._fall_back('rclpy has no _rclpy.WaitSet')
        node.context.on_shutdown(self._on_shutdown)

    def _fall_back(self, why: str):
        self.path = 'public'
        self.node.get_logger().warn(f'{self.io.get_name()}: the private take path is not usable ({why}); its '
                                    'inputs are taken on the public path (a SingleThreadedExecutor of their own)')

    def add(self, msg_type, topic, callback, qos, raw=False, gil_free=False):
        """Subscribe to ``topic`` as the owner resolves it (its namespace and remaps);
        ``gil_free`` (with ``raw``, on the private path): taken without the GIL, as a numpy
        uint8 array (else as bytes)."""
        if self._started:
            raise RuntimeError('DirectTake.add after start: the wait set is sized at start')
        name = self.node.resolve_topic_name(topic)
        # the public path's executor calls this callback; the private path calls _deliver itself
        sub = self.io.create_subscription(msg_type, name, lambda msg: self._deliver(name, callback, msg),
                                          qos, raw=raw)
        self._subs.append((sub, callback))
        if gil_free and raw and self.path == 'private':
            from .gil_free_take import GilFreeTaker
            try:
                self._gil_free[sub] = GilFreeTaker()
            except (OSError, AttributeError) as exc:
                self._fall_back(f'rcl not reachable through ctypes: {exc}')
        return sub

    def tick(self, period: float, callback) -> None:
        """Call ``callback()`` every ``period`` steady seconds on this thread too, under the lock, between
        takes (a node's watchdog, off its executor: an executor wake costs ~0.3 ms before its callback
        runs; served by the private path's wait timeouts, or a steady timer of the helper node on the
        public path). Again with a new period: that one from now on."""
        self._tick = (float(period), callback)
        self._next_tick = time.monotonic() + float(period)
        if self._tick_timer is not None:
            self.io.destroy_timer(self._tick_timer)
            self._tick_timer = None
        if self.path == 'public':
            from rclpy.clock import Clock, ClockType
            self._tick_timer = self.io.create_timer(float(period), lambda: self._deliver('tick', callback, None,
                                                                                         call=True),
                                                    clock=Clock(clock_type=ClockType.STEADY_TIME))

    def start(self):
        self._started = True
        if self.path == 'private':
            try:
                with self.io.context.handle:
                    self._wait_set = _rclpy.WaitSet(len(self._subs), 1, 0, 0, 0, 0, self.io.context.handle)
            except Exception as exc:   # noqa: BLE001  a private binding that changed: the public path
                self._fall_back(f'no rcl wait set: {type(exc).__name__}: {exc}')
        if self.path == 'public':
            if self._tick is not None and self._tick_timer is None:      # (a fall back after tick())
                self.tick(*self._tick)
            self._executor = SingleThreadedExecutor(context=self.io.context)
            self._executor.add_node(self.io)
            run = self._spin
        else:
            run = self._run
        self._thread = threading.Thread(target=run, name=f'{self.io.get_name()}_take', daemon=True)
        self._thread.start()

    def _spin(self):
        """The public path: the helper node's own executor."""
        try:
            while not self._closing and self.io.context.ok():
                self._executor.spin_once()
        except Exception:   # noqa: BLE001  the context going away, or rcl failing: say so and end
            if not self._closing and self.io.context.ok():
                self._failed()

    def _run(self):
        """The private path: a wait set of the subscriptions alone."""
        subs, wait_set = self._subs, self._wait_set
        try:
            with ExitStack() as handles:     # kept alive while waited on (as rclpy's executor does)
                handles.enter_context(self.io.context.handle)
                for sub, _ in subs:
                    handles.enter_context(sub.handle)
                handles.enter_context(self._stop.handle)
                while not self._closing:
                    wait_set.clear_entities()
                    for sub, _ in subs:
                        wait_set.add_subscription(sub.handle)
                    wait_set.add_guard_condition(self._stop.handle)
                    tick = self._tick
                    if tick is None:
                        wait_set.wait(-1)
                    else:
                        wait_set.wait(max(0, int((self._next_tick - time.monotonic()) * 1e9)))
                    if self._closing:
                        return
                    ready = wait_set.get_ready_entities('subscription')
                    for sub, callback in subs:
                        if sub.handle.pointer in ready:
                            self._take(sub, callback)
                    if tick is not None:
                        now = time.monotonic()
                        if now >= self._next_tick:
                            # the next tick a period on; after a long stall, a period from now (no burst)
                            self._next_tick = (self._next_tick + tick[0] if now - self._next_tick < tick[0]
                                               else now + tick[0])
                            self._deliver('tick', tick[1], None, call=True)
        except Exception:   # noqa: BLE001  the context going away, or rcl failing: say so and end
            if not self._closing:
                self._failed()

    def _failed(self):
        self.node.get_logger().error(f'{self.io.get_name()}: taking inputs failed; they are no longer '
                                     f'taken (the watchdog fails safe on them): {traceback.format_exc()}')

    def _take(self, sub, callback):
        taker = self._gil_free.get(sub)
        try:
            if taker is not None:
                message = taker.take(sub)
            else:
                message = take(sub)
        except (RuntimeError, MemoryError) as exc:    # rcl failed to take: nothing was taken
            self._said(sub.topic_name, exc, 'take failed')
            return
        if message is not None:
            self._deliver(sub.topic_name, callback, message)

    def _deliver(self, topic, callback, message, call=False):
        if not call:
            self.taken += 1
        try:
            with self.lock:
                callback() if call else callback(message)
        except Exception as exc:   # noqa: BLE001  keep serving: the watchdog still stands
            self._said(topic, exc, 'callback failed')

    def _said(self, topic, exc, what):
        kind = (topic, what, type(exc).__name__)
        if kind not in self._errors:
            self._errors.add(kind)
            self.node.get_logger().error(f'{topic} {what} (said once per kind): {traceback.format_exc()}')

    def _on_shutdown(self):
        self._closing = True
        try:
            self._stop.trigger()
        except Exception:   # noqa: BLE001  already destroyed
            pass

    def close(self):
        """Stop the thread (it finishes the callback it is in) and destroy the helper node (its own), or
        what it made on the one it was given."""
        if self._closed:
            return
        self._closed = self._closing = True
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stop.trigger()           # wakes either path's wait
            thread.join(timeout=5.0)
            if thread.is_alive():      # a callback stuck: leave its handles alone
                self.node.get_logger().error(f'{self.io.get_name()}: input thread still busy after 5 s; '
                                             'helper node left in place')
                return
        if self._executor is not None:
            try:
                self._executor.shutdown(timeout_sec=1.0)
            except Exception:   # noqa: BLE001  the context is gone already: nothing left to stop
                pass
        if self._owns_io:
            self.io.destroy_node()
        else:
            for sub, _ in self._subs:
                self.io.destroy_subscription(sub)
            self.io.destroy_guard_condition(self._stop)
            if self._tick_timer is not None:
                self.io.destroy_timer(self._tick_timer)


def helper_node(node: Node, suffix: str = '_io') -> Node:
    """A helper node beside ``node`` (``<name><suffix>``, its namespace, no parameter services) that
    ignores the process's global ROS arguments (a ``__node:=`` remap would give it the owner's name;
    ``use_sim_time`` a /clock subscription it never reads): it takes the names the owner resolves."""
    return Node(f'{node.get_name()}{suffix}', namespace=node.get_namespace(), context=node.context,
                start_parameter_services=False, use_global_arguments=False)
