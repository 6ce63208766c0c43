"""learner_node at topic level: interventions from a simulated supervisor in, fits out."""
import math
import os
from pathlib import Path

import numpy as np
import pytest
from rclpy.parameter import Parameter

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import Float32MultiArray
from std_srvs.srv import Empty

from supersafe_ros.ros_io import rosmsg
from supersafe_ros.learning.data import PHASE2_OFFSETS, intervention_states, phase2_encounters
from supersafe_ros.learning.supervisor import NoisySupervisor
from supersafe_ros.nodes.learner_node import FIT_TOPIC, VALUE_FUNCTION_TOPIC, LearnerNode
from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
from supersafe_ros.ros_io.vfmsg import msg_to_value_function

from graph_support import Spinner, matched

pytestmark = pytest.mark.ros   # rclpy nodes in this process

OMEGAS = [0.25, 0.5, 1.0, 2.0]
SHAPE = [41, 41, 24]
TRUE_OMEGA, MU, SIGMA = 0.5, 0.3, 0.1     # the simulated supervisor


@pytest.fixture(scope='module')
def library(ros_context):
    return load_or_build_library(LibrarySpec(shape=tuple(SHAPE), omegas=tuple(OMEGAS)))


@pytest.fixture(scope='module')
def supervised_states(library):
    sup = NoisySupervisor(library.entry(TRUE_OMEGA), MU, SIGMA, rng=1)
    return intervention_states(phase2_encounters(sup, np.tile(PHASE2_OFFSETS, 2), rng=1))


class Listener:
    """Latched subscriber of the learner's outputs, /interventions publisher, reset client."""

    def __init__(self, ctx, name):
        from rclpy.node import Node
        self.node = Node(name, context=ctx)
        self.fits, self.vfs = [], []
        self.fit_sub = self.node.create_subscription(DiagnosticStatus, FIT_TOPIC, self.fits.append,
                                                     rosmsg.QOS_LATCHED)
        self.vf_sub = self.node.create_subscription(Float32MultiArray, VALUE_FUNCTION_TOPIC,
                                                    self.vfs.append, rosmsg.QOS_LATCHED)
        self.pub = self.node.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        self.reset = self.node.create_client(Empty, '/learner/reset')

    def fit(self):
        return rosmsg.diagnostic_values(self.fits[-1]) if self.fits else {}

    def send(self, state, obstacle, stamp_s, frame=None, nanosec=None):
        msg = PoseStamped()
        msg.header.frame_id = rosmsg.obstacle_frame(obstacle) if frame is None else frame
        msg.header.stamp.sec, msg.header.stamp.nanosec = math.floor(stamp_s), int((stamp_s % 1) * 1e9)
        if nanosec is not None:
            msg.header.stamp.nanosec = nanosec
        msg.pose.position.x, msg.pose.position.y = float(state[0]), float(state[1])
        if math.isfinite(state[2]):
            msg.pose.orientation = rosmsg.yaw_to_quaternion(state[2])
        else:
            msg.pose.orientation.w = 0.0   # a zero quaternion cannot be normalised
        self.pub.publish(msg)


def make_learner(ctx, store, **extra):
    params = [Parameter('store_path', value=str(store)), Parameter('library_shape', value=SHAPE),
              Parameter('library_omegas', value=OMEGAS), Parameter('min_interventions', value=3),
              Parameter('estimator', value='paper')]
    params += [Parameter(k, value=v) for k, v in extra.items()]
    return LearnerNode(context=ctx, parameter_overrides=params)


@pytest.fixture(scope='module')
def running(ros_context, tmp_path_factory, library):
    store = tmp_path_factory.mktemp('learner') / 'subject.jsonl'
    node = make_learner(ros_context, store, republish_level_tolerance=0.0)     # every fit goes out
    listener = Listener(ros_context, 'learner_test_listener')
    spin = Spinner(ros_context, node, listener.node)
    spin.until(lambda: matched(listener.pub, listener.fit_sub, listener.vf_sub), 10.0, 'learner topics')
    state = {'node': node, 'store': store}
    yield state, listener, spin
    spin.shutdown()
    state['node'].close()
    state['node'].destroy_node()
    listener.node.destroy_node()


