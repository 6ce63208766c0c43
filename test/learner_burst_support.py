"""Plumbing of the learner's burst test and benchmark (not a test module).

``publish_burst(n, ...)`` runs in its own process (``python -m`` of this file's
directory): it waits for the learner's /interventions subscription, publishes ``n``
distinct valid interventions as fast as rclpy can with the supervisor's QoS
(rosmsg.QOS_EVENTS), and prints the wall time of the last publish. ``CpuBurners`` keeps
the machine busy with plain Python busy loops (killed by pid).
"""
from __future__ import annotations

import subprocess
import sys
import time

BURNER = 'while True: pass'


class CpuBurners:
    def __init__(self, n=2):
        self.procs = [subprocess.Popen([sys.executable, '-c', BURNER]) for _ in range(n)]

    def stop(self):
        for p in self.procs:
            p.kill()
        for p in self.procs:
            p.wait()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()


def state_of(i):
    """A valid state inside the paper's grid, different for every i."""
    return (-6.0 + (i % 97) * 0.1, -2.0 + (i % 41) * 0.1, 0.0)


def newest_is(msg, published):
    """Whether a value-function message is the learner's last published fit, by its
    (library index, alpha, mu, sigma) key (``LearnerNode.published``)."""
    from supersafe_ros.ros_io.vfmsg import msg_metadata
    meta = msg_metadata(msg)
    return published is not None and tuple(meta.get(k) for k in ('index', 'alpha', 'mu', 'sigma')) == \
        tuple(published)


def publisher_cmd(n, first_obstacle=1000, stamp0=1000.0):
    return [sys.executable, __file__, str(n), str(first_obstacle), repr(stamp0)]


def run_burst(ctx, store, n, burners=2, extra_params=(), timeout=300.0):
    """Learner (paper estimator, small library) in this process, spun here; a burst of
    ``n`` from another process while ``burners`` busy loops run. Returns a dict of figures."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from diagnostic_msgs.msg import DiagnosticStatus
    from std_msgs.msg import Float32MultiArray
    from supersafe_ros.nodes.learner_node import FIT_TOPIC, VALUE_FUNCTION_TOPIC, LearnerNode
    from supersafe_ros.ros_io import rosmsg
    from graph_support import Spinner
    params = dict(store_path=str(store), estimator='paper', library_shape=[41, 41, 24],
                  library_omegas=[0.25, 0.5, 1.0, 2.0])
    params.update(dict(extra_params))
    node = LearnerNode(context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    listener = Node('burst_listener', context=ctx)
    fits, vfs = [], []
    listener.create_subscription(DiagnosticStatus, FIT_TOPIC,
                                 lambda m: fits.append((time.time(), rosmsg.diagnostic_values(m))),
                                 rosmsg.QOS_LATCHED)
    listener.create_subscription(Float32MultiArray, VALUE_FUNCTION_TOPIC, vfs.append, rosmsg.QOS_LATCHED)
    spin = Spinner(ctx, node, listener)
    hot = CpuBurners(burners)
    try:
        with open('/proc/loadavg') as f:
            load_before = f.read().split()[0]
        pub = subprocess.Popen(publisher_cmd(n), stdout=subprocess.PIPE, text=True)
        spin.until(lambda: fits and fits[-1][1].get('interventions') == str(n), timeout,
                   f'/safe_set/fit counting all {n}')
        t_counted = fits[-1][0]
        # the newest value function sent arrives (latched, keep-last 1: a reader that falls behind
        # may skip one sent before it, so the count of those received is not the count sent)
        spin.until(lambda: vfs and newest_is(vfs[-1], node.published), 60.0,
                   f'the last of the {fits[-1][1]["published"]} value functions sent')
        with open('/proc/loadavg') as f:
            load_after = f.read().split()[0]
        out, _ = pub.communicate(timeout=120)
    finally:
        hot.stop()
        spin.shutdown()
    t_first, t_last = (float(v) for v in out.split()[:2])
    stored = len(node.store)
    node.close()
    final = [v for t, v in fits if t <= t_counted][-1]
    figures = dict(n=n, stored=stored, returncode=pub.returncode, final=final,
                   vfs=len(vfs), latency=t_counted - t_last, publish_s=t_last - t_first,
                   total_s=t_counted - t_first, load=(load_before, load_after))
    node.destroy_node()
    listener.destroy_node()
    return figures


def main(argv):
    n, first, stamp0 = int(argv[1]), int(argv[2]), float(argv[3])
    import rclpy
    from rclpy.node import Node
    from geometry_msgs.msg import PoseStamped
    from supersafe_ros.ros_io import rosmsg
    from supersafe_ros.rosenv import ensure_local_ros_env
    ensure_local_ros_env()
    rclpy.init()
    node = Node('learner_burst_publisher')
    pub = node.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
    deadline = time.monotonic() + 60.0
    while pub.get_subscription_count() < 1:
        if time.monotonic() > deadline:
            print('no subscriber', flush=True)
            return 2
        time.sleep(0.01)
    msgs = []
    for i in range(n):
        m = rosmsg.state_to_pose(state_of(i), frame=rosmsg.obstacle_frame(first + i))
        t = stamp0 + i * 0.001
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9)) % 1_000_000_000
        msgs.append(m)
    t0 = time.time()
    for m in msgs:
        pub.publish(m)
    t_last = time.time()
    print(f'{t0!r} {t_last!r}', flush=True)
    # stay until the learner has everything acknowledged (reliable): closing the writer
    # at once could drop samples still in flight
    pub.wait_for_all_acked(rclpy.duration.Duration(seconds=60.0)) if hasattr(pub, 'wait_for_all_acked') \
        else time.sleep(5.0)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == '__main__':
    import os
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    raise SystemExit(main(sys.argv))
