"""An rclpy node with a context of its own, spun on a daemon thread.

For plain Python programs that watch or drive a graph of node processes (the
team runner's monitor, the study's conductor and learned-set publisher): the
program's main thread stays free, and closing the node never touches any other
rclpy context in the process. DDS stays on loopback (ensure_local_ros_env).
"""
from __future__ import annotations

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

    def close(self, join_timeout: float = 2.0, shutdown_timeout: float | None = None) -> None:
        """Stop spinning and tear down; ``join_timeout``, ``shutdown_timeout``: the most wall
        seconds to wait for the spin thread and for callbacks in flight (None: until they end)."""
        # stop the context first so spin() returns, then tear down in this thread
        self._rclpy.try_shutdown(context=self.context)
        if self._thread is not None:
            self._thread.join(timeout=join_timeout)
        try:
            self._executor.shutdown(timeout_sec=shutdown_timeout)
            self.node.destroy_node()
        except Exception:
            pass
