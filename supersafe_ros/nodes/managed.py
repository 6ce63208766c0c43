"""Filter nodes as managed (lifecycle) nodes, brought up as Nav2's lifecycle_manager brings its own.

``ManagedFilter`` goes before a filter body and ``rclpy.lifecycle.LifecycleNode`` in a class's
bases. The body provides ``build()`` (declare and read the parameters, load the value
functions, make every publisher, subscription and timer: what a plain node does in its
constructor), ``close()`` and ``send_zero_twist()`` (one zero twist on every cmd_vel it
serves; it returns the publishers); it decides only while ``active`` is true. The lifecycle graph (rcl_lifecycle's; the
ids are lifecycle_msgs/msg/Transition's)::

    unconfigured --configure (1)--> inactive --activate (3)--> active
    unconfigured <--cleanup (2)---- inactive <--deactivate (4)-- active
    unconfigured, inactive, active --shutdown (5, 6, 7)--> finalized

* unconfigured (after construction): nothing declared, no cmd_vel;
* configure: ``build()``; a failure (a parameter refused, no value function) is logged and
  the node stays unconfigured, with what the failed build made destroyed;
* activate: ``active`` true, the filter decides and publishes ``cmd_vel`` (and its state);
* deactivate: ``active`` false, then exactly one zero twist (``send_zero_twist``), so the
  base does not keep driving the last command; then no ``cmd_vel`` at all (the robot's
  driver times out, as behind Nav2's collision_monitor when it is inactive); inputs are still
  taken, so the filter is current when activated again;
* cleanup / shutdown: ``close()`` and every entity ``build()`` made destroyed; parameters stay
  declared with their values, a later configure reads them again. Shutdown from active sends
  the zero twist first, and waits (at most ``ZERO_TWIST_ACK_TIMEOUT``) until every subscriber
  has acknowledged it: a reliable sample still on its way when its publisher is destroyed is
  dropped (seen under load).

A request for a transition that is not valid from the current state (activate while
unconfigured, configure while inactive, anything once finalized), by id or by label, is
refused: the change_state service answers success=False and the node logs a WARN naming the
transition, the state and the transitions valid from it (``refusal``). rclpy's own service
callback raised RCLError for such an id, which ended the process. The service's callback is
wrapped (``_on_change_state``): the request is checked against the state machine's
``available_transitions`` first (``requested_transition``), and whatever the transition
still raises is logged and answered False. In-process ``trigger_*()`` calls are checked the
same way and return FAILURE instead of raising.

/diagnostics belongs to the lifecycle node from construction (a publisher and a 1 Hz steady
timer that configure does not make and cleanup does not destroy): while active, the body's
statuses (``filter_diagnostics.FilterDiagnostics.array``: OK pass, WARN override, ERROR fail
safe); in every other state (unconfigured, inactive, after cleanup or a failed configure,
finalized) a WARN per status, ``inactive (lifecycle state <state>): no cmd_vel``
(``inactive_message``), under the names the body's statuses have (before the first
configure: ``<node>: <namespace>``).
"""
from __future__ import annotations

import time
import traceback

from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.lifecycle import TransitionCallbackReturn

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from ..ros_io import rosmsg
from .filter_diagnostics import DIAGNOSTICS_TOPIC, array_bytes
from .filter_state import Status

_ENTITIES = (('publishers', 'destroy_publisher'), ('subscriptions', 'destroy_subscription'),
             ('timers', 'destroy_timer'), ('guards', 'destroy_guard_condition'))
DIAGNOSTICS_PERIOD = 1.0        # steady s
ZERO_TWIST_ACK_TIMEOUT = 2.0    # steady s, all publishers together


def requested_transition(transition_id: int, label: str, available) -> int | None:
    """The id of the transition a ChangeState request names among the ``available`` ones
    (rows ``(id, label, ...)`` of the state machine's ``available_transitions``), read as
    rclpy reads it: by ``label`` when one is given, else by ``transition_id``; None if it
    names none of them (not valid from the current state)."""
    for row in available:
        if (row[1] == label) if label else (row[0] == transition_id):
            return row[0]
    return None


