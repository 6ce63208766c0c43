"""Subscriptions served by a thread of their own, off the executor.

rclpy's executors rebuild their wait set over every entity of their nodes on each wake-up
(the parameter services, timers, guard conditions, all subscriptions): about 0.3 ms on this
class of machine before a callback runs. ``DirectTake`` keeps a few latency-critical
subscriptions out of that: they live on a helper node that is never added to an executor
(``<name>_io``, in the same namespace, without parameter services), and a thread waits on an
rcl wait set holding only them and a stop guard, takes what is ready, and calls the callback
under ``lock``. The node's executor keeps everything else; callbacks that share state with
these take the same lock.

The helper ignores the process's global ROS arguments (a ``__node:=`` remap would give it
the owner's name; ``use_sim_time`` would give it a /clock subscription it never reads): it
subscribes to the names the owner resolves, so the owner's remaps apply.

``rclpy.wait_for_message`` waits on such a wait set the same way (the ``_rclpy.WaitSet`` it
uses is rclpy's own binding, not public API: this module is the one place that touches it).

``add(..., gil_free=True)`` (raw subscriptions): the message is taken by rcl through ctypes
with the GIL released (``ros_io.gil_free_take``) and handed over as a numpy uint8 array,
so that a large message (a 50 MB value function) does not stop the process's other
threads while it is copied; rclpy's take holds the GIL for the whole copy. Such a
subscription gets a DirectTake of its own (``suffix``), so its copy never delays the
others.
"""
from __future__ import annotations

from contextlib import ExitStack
import threading
import traceback

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node


class DirectTake:
    """``add(msg_type, topic, callback, qos, raw)`` subscriptions (before ``start()``), served
    until ``close()`` or the context's shutdown. A callback that raises is logged (with its
    traceback, once per kind of error) and the thread goes on; if the waiting itself fails
    the thread says so and ends (the owner's inputs then go stale: its watchdog fails safe)."""

    def __init__(self, node: Node, lock, suffix: str = '_io'):
        self.node = node
        self.lock = lock
        self.io = Node(f'{node.get_name()}{suffix}', namespace=node.get_namespace(), context=node.context,
                       start_parameter_services=False, use_global_arguments=False)
        self._subs = []                      # (subscription, callback)
        self._gil_free = {}                  # subscription -> GilFreeTaker (or None: rclpy takes)
        self._stop = self.io.create_guard_condition(lambda: None)
        self._closing = False
        self._closed = False
        self._started = False
        self._thread = None
        self._errors = set()
        self.taken = 0
        node.context.on_shutdown(self._on_shutdown)

    def add(self, msg_type, topic, callback, qos, raw=False, gil_free=False):
        """Subscribe to ``topic`` as the owner resolves it (its namespace and remaps);
        ``gil_free`` (with ``raw``): taken without the GIL, as a numpy uint8 array."""
        if self._started:
            raise RuntimeError('DirectTake.add after start: the wait set is sized at start')
        sub = self.io.create_subscription(msg_type, self.node.resolve_topic_name(topic), lambda msg: None,
                                          qos, raw=raw)
        self._subs.append((sub, callback))
        if gil_free and raw:
            from .gil_free_take import GilFreeTaker
            try:
                self._gil_free[sub] = GilFreeTaker()
            except (OSError, AttributeError) as exc:
                self.node.get_logger().warn(f'{sub.topic_name}: rcl not reachable through ctypes ({exc}); '
                                            'rclpy takes it (holding the GIL while it copies)')
        return sub

    def start(self):
        self._started = True
        self._thread = threading.Thread(target=self._run, name=f'{self.io.get_name()}_take', daemon=True)
        self._thread.start()

    def _run(self):
        subs = self._subs
        try:
            with ExitStack() as handles:     # kept alive while waited on (as rclpy's executor does)
                handles.enter_context(self.io.context.handle)
                for sub, _ in subs:
                    handles.enter_context(sub.handle)
                handles.enter_context(self._stop.handle)
                wait_set = _rclpy.WaitSet(len(subs), 1, 0, 0, 0, 0, self.io.context.handle)
                while not self._closing:
                    wait_set.clear_entities()
                    for sub, _ in subs:
                        wait_set.add_subscription(sub.handle)
                    wait_set.add_guard_condition(self._stop.handle)
                    wait_set.wait(-1)
                    if self._closing:
                        return
                    ready = wait_set.get_ready_entities('subscription')
                    for sub, callback in subs:
                        if sub.handle.pointer in ready:
                            self._take(sub, callback)
        except Exception:   # noqa: BLE001  the context going away, or rcl failing: say so and end
            if not self._closing:
                self.node.get_logger().error(f'{self.io.get_name()}: taking inputs failed; they are no longer '
                                             f'taken (the watchdog fails safe on them): {traceback.format_exc()}')

    def _take(self, sub, callback):
        taker = self._gil_free.get(sub)
        try:
            if taker is not None:
                message = taker.take(sub)
            else:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
                message = None if taken is None else taken[0]
        except (RuntimeError, MemoryError) as exc:    # rcl failed to take: nothing was taken
            self._said(sub, exc, 'take failed')
            return
        if message is None:
            return
        self.taken += 1
        try:
            with self.lock:
                callback(message)
        except Exception as exc:   # noqa: BLE001  keep serving: the watchdog still stands
            self._said(sub, exc, 'callback failed')

    def _said(self, sub, exc, what):
        kind = (sub.topic_name, what, type(exc).__name__)
        if kind not in self._errors:
            self._errors.add(kind)
            self.node.get_logger().error(f'{sub.topic_name} {what} (said once per kind): '
                                         f'{traceback.format_exc()}')

    def _on_shutdown(self):
        self._closing = True
        try:
            self._stop.trigger()
        except Exception:   # noqa: BLE001  already destroyed
            pass

    def close(self):
        """Stop the thread (it finishes the callback it is in) and destroy the helper node."""
        if self._closed:
            return
        self._closed = self._closing = True
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stop.trigger()
            thread.join(timeout=5.0)
            if thread.is_alive():      # a callback stuck: leave its handles alone
                self.node.get_logger().error(f'{self.io.get_name()}: input thread still busy after 5 s; '
                                             'helper node left in place')
                return
        self.io.destroy_node()
