"""safety_filter_node as a process with the installed config, and a driver that keeps arrival
times (not a test module): for test_nodes_safety_filter_process.py and
test_nodes_bounded_detections.py."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from supersafe_ros.ros_io import rosmsg

from safety_filter_support import Driver

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / 'config' / 'safety_filter.yaml'
NS = '/robot_7'
OBSTACLE = (4.0, -2.0)
FAR = (OBSTACLE[0] - 7.5, OBSTACLE[1] + 7.0, 0.0)


def start(tmp_path, name, argv):
    log = open(tmp_path / f'{name}.log', 'w')
    return subprocess.Popen([sys.executable, *argv], stdout=log, stderr=subprocess.STDOUT,
                            env=dict(os.environ), start_new_session=True)


def stop(proc):
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def filter_process(tmp_path, *params):
    argv = ['-m', 'supersafe_ros.nodes.safety_filter_node', '--ros-args', '-r', f'__ns:={NS}',
            '--params-file', str(CONFIG)]
    for p in params:
        argv += ['-p', p]
    return start(tmp_path, 'safety_filter', argv)


class TimedDriver(Driver):
    """safety_filter_support's driver in ``NS`` that keeps arrival times: ``out`` the steady times
    of cmd_vel, ``states`` (steady time, values) of safety_filter/state; ``feed`` sends a pose far
    from ``OBSTACLE``, the obstacle and a planner command."""

    def __init__(self, ctx):
        super().__init__(ctx, ns=NS, name='filter_process_driver')
        self.last_pose = None

    def on_cmd_vel(self, msg):
        self.out.append(time.monotonic())

    def on_state(self, msg):
        self.states.append((time.monotonic(), rosmsg.diagnostic_values(msg)))

    def endpoints(self):
        return (self.pose, self.det, self.cmd, self.out_sub, self.state_sub)

    def feed(self, poses=True, stamp=True):
        if poses:
            msg = rosmsg.state_to_pose(FAR, stamp=self.node.get_clock().now().to_msg() if stamp else None)
            self.pose.publish(msg)
            self.last_pose = time.monotonic()
        self.det.publish(rosmsg.xy_to_posearray([OBSTACLE]))
        self.cmd.publish(rosmsg.turn_rate_to_twist(0.2, 3.0))

    def feed_until(self, spin, condition, timeout, what, period=0.05, poses=True):
        deadline = time.monotonic() + timeout
        next_feed = 0.0
        while not condition():
            now = time.monotonic()
            if now > deadline:
                raise AssertionError(f'timed out after {timeout} s waiting for {what}')
            if now >= next_feed:
                self.feed(poses=poses)
                next_feed = now + period
            spin.executor.spin_once(timeout_sec=0.005)

    def newest(self):
        return self.states[-1][1] if self.states else {}


def steady_pass(d, spin):
    """Feed until the filter passes on fresh poses for 5 states in a row (a busy machine can
    deliver the first poses late, and the filter rightly calls those stale)."""
    def settled():
        last = [s for _, s in d.states[-5:]]
        return len(last) == 5 and all(s['action'] == 'pass' for s in last)
    d.feed_until(spin, settled, 60.0, 'five passes in a row')