def request_name(transition_id: int, label: str, graph) -> str:
    """How a request is named in the log: ``'activate'`` by label, ``3 (activate)`` by id
    (its label from the ``graph``'s rows ``(id, label, ...)``; ``unknown`` if none)."""
    if label:
        return repr(label)
    names = {row[0]: row[1] for row in graph}
    return f'{transition_id} ({names.get(transition_id, "unknown")})'


def refusal(request: str, state: str, available) -> str:
    """The WARN of a refused request: what was asked, the state, the labels valid from it."""
    valid = ', '.join(row[1] for row in available) or 'none'
    return f"lifecycle: transition {request} refused: not valid from '{state}' (valid: {valid})"


def acknowledged(publishers, timeout: float) -> bool:
    """Wait until every reliable subscriber of each of ``publishers`` has acknowledged what it
    was sent, ``timeout`` steady seconds at most for all of them; True if they all did."""
    deadline = time.monotonic() + timeout
    for pub in publishers:
        left = deadline - time.monotonic()
        if left <= 0.0 or not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
            return False
    return True


def inactive_message(state: str, configure_failure: str = '', notes=()) -> str:
    """The /diagnostics message of a node that is not active: its lifecycle state, why the last
    configure failed (if it did), and the notes of its input watch (foreign publisher types)."""
    parts = [f'inactive (lifecycle state {state}): no cmd_vel']
    if configure_failure:
        parts.append(f'configure failed: {configure_failure}')
    return '; '.join([*parts, *notes])