def test_fit_follows_the_interventions_of_a_simulated_supervisor(running, supervised_states, library):
    state, listener, spin = running
    states = supervised_states
    for i, s in enumerate(states[:2]):
        listener.send(s, i, 100.0 + i)
    spin.until(lambda: listener.fit().get('interventions') == '2', 5.0, 'two stored')
    assert not listener.vfs and listener.fit()['fitted_interventions'] == '0'   # below min_interventions
    listener.send(states[2], 2, 102.0)
    spin.until(lambda: listener.fit().get('fitted_interventions') == '3', 5.0, 'the first fit')
    spin.until(lambda: listener.vfs, 5.0, 'the first value function')
    for i in range(3, len(states)):
        listener.send(states[i], i, 100.0 + i)
    n = str(len(states))
    spin.until(lambda: listener.fit().get('fitted_interventions') == n, 10.0, 'the fit on every intervention')
    fit = listener.fit()
    assert float(fit['omega_max']) == TRUE_OMEGA
    assert abs(float(fit['mu']) - MU) < 0.1 and abs(float(fit['sigma']) - SIGMA) < 0.06
    assert fit['estimator'] == 'paper' and math.isfinite(float(fit['log_likelihood']))
    assert float(fit['alpha']) == pytest.approx(float(fit['mu']))   # alpha_k = 0
    # the value function that went out is the chosen library entry, bit for bit
    spin.until(lambda: msg_to_value_function(listener.vfs[-1]).meta.get('interventions') == len(states),
               5.0, 'the last value function')
    vf = msg_to_value_function(listener.vfs[-1])
    assert np.array_equal(vf.values, library.entry(TRUE_OMEGA).values)
    assert vf.meta['source'] == 'learned' and vf.meta['mu'] == pytest.approx(float(fit['mu']))
    assert vf.meta['omega_max'] == TRUE_OMEGA and vf.grid == library.spec.grid


@pytest.mark.parametrize('bad', ['nan', 'inf', 'empty_frame', 'map_frame', 'outside', 'zero_quaternion',
                                 'duplicate', 'duplicate_spelled', 'frame_not_an_id', 'frame_100kB',
                                 'negative_stamp', 'nanosec_overflow'])
def test_bad_interventions_are_rejected_and_the_node_keeps_running(running, bad):
    state, listener, spin = running
    before = int(listener.fit().get('interventions', 0))
    rejected = int(listener.fit().get('rejected', 0))
    s, frame, stamp = (-3.0, 0.5, 0.0), None, 500.0 + rejected
    if bad == 'nan':
        s = (math.nan, 0.5, 0.0)
    elif bad == 'inf':
        s = (-3.0, -math.inf, 0.0)
    elif bad == 'empty_frame':
        frame = ''
    elif bad == 'map_frame':
        frame = 'map'
    elif bad == 'outside':
        s = (-30.0, 0.5, 0.0)
    elif bad == 'zero_quaternion':
        s = (-3.0, 0.5, math.nan)
    elif bad == 'duplicate':
        stamp = 100.0   # the first supervised intervention, same obstacle and time
    elif bad == 'duplicate_spelled':
        stamp, frame = 100.0, 'obstacle_000'    # obstacle 0 again, its number spelled otherwise
    elif bad == 'frame_not_an_id':
        frame = 'obstacle_abc'
    elif bad == 'frame_100kB':
        frame = 'obstacle_' + '7' * 100_000
    elif bad == 'negative_stamp':
        stamp = -5.0
    duplicates = int(listener.fit().get('duplicates', 0))
    set_aside = int(listener.fit().get('set_aside', 0))
    fitted = listener.fit().get('fitted_interventions')
    listener.fits.clear()
    if bad == 'nanosec_overflow':
        listener.send(s, 0, stamp, frame, nanosec=1_500_000_000)
    else:
        listener.send(s, 0, stamp, frame)
    if bad.startswith('duplicate'):
        spin.until(lambda: listener.fit().get('duplicates') == str(duplicates + 1), 5.0, 'the duplicate')
        assert listener.fit()['interventions'] == str(before) and listener.fit()['rejected'] == str(rejected)
        assert len(state['node'].store) == before
        assert listener.fit()['last_rejection'].startswith('duplicate: obstacle 0 at stamp 100000000000 ns')
        return
    if bad == 'outside':
        # an obstacle far from every robot: a real removal, stored, but no value to fit
        spin.until(lambda: listener.fit().get('set_aside') == str(set_aside + 1), 5.0, 'the set-aside')
        assert listener.fit()['interventions'] == str(before + 1) and listener.fit()['rejected'] == str(rejected)
        assert listener.fit()['fitted_interventions'] == fitted
        assert listener.fit()['last_set_aside'].startswith('outside the library grid: obstacle_0 at (-30, 0.5)')
        assert 'set aside' in listener.fits[-1].message and listener.fits[-1].level == bytes([1])
        return
    spin.until(lambda: listener.fit().get('rejected') == str(rejected + 1), 5.0, 'the rejection')
    assert listener.fit()['interventions'] == str(before)
    assert 'rejected' in listener.fits[-1].message and listener.fits[-1].level == bytes([1])
    reason = listener.fit()['last_rejection']
    expected = {'frame_not_an_id': 'does not name an obstacle', 'frame_100kB': 'characters long',
                'negative_stamp': 'not a valid time', 'nanosec_overflow': 'not a valid time',
                'nan': 'not finite'}.get(bad)
    if expected:
        assert expected in reason and len(reason) < 300


