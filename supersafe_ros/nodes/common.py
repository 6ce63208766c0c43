"""Shared main() plumbing for the node executables.

``run_node(NodeClass, args)`` keeps DDS on loopback (before rclpy.init), builds
the node, spins it, and stops quietly on Ctrl-C or SIGTERM (``StopSignals``: the
spin ends before the context is shut down). It returns a process exit code: 0 on
a clean stop, 1 if the node failed to start.

Parameters: ``declare`` (one, with its descriptor), ``ParameterSpec`` and
``declare_all`` (a node's table of them), ``LiveParameters`` (those that change at
run time).
"""
from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass
import gc
import os
import signal
import sys
import threading
import traceback

from ..rosenv import ensure_local_ros_env


def make_executor(kind: str | None = None):
    """The executor a node process spins: $SUPERSAFE_EXECUTOR = 'events' or 'single'.

    'single' (default) is rclpy's SingleThreadedExecutor. 'events' is the experimental
    C++ EventsExecutor; in this rclpy (7.1.6) it spins a whole core per process with
    use_sim_time and its timers do not follow /clock, so it is opt-in only.
    """
    from rclpy.executors import SingleThreadedExecutor
    kind = (kind or os.environ.get('SUPERSAFE_EXECUTOR', 'single')).lower()
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor()
        except (ImportError, AttributeError):
            pass
    return SingleThreadedExecutor()


class StopSignals:
    """SIGINT and SIGTERM turned into an orderly stop instead of an interruption.

    rclpy's own handlers shut the context down the moment the signal lands, while a
    callback or a node's thread may still be publishing: that is what printed
    ``RCLError: ... context is invalid`` tracebacks on Ctrl-C. Here Python's handler
    only raises KeyboardInterrupt while the node is still being built (a slow
    constructor stops where it is); once the node spins, the signal (whichever thread
    the OS gave it to) wakes a thread through ``signal.set_wakeup_fd``, which calls
    ``on_stop`` (a guard condition that ends the spin loop), so the node is closed and
    destroyed while the context is still valid. Handlers are installed even where the
    signal was ignored (background jobs of a shell ignore SIGINT).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.requested = threading.Event()
        self.state = 'constructing'          # -> 'spinning' -> 'stopping'
        self.on_stop = None
        self._lock = threading.Lock()
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        for s in self.SIGNALS:
            signal.signal(s, self._handler)
        threading.Thread(target=self._wait, args=(read_fd,), name='stop_signals',
                         daemon=True).start()

    def _handler(self, signum, frame):      # main thread, between bytecodes
        self.requested.set()
        if self.state == 'constructing':
            self.state = 'interrupted'          # once: a second signal must not interrupt the clean-up
            raise KeyboardInterrupt

    def _wait(self, read_fd):
        while os.read(read_fd, 64):
            self.requested.set()
            with self._lock:
                on_stop = self.on_stop if self.state == 'spinning' else None
            if on_stop is not None:
                on_stop()

    def spinning(self, on_stop) -> bool:
        """Hand over to the spin loop; False if a stop was asked for already."""
        with self._lock:
            self.on_stop = on_stop
            self.state = 'spinning'
        return not self.requested.is_set()

    def stopping(self):
        """The stop is under way (main thread): further SIGINT/SIGTERM are ignored from here on.
        A terminal's Ctrl-C reaches every process of the group and ``ros2 launch`` then signals
        each node again; Python restores the default handlers while it finalizes, so a second
        signal there killed the node (exit code -2, "process has died") after a clean stop.
        Ignored signals stay ignored through finalization; a stop that hangs is left to the
        caller's SIGKILL."""
        with self._lock:
            self.state = 'stopping'
        for s in self.SIGNALS:
            signal.signal(s, signal.SIG_IGN)


def freeze_startup_objects() -> None:
    """Move what starting made (the node, its value functions, its robots' filters), which
    lives as long as the process, out of the garbage collector's generations: a collection
    then scans only what the run allocates (about 1 ms a tick for the 1,000-robot fleet)."""
    gc.freeze()


