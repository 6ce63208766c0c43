"""ros_io.direct_take: subscriptions served by a thread of their own, off the executor."""
import threading
import time

import pytest
from rclpy.node import Node

from std_msgs.msg import Int32

from supersafe_ros.ros_io import rosmsg
from supersafe_ros.ros_io import direct_take
from supersafe_ros.ros_io.direct_take import TAKE_PATHS, DirectTake

pytestmark = pytest.mark.ros   # rclpy nodes in this process


def wait(cond, timeout, what):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        time.sleep(0.005)


@pytest.mark.parametrize('path', TAKE_PATHS)
def test_messages_are_taken_in_order_under_the_lock_and_a_failing_callback_is_said_once(ros_context, path):
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

    direct = DirectTake(owner, lock, path=path)
    direct.add(Int32, 'numbers', on_number, rosmsg.QOS_EVENTS)
    pub = talker.create_publisher(Int32, 'numbers', rosmsg.QOS_EVENTS)
    direct.start()
    try:
        assert direct.path == path
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


def test_an_invalid_path_is_refused(ros_context):
    owner = Node('direct_owner', context=ros_context)
    try:
        with pytest.raises(ValueError, match='private, public'):
            DirectTake(owner, threading.RLock(), path='fast')
    finally:
        owner.destroy_node()


@pytest.mark.parametrize('broken', ['no_wait_set', 'wait_set_fails', 'no_rcl_through_ctypes'])
def test_without_the_private_api_the_public_path_takes_the_messages_and_says_so(ros_context, monkeypatch,
                                                                                broken):
    """An rclpy without ``_rclpy.WaitSet``, one whose wait set cannot be made, or an rcl that
    ctypes cannot reach: a WARN, then the helper's own executor serves the subscriptions (raw
    ones as bytes)."""
    import types
    from std_msgs.msg import Float32MultiArray
    if broken == 'no_wait_set':
        monkeypatch.setattr(direct_take, '_rclpy', types.SimpleNamespace())
    elif broken == 'wait_set_fails':
        def no_wait_set(*args):
            raise TypeError('WaitSet() takes other arguments')
        monkeypatch.setattr(direct_take, '_rclpy', types.SimpleNamespace(WaitSet=no_wait_set))
    else:
        from supersafe_ros.ros_io import gil_free_take

        def unreachable(name):
            raise OSError(f'{name} is not loaded and cannot be found')
        monkeypatch.setattr(gil_free_take, '_loaded_library', unreachable)
    owner = Node('fallback_owner', namespace='/fb', context=ros_context)
    talker = Node('fallback_talker', namespace='/fb', context=ros_context)
    warnings, got, raw = [], [], []
    owner.get_logger().warn = lambda text, **k: warnings.append(text)
    direct = DirectTake(owner, threading.RLock())
    direct.add(Int32, 'numbers', lambda msg: got.append(msg.data), rosmsg.QOS_EVENTS)
    direct.add(Float32MultiArray, 'arrays', raw.append, rosmsg.QOS_EVENTS, raw=True, gil_free=True)
    numbers = talker.create_publisher(Int32, 'numbers', rosmsg.QOS_EVENTS)
    arrays = talker.create_publisher(Float32MultiArray, 'arrays', rosmsg.QOS_EVENTS)
    direct.start()
    try:
        assert direct.path == 'public' and direct._executor is not None
        assert len(warnings) == 1 and 'public path' in warnings[0], warnings
        wait(lambda: numbers.get_subscription_count() == 1 and arrays.get_subscription_count() == 1, 10.0,
             'the helper node to subscribe')
        for k in range(5):
            numbers.publish(Int32(data=k))
        arrays.publish(Float32MultiArray(data=[1.5, 2.5]))
        wait(lambda: len(got) == 5 and len(raw) == 1, 10.0, 'every message taken')
        assert got == list(range(5)) and isinstance(raw[0], bytes) and direct.taken == 6
        thread = direct._thread
    finally:
        direct.close()
    assert not thread.is_alive()
    owner.destroy_node()
    talker.destroy_node()


def test_a_50_mb_message_taken_without_the_gil_leaves_the_other_threads_running(ros_context):
    """gil_free: rcl copies a 50 MB serialized message out through ctypes, without the GIL, and
    hands over the same bytes; a Python thread counting meanwhile counts at a fifth or more of
    its rate while the main thread only sleeps (a ratio of two rates measured side by side, so
    the machine's load scales both: 0.7-1.0 quiet, 0.4-0.55 beside two CPU burners, where the
    copy competes for the cores too). rclpy's own take holds the GIL while it copies: its ratio
    (0.03-0.08) is printed beside."""
    import numpy as np
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float32MultiArray
    from supersafe_ros.ros_io.gil_free_take import GilFreeTaker
    n = 12_500_000
    values = np.arange(n, dtype='<f4')
    # a serialized std_msgs/Float32MultiArray: CDR header, no dims, data_offset 0, n floats
    data = b'\x00\x01\x00\x00' + np.array([0, 0, n], dtype='<u4').tobytes() + values.tobytes()
    qos = QoSProfile(depth=2, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
    node = Node('gil_free_taker', context=ros_context)
    sub = node.create_subscription(Float32MultiArray, '/gil_free_big', lambda m: None, qos, raw=True)
    pub = node.create_publisher(Float32MultiArray, '/gil_free_big', qos)
    count, stop = [0], threading.Event()

    def counter():
        while not stop.is_set():
            count[0] += 1

    def counted(action):
        """(what ``action`` returned, the counter's rate while it ran)."""
        before, t0 = count[0], time.perf_counter()
        got = action()
        return got, (count[0] - before) / (time.perf_counter() - t0)

    def take_with(take):
        deadline = time.monotonic() + 60
        while True:
            with sub.handle:
                got, rate = counted(take)
            if got is not None:
                return got, rate
            assert time.monotonic() < deadline, 'no message to take'
            time.sleep(0.01)
    thread = threading.Thread(target=counter, daemon=True)
    try:
        wait(lambda: pub.get_subscription_count() == 1, 10.0, 'matching')
        pub.publish(data)
        pub.publish(data)
        taker = GilFreeTaker()
        thread.start()
        _, alone = counted(lambda: time.sleep(0.3))
        ours, rate = take_with(lambda: taker.take(sub))
        theirs, rate_rclpy = take_with(lambda: (sub.handle.take_message(sub.msg_type, True) or [None])[0])
        print(f'counter while 50 MB were taken, relative to its rate alone: {rate / alone:.2f} without the '
              f'GIL, {rate_rclpy / alone:.2f} by rclpy')
        assert ours.dtype == np.uint8 and ours.tobytes() == data == theirs
        assert rate > alone / 5
        assert taker.take(sub) is None                       # nothing left: None, no error
    finally:
        stop.set()
        if thread.is_alive():
            thread.join()
        node.destroy_node()
