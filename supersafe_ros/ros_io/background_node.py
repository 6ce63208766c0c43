"""An rclpy node with a context of its own, spun on a daemon thread.

For plain Python programs that watch or drive a graph of node processes (the
team runner's monitor, the study's conductor and learned-set publisher): the
program's main thread stays free, and closing the node never touches any other
rclpy context in the process. DDS stays on loopback (ensure_local_ros_env).
"""
from __future__ import annotations

import logging
import threading

from ..rosenv import ensure_local_ros_env


class BackgroundNode:
    def __init__(self, name: str, domain_id: int):
        ensure_local_ros_env()
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, args=[], domain_id=int(domain_id))
        self.node = rclpy.create_node(name, context=self.context)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self.node)
        self._thread = None

    def start(self) -> None:
        """Spin on a daemon thread (after the owner has created its endpoints)."""
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        try:
            self._executor.spin()
        except Exception:  # the context was shut down under the executor by close()
            pass

    def close(self, join_timeout: float = 2.0, shutdown_timeout: float | None = None,
              teardown_timeout: float | None = 5.0) -> bool:
        """Stop spinning and tear down; ``join_timeout``, ``shutdown_timeout``: the most wall
        seconds to wait for the spin thread and for callbacks in flight (None: until they end);
        ``teardown_timeout``: the most wall seconds to wait for the executor's shutdown and the
        node's destruction, which run on a daemon thread of their own (None: until they end).

        True when the teardown finished. A teardown seen blocking in rclpy's
        ``destroy_when_not_in_use`` under load (a session's main thread stuck there for good)
        is left to its daemon thread with a WARNING: the context is already shut down, so the
        node can take no more messages, and the caller goes on.
        """
        # stop the context first so spin() returns, then tear down off the caller's thread
        self._rclpy.try_shutdown(context=self.context)
        if self._thread is not None:
            self._thread.join(timeout=join_timeout)
        teardown = threading.Thread(target=self._teardown, args=(shutdown_timeout,), daemon=True,
                                    name=f'teardown {self.node.get_name()}')
        teardown.start()
        teardown.join(timeout=teardown_timeout)
        if teardown.is_alive():
            logging.getLogger(__name__).warning(
                'node %s: its teardown did not finish within %.1f s; left to a daemon thread '
                '(its context is shut down: it takes no more messages)', self.node.get_name(), teardown_timeout)
            return False
        return True

    def _teardown(self, shutdown_timeout: float | None) -> None:
        try:
            self._executor.shutdown(timeout_sec=shutdown_timeout)
            self.node.destroy_node()
        except Exception:
            pass