def test_a_fit_is_resent_only_when_its_set_or_level_moves_beyond_the_tolerance(
        ros_context, tmp_path, supervised_states):
    """The default republish_level_tolerance (0.01): a refit whose entry is the same and whose
    mu, sigma and alpha are each within 0.01 of the set in force sends no value function (a
    710 KB set went out for a change of mu in its 17th digit); the rule, replayed on every
    refit's status, says when one went out."""
    node = make_learner(ros_context, tmp_path / 'subject.jsonl')
    assert node.level_tolerance == 0.01
    listener = Listener(ros_context, 'learner_tolerance_listener')
    spin = Spinner(ros_context, node, listener.node)
    try:
        spin.until(lambda: matched(listener.pub, listener.fit_sub, listener.vf_sub), 10.0, 'learner topics')
        refits = []
        for i, s in enumerate(supervised_states):
            listener.send(s, i, 100.0 + i)
            if i >= 2:
                spin.until(lambda: listener.fit().get('fitted_interventions') == str(i + 1), 10.0, f'refit {i}')
                refits.append((listener.fits[-1].message, listener.fit()))
        last, sent = None, 0
        for message, f in refits:
            key = (int(f['index']), float(f['alpha']), float(f['mu']), float(f['sigma']))
            changed = last is None or key[0] != last[0] or any(abs(a - b) > 0.01 for a, b in zip(key[1:], last[1:]))
            assert message.startswith('fit published' if changed else 'fit unchanged'), (message, key, last)
            if changed:
                last, sent = key, sent + 1
            assert int(f['published']) == sent
        print(f'{sent} value functions for {len(refits)} refits')
        assert 1 < sent < len(refits)
        spin.until(lambda: listener.vfs and msg_to_value_function(listener.vfs[-1]).meta['mu'] == last[2], 10.0,
                   'the last value function sent')
    finally:
        spin.shutdown()
        node.close()
        node.destroy_node()
        listener.node.destroy_node()


def test_a_learner_without_a_store_path_keeps_the_newest_run_folders(ros_context, tmp_path, monkeypatch):
    """store_path '': a fresh run folder under $XDG_DATA_HOME/supersafe_ros/runs, and the older
    ones beyond keep_runs go (each launch left one behind, and nothing removed them)."""
    import subprocess
    import sys
    monkeypatch.setenv('XDG_DATA_HOME', str(tmp_path))
    runs = tmp_path / 'supersafe_ros' / 'runs'
    gone = subprocess.Popen([sys.executable, '-c', 'pass'])
    gone.wait()
    old = []
    for day in range(1, 5):
        folder = runs / f'2026010{day}T120000Z-{gone.pid}'
        folder.mkdir(parents=True)
        (folder / 'interventions.jsonl').write_text('')
        old.append(folder)
    node = LearnerNode(context=ros_context, parameter_overrides=[
        Parameter('store_path', value=''), Parameter('keep_runs', value=2), Parameter('library_shape', value=SHAPE),
        Parameter('library_omegas', value=OMEGAS), Parameter('estimator', value='paper')])
    try:
        here = Path(node.store.path).parent
        assert here.parent == runs and here not in old
        assert sorted(p for p in runs.iterdir()) == sorted([old[-1], here])     # the newest old one and this
    finally:
        node.close()
        node.destroy_node()


def test_restart_keeps_the_data_and_republishes_the_fit(running, ros_context):
    state, listener, spin = running
    n = len(state['node'].store)
    old_mu = state['node'].fit.mu
    assert n >= 3
    spin.remove(state['node'])
    state['node'].close()
    state['node'].destroy_node()
    state['node'] = make_learner(ros_context, state['store'])
    spin.add(state['node'])
    late = Listener(ros_context, 'learner_late_joiner')   # late joiner: latched fit and set
    spin.add(late.node)
    spin.until(lambda: late.fits and late.vfs, 10.0, 'the republished fit')
    assert late.fit()['interventions'] == str(n) and float(late.fit()['mu']) == pytest.approx(old_mu)
    # the intervention outside the grid (test_bad_interventions...) is stored, and set aside again
    assert late.fit()['set_aside'] == '1' and 'outside the library grid' in late.fit()['last_set_aside']
    meta = msg_to_value_function(late.vfs[-1]).meta
    assert meta['interventions'] == n - 1 and meta['stored_interventions'] == n
    late.node.destroy_node()


def test_reset_archives_the_data_and_publishes_the_standard_set(running):
    state, listener, spin = running
    n = len(state['node'].store)
    spin.until(lambda: listener.reset.service_is_ready(), 10.0, 'the reset service')
    listener.vfs.clear()
    future = listener.reset.call_async(Empty.Request())
    spin.until(future.done, 5.0, 'the reset reply')
    spin.until(lambda: listener.vfs and listener.fit().get('interventions') == '0', 5.0, 'the reset')
    vf = msg_to_value_function(listener.vfs[-1])
    assert vf.meta['source'] == 'standard' and vf.meta['omega_max'] == 1.0
    assert len(state['node'].store) == 0
    folder = os.path.dirname(state['store'])
    archived = [f for f in os.listdir(folder) if f != os.path.basename(state['store'])]
    assert len(archived) == 1
    with open(os.path.join(folder, archived[0])) as f:
        assert len(f.read().splitlines()) == n
