"""The node executables (one node per module; main() -> common.run_node)."""
import os as _os
import signal as _signal
import sys as _sys


def _stop_quietly_while_importing():
    """A node process stopped while it is still importing (rclpy, numpy: seconds on a busy
    machine) exits 0 without a KeyboardInterrupt traceback; run_node takes the signals
    over before rclpy starts. Only in a node's own process: ``python -m
    supersafe_ros.nodes.<node>`` (argv[0] is '-m' while the module is located) or its
    console script (``ros2 run``), never in a program that merely imports the package."""
    program = _os.path.basename(_sys.argv[0]) if _sys.argv else ''
    if program != '-m' and not program.endswith('_node'):
        return

    def stop(signum, frame):
        raise SystemExit(0)
    try:
        for s in (_signal.SIGINT, _signal.SIGTERM):
            _signal.signal(s, stop)
    except ValueError:         # not the main thread: not a node process being started
        pass


_stop_quietly_while_importing()
