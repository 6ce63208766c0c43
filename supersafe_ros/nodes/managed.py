"""Filter nodes as managed (lifecycle) nodes, brought up as Nav2's lifecycle_manager brings its own.

``ManagedFilter`` goes before a filter body and ``rclpy.lifecycle.LifecycleNode`` in a class's
bases. The body provides ``build()`` (declare and read the parameters, load the value
functions, make every publisher, subscription and timer: what a plain node does in its
constructor) and ``close()``; it decides only while ``active`` is true. The transitions:

* unconfigured (after construction): nothing declared, nothing published;
* configure: ``build()``; a failure (a parameter refused, no value function) is logged and
  the node stays unconfigured, with what the failed build made destroyed;
* activate: ``active`` true, the filter decides and publishes ``cmd_vel`` (and its state and
  /diagnostics);
* deactivate: ``active`` false: no ``cmd_vel`` at all (the robot's driver times out, as behind
  Nav2's collision_monitor when it is inactive); inputs are still taken, so the filter is
  current when activated again;
* cleanup / shutdown: ``close()`` and every entity ``build()`` made destroyed; parameters stay
  declared with their values, a later configure reads them again.
"""
from __future__ import annotations

import traceback

from rclpy.lifecycle import TransitionCallbackReturn

_ENTITIES = (('publishers', 'destroy_publisher'), ('subscriptions', 'destroy_subscription'),
             ('timers', 'destroy_timer'))


class ManagedFilter:
    """Lifecycle transitions for a filter body (see the module)."""

    active = False
    built = False

    def on_configure(self, state):
        before = {kind: set(getattr(self, kind)) for kind, _ in _ENTITIES}
        self._made_before = before
        try:
            self.build()
        except Exception:       # noqa: BLE001  say why, stay unconfigured
            self.get_logger().error(f'configure failed: {traceback.format_exc()}')
            self._undo()
            return TransitionCallbackReturn.FAILURE
        self.built = True
        self.get_logger().info('configured: inactive, no cmd_vel until activated')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        self.active = True
        self.get_logger().info('activated: filtering')
        return super().on_activate(state)

    def on_deactivate(self, state):
        self.active = False
        self.get_logger().info('deactivated: no cmd_vel until activated')
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        self._undo()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        self._undo()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state):
        self._undo()
        return TransitionCallbackReturn.SUCCESS

    def _undo(self):
        """close() what build() made and destroy its entities (the lifecycle node's own stay)."""
        self.active = False
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


def node_classes(body, node_name: str, class_name: str) -> tuple:
    """(plain, managed) node classes of a filter ``body`` (a class with ``build()``):
    ``<class_name>Node`` builds in its constructor and decides from then on;
    ``Managed<class_name>Node`` builds on configure and decides while active."""
    from rclpy.lifecycle import LifecycleNode
    from rclpy.node import Node

    def plain_init(self, node_name=node_name, **kwargs):
        Node.__init__(self, node_name, **kwargs)
        self.build()

    def managed_init(self, node_name=node_name, **kwargs):
        LifecycleNode.__init__(self, node_name, **kwargs)

    plain = type(f'{class_name}Node', (body, Node), {
        '__init__': plain_init, '__module__': body.__module__,
        '__doc__': f'{body.__name__} as a plain node: built and deciding from construction.'})
    managed = type(f'Managed{class_name}Node', (ManagedFilter, body, LifecycleNode), {
        '__init__': managed_init, '__module__': body.__module__,
        '__doc__': f'{body.__name__} as a managed (lifecycle) node: see nodes/managed.py.'})
    return plain, managed