def run_node(node_class, args=None, executor_class=None) -> int:
    """Run one node until SIGINT/SIGTERM; ``args`` are the process argv (incl. --ros-args).

    The stop is orderly and quiet: the spin loop ends, then the node's ``close()`` (its own
    threads and timers), ``destroy_node()`` and the context's shutdown, in that order, so
    nothing publishes or logs into a context that is gone. Exit code 0 on a stop asked for,
    1 if the node failed to start or crashed (with the traceback on stderr).

    A node that ends by itself (sim_clock at its duration, with ``exit_at_duration``) sets
    ``node.stop_requested`` and then calls ``node.stop_process()`` if it is set; it is set
    here (and called at once when the flag is up already): the same orderly stop.
    """
    ensure_local_ros_env()
    import rclpy
    import rclpy.executors
    from rclpy.signals import SignalHandlerOptions

    from . import stop_requested_while_importing
    argv = sys.argv if args is None else args
    signals = StopSignals() if threading.current_thread() is threading.main_thread() else None
    if stop_requested_while_importing.is_set():
        return 0          # stopped while importing, and the SystemExit was swallowed
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    code = 0
    stopping = threading.Event()
    try:
        node = node_class()
        freeze_startup_objects()
        executor = executor_class() if executor_class else make_executor()
        executor.add_node(node)
        if isinstance(executor, rclpy.executors.Executor):
            on_stop, poll = node.create_guard_condition(stopping.set).trigger, None
        else:   # the EventsExecutor takes no guard conditions: the loop looks for the stop 10 times a second
            on_stop, poll = stopping.set, 0.1
        node.stop_process = on_stop
        if getattr(node, 'stop_requested', False):
            on_stop()         # the node ended by itself before the hook was set
        if signals is None or signals.spinning(on_stop):
            while not stopping.is_set() and rclpy.ok():
                executor.spin_once(timeout_sec=poll)
    except KeyboardInterrupt:
        pass
    except Exception:  # a node that cannot start or crashes: say why, exit non-zero
        traceback.print_exc()
        code = 1
    finally:
        if signals is not None:
            signals.stopping()
        if node is not None:
            try:
                close = getattr(node, 'close', None)
                if close is not None:
                    close()
                node.destroy_node()
            except Exception:
                traceback.print_exc()
                code = code or 1
        rclpy.try_shutdown()
    return code


