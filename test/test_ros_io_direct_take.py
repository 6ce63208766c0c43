"""ros_io.direct_take: subscriptions served by a thread of their own, off the executor."""
import threading
import time

import pytest
from rclpy.node import Node

from std_msgs.msg import Int32

from supersafe_ros.ros_io import rosmsg
from supersafe_ros.ros_io.direct_take import DirectTake

pytestmark = pytest.mark.ros   # rclpy nodes in this process


def wait(cond, timeout, what):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        time.sleep(0.005)


def test_messages_are_taken_in_order_under_the_lock_and_a_failing_callback_is_said_once(ros_context):
    owner = Node('direct_owner', namespace='/dt', context=ros_context)
    talker = Node('direct_talker', namespace='/dt', context=ros_context)
    lock = threading.RLock()
    got, owned, threads = [], [], set()
    errors = []
    owner.get_logger().error = lambda text, **k: errors.append(text)     # what the thread says

    def on_number(msg):
        owned.append(lock._is_owned())
        threads.add(threading.current_thread().name)
        if msg.data % 10 == 3:
            raise RuntimeError(f'bad number {msg.data}')
        got.append(msg.data)

    direct = DirectTake(owner, lock)
    direct.add(Int32, 'numbers', on_number, rosmsg.QOS_EVENTS)
    pub = talker.create_publisher(Int32, 'numbers', rosmsg.QOS_EVENTS)
    direct.start()
    try:
        wait(lambda: pub.get_subscription_count() == 1, 10.0, 'the helper node to subscribe')
        assert direct.io.get_name() == 'direct_owner_io' and direct.io.get_namespace() == '/dt'
        for k in range(40):
            pub.publish(Int32(data=k))
            time.sleep(0.002)
        wait(lambda: len(owned) == 40, 10.0, 'every message taken')
        assert got == [k for k in range(40) if k % 10 != 3]        # in order, the thread went on
        assert all(owned) and threads == {'direct_owner_io_take'}
        assert len(errors) == 1 and 'bad number 3' in errors[0]    # one kind of error: said once
        # the lock keeps a callback out while another thread holds it
        with lock:
            pub.publish(Int32(data=100))
            wait(lambda: direct.taken == 41, 5.0, 'the message to be taken')
            time.sleep(0.05)
            assert 100 not in got                                   # taken, its callback waits
        wait(lambda: 100 in got, 5.0, 'the message held back by the lock')
        thread = direct._thread
    finally:
        direct.close()
    assert not thread.is_alive()
    wait(lambda: pub.get_subscription_count() == 0, 10.0, 'the helper node to leave the graph')
    with pytest.raises(RuntimeError, match='after start'):
        direct.add(Int32, 'late', on_number, rosmsg.QOS_EVENTS)
    direct.close()                             # twice is harmless
    owner.destroy_node()
    talker.destroy_node()
