"""The node executables (one node per module; main() -> common.run_node)."""
import os as _os
import signal as _signal
import sys as _sys
import threading as _threading

# set by a stop signal that came while the node was still importing: SystemExit raised
# inside an import can be swallowed by a library's bare ``except:``, so run_node checks
# this too before it starts rclpy (a killed team runner's node once kept running so)
stop_requested_while_importing = _threading.Event()


def _stop_quietly_while_importing():
    """A node process stopped while it is still importing (rclpy, numpy: seconds on a busy
    machine) exits 0 without a KeyboardInterrupt traceback; run_node takes the signals
    over before rclpy starts. Only in a node's own process: ``python -m
    supersafe_ros.nodes.<node>`` (argv[0] is '-m' while the module is located) or its
    console script (``ros2 run``), never in a program that merely imports the package."""
    program = _os.path.basename(_sys.argv[0]) if _sys.argv else ''
    if program != '-m' and not program.endswith('_node'):
        return

    try:
        for s in (_signal.SIGINT, _signal.SIGTERM):
            _signal.signal(s, _stop_while_importing)
    except ValueError:         # not the main thread: not a node process being started
        pass


def _stop_while_importing(signum, frame):
    stop_requested_while_importing.set()
    raise SystemExit(0)


_stop_quietly_while_importing()