class ManagedFilter:
    """Lifecycle transitions for a filter body (see the module)."""

    active = False
    built = False
    # the body's FilterDiagnostics makes no /diagnostics publisher of its own: this node's is
    publishes_diagnostics = True

    def start_lifecycle(self):
        """What the node has from construction, whatever its state: the guarded change_state
        service and /diagnostics (see the module)."""
        self._configure_failure = ''
        ns = self.get_namespace()
        self._status_names = [(f'{self.get_fully_qualified_name()}: {ns}', ns)]
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, rosmsg.QOS_STREAM)
        self._diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD, self._publish_diagnostics,
                                                    clock=Clock(clock_type=ClockType.STEADY_TIME))
        service = getattr(self, '_service_change_state', None)     # None without the communication interface
        if service is not None:
            rclpy_callback = service.callback
            service.callback = lambda request, response: self._on_change_state(rclpy_callback, request, response)

    # -- requests ---------------------------------------------------------------------------------
    def _on_change_state(self, rclpy_callback, request, response):
        """The change_state service: refused (False, a WARN) unless valid from the current state;
        then rclpy's callback, whatever it raises logged and answered False."""
        machine = self._state_machine
        transition = request.transition
        available = machine.available_transitions
        valid = requested_transition(transition.id, transition.label, available) is not None
        if valid:
            try:
                return rclpy_callback(request, response)
            except Exception:   # noqa: BLE001  no lifecycle request ends the process
                name = request_name(transition.id, transition.label, machine.transition_graph)
                self.get_logger().error(f'lifecycle: transition {name} failed: {traceback.format_exc()}')
        else:
            name = request_name(transition.id, transition.label, machine.transition_graph)
            self.get_logger().warning(refusal(name, machine.current_state[1], available))
        response.success = False
        return response

    def _trigger(self, label, rclpy_trigger):
        """An in-process trigger_<label>(): FAILURE (and a WARN) unless valid from the current
        state; rclpy's trigger otherwise, whatever it raises logged and answered FAILURE."""
        machine = self._state_machine
        available = machine.available_transitions
        if requested_transition(0, label, available) is None:
            self.get_logger().warning(refusal(repr(label), machine.current_state[1], available))
            return TransitionCallbackReturn.FAILURE
        try:
            return rclpy_trigger()
        except Exception:   # noqa: BLE001  a callback that triggers must not be ended by it
            self.get_logger().error(f'lifecycle: transition {label!r} failed: {traceback.format_exc()}')
            return TransitionCallbackReturn.FAILURE

    def trigger_configure(self):
        """rclpy's trigger_configure, refused (FAILURE) unless valid from the current state."""
        return self._trigger('configure', super().trigger_configure)

    def trigger_cleanup(self):
        """rclpy's trigger_cleanup, refused (FAILURE) unless valid from the current state."""
        return self._trigger('cleanup', super().trigger_cleanup)

    def trigger_activate(self):
        """rclpy's trigger_activate, refused (FAILURE) unless valid from the current state."""
        return self._trigger('activate', super().trigger_activate)

    def trigger_deactivate(self):
        """rclpy's trigger_deactivate, refused (FAILURE) unless valid from the current state."""
        return self._trigger('deactivate', super().trigger_deactivate)

    def trigger_shutdown(self):
        """rclpy's trigger_shutdown, refused (FAILURE) once finalized (or mid-transition)."""
        return self._trigger('shutdown', super().trigger_shutdown)

    # -- transitions ------------------------------------------------------------------------------
    def on_configure(self, state):
        before = {kind: set(getattr(self, kind)) for kind, _ in _ENTITIES}
        self._made_before = before
        try:
            self.build()
        except Exception as exc:       # noqa: BLE001  say why, stay unconfigured
            self.get_logger().error(f'configure failed: {traceback.format_exc()}')
            self._configure_failure = f'{type(exc).__name__}: {exc}'.splitlines()[0]
            self._undo()
            return TransitionCallbackReturn.FAILURE
        self.built = True
        self._configure_failure = ''
        self.get_logger().info('configured: inactive, no cmd_vel until activated')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        self.active = True
        self.get_logger().info('activated: filtering')
        return super().on_activate(state)

    def on_deactivate(self, state):
        self._stop_the_base('deactivated', 'no cmd_vel until activated')
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        self._undo()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        self._stop_the_base('shutting down', 'no cmd_vel any more', before_destroy=True)
        self._undo()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state):
        self._stop_the_base('a transition failed', 'no cmd_vel until configured and activated',
                            before_destroy=True)
        self._undo()
        return TransitionCallbackReturn.SUCCESS

    def _stop_the_base(self, what, then, before_destroy=False):
        """Active -> quiet: no decision from here on, then one zero twist, so that the base does
        not keep the last command (nothing if the node was not active). ``before_destroy``: its
        publishers go next, so wait until it is acknowledged."""
        was_active, self.active = self.active, False
        if not (was_active and self.built):
            return
        try:
            sent = self.send_zero_twist()       # the body's; after a decision under way, never before it
        except Exception:   # noqa: BLE001  quiet all the same; the transition goes on
            self.get_logger().error(f'{what}: the zero twist was not sent: {traceback.format_exc()}')
            return
        self.get_logger().info(f'{what}: sent a zero twist; {then}')
        if before_destroy and not acknowledged(sent, ZERO_TWIST_ACK_TIMEOUT):
            self.get_logger().warning(f'{what}: the zero twist was not acknowledged by every subscriber within '
                                      f'{ZERO_TWIST_ACK_TIMEOUT:g} s')

    def _undo(self):
        """close() what build() made and destroy its entities (the lifecycle node's own stay)."""
        self.active = False
        if self.built:          # /diagnostics keeps the names of the body's statuses (its robots)
            self._status_names = [(s.name, s.hardware_id) for s in self._statuses()]
        if self.built or getattr(self, 'wiring', None) is not None:
            try:
                super().close()          # the body's
            except Exception:   # noqa: BLE001  a half-made build: destroy what exists
                self.get_logger().warn(f'cleanup: {traceback.format_exc()}')
        before = getattr(self, '_made_before', None)
        if before is not None:
            for kind, destroy in _ENTITIES:
                for entity in set(getattr(self, kind)) - before[kind]:
                    getattr(self, destroy)(entity)
        self.built = False
        self.wiring = None

    def close(self):
        """The body's close, once (run_node calls it, then destroy_node)."""
        if self.built:
            self._undo()

    # -- /diagnostics ---------------------------------------------------------------------------------
    def _publish_diagnostics(self):
        """Once a second, in every state: the body's statuses while active, else WARN inactive."""
        if self.active and self.built:
            out = self.diagnostics.array()
        else:
            names, notes = self._status_names, []
            if self.built:          # inactive: the body's names (its robots) and its input watch
                names = [(s.name, s.hardware_id) for s in self._statuses()]
                notes = self.diagnostics.check_graph()
            message = inactive_message(self._state_machine.current_state[1], self._configure_failure, notes)
            out = array_bytes(self, [Status(DiagnosticStatus.WARN[0], name, message, hardware_id)
                                     for name, hardware_id in names])
        self._diagnostics_pub.publish(out)