def declare(node, name, default, description, lo=None, hi=None, step=0, read_only=False):
    """Declare a parameter with a descriptor (description and range) and return its value.

    Floats get a FloatingPointRange, ints an IntegerRange when ``lo``/``hi`` are given.
    """
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
    desc = ParameterDescriptor(description=description, read_only=read_only)
    if lo is not None and hi is not None:
        if isinstance(default, bool):
            pass
        elif isinstance(default, int):
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=int(step))]
        elif isinstance(default, float):
            desc.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi),
                                                            step=float(step))]
    if node.has_parameter(name):     # a managed node configured again: the value in force
        return node.get_parameter(name).value
    return node.declare_parameter(name, default, desc).value


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter of a node: its default, description and range in one row of a table.

    ``live``: it takes effect when set at run time (the node registers it with
    ``LiveParameters``); otherwise it is declared ``read_only``.
    """

    name: str
    default: object
    description: str
    lo: float | None = None
    hi: float | None = None
    live: bool = False


def declare_all(node, specs) -> dict:
    """Declare every ``ParameterSpec`` of ``specs`` (``declare``), in order; name -> value."""
    return {s.name: declare(node, s.name, s.default, s.description, s.lo, s.hi, read_only=not s.live)
            for s in specs}


class StepAcknowledger:
    """For nodes that judge every robot pose (world, supervisor) under a lockstep clock:
    publishes on ``~/step_done`` the newest sim time up to which the poses of every
    robot have been processed (see sim_clock_node's ``observers``).

    Before that it announces readiness with 0 once every subscription passed to
    ``watch`` has a matched publisher (and ``also_ready()``, if given, is true), so the
    clock does not step while a robot's first poses could still miss this node."""

    def __init__(self, node, robots, also_ready=None):
        from rclpy.clock import Clock as RosClock, ClockType
        from rosgraph_msgs.msg import Clock
        from ..ros_io import rosmsg
        self._also_ready = also_ready        # a further condition of readiness (callable)
        self._clock_type = Clock
        self.latest = {r: -1 for r in robots}
        self.sent = -1
        self.watched = []
        self.pub = node.create_publisher(Clock, '~/step_done', rosmsg.QOS_ACK)
        self._ready_timer = node.create_timer(0.05, self._check_ready,
                                              clock=RosClock(clock_type=ClockType.STEADY_TIME))

    def watch(self, *subscriptions) -> None:
        self.watched.extend(subscriptions)

    def _check_ready(self):
        if all(s.get_publisher_count() > 0 for s in self.watched) and (
                self._also_ready is None or self._also_ready()):
            self._ready_timer.cancel()
            if self.sent < 0:
                self.sent = 0
                self.pub.publish(self._clock_type())

    def processed(self, robot, stamp):
        """Record that ``robot``'s pose stamped ``stamp`` (builtin Time) is dealt with;
        returns (previous, new) acknowledged time in ns when it advanced, else None."""
        t = stamp.sec * 1_000_000_000 + stamp.nanosec
        if t > self.latest.get(robot, t):
            self.latest[robot] = t
        done = min(self.latest.values())
        if done > self.sent:
            before, self.sent = self.sent, done
            msg = self._clock_type()
            msg.clock.sec, msg.clock.nanosec = divmod(done, 1_000_000_000)
            self.pub.publish(msg)
            return before, done
        return None


class LiveParameters:
    """Parameters that take effect when changed at run time (``ros2 param set``).

    ``add(name, apply, check=None)``: ``check(value)`` returns a reason string to refuse
    the value (None to accept); ``apply(value)`` puts it into force. rclpy itself
    enforces the descriptor's type, range and ``read_only`` before this runs. A set of
    several parameters is all-or-nothing: every check runs before any apply. Declare every
    parameter that is not registered here ``read_only=True``, so that a set never answers
    "successful" without effect. ``after(names)``, if given, runs once per accepted set,
    after every apply (e.g. to rebuild something that depends on several parameters).
    """

    def __init__(self, node, after=None, lock=None):
        self._node = node
        self._entries = {}
        self._after = after
        # applied under it (a node whose callbacks run on several threads)
        self._lock = lock if lock is not None else nullcontext()
        node.add_on_set_parameters_callback(self._on_set)
        self._registered = True

    def close(self) -> None:
        """No longer applied (a managed node cleaned up)."""
        if self._registered:
            self._node.remove_on_set_parameters_callback(self._on_set)
            self._registered = False

    def add(self, name, apply, check=None) -> None:
        self._entries[name] = (apply, check)

    @property
    def names(self) -> set:
        return set(self._entries)

    def _on_set(self, params):
        from rcl_interfaces.msg import SetParametersResult
        ours = [p for p in params if p.name in self._entries]
        for p in ours:
            check = self._entries[p.name][1]
            reason = check(p.value) if check is not None else None
            if reason:
                self._node.get_logger().warn(f'parameter {p.name} := {p.value!r} refused: {reason}')
                return SetParametersResult(successful=False, reason=f'{p.name}: {reason}')
        with self._lock:
            for p in ours:
                self._entries[p.name][0](p.value)
            if ours and self._after is not None:
                self._after({p.name for p in ours})
        for p in ours:
            self._node.get_logger().info(f'parameter {p.name} := {p.value!r} in force')
        return SetParametersResult(successful=True)
