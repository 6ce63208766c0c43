"""learner_node under a real person's clicks (issue 29), at topic level.

* A click flood: Phase II scenes judged by the simulated supervisor, then hasty clicks
  (each on an obstacle the robot has just passed, the click stamped with that pose, as
  the console stamps it; and clicks on obstacles far from every robot, outside the
  library's grid), then Phase II scenes again. Each hasty click makes an encounter that
  no library entry can explain (before: every log-likelihood -inf, "fit failed" on every
  refit, and no fit published again). Now each is set aside, kept in the stores, counted,
  and the fits resume on the rest.
* Unstamped interventions under use_sim_time with no /clock: each takes the steady
  clock, so the second (another position, same obstacle) is not its duplicate.
* A burst of junk of two kinds: one WARN per reason at once, the count of the rest in one
  line per reason that comes on its own (a timer), the totals at shutdown.
"""
import math

import pytest

from geometry_msgs.msg import PoseStamped

from supersafe_ros.learning.data import PHASE2_OFFSETS
from supersafe_ros.learning.phase2_stream import phase2_events
from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
from supersafe_ros.ros_io import rosmsg
from supersafe_ros.sim.watcher import Watcher

from graph_support import Spinner, matched
from learner_phase2_support import (FAR, OMEGAS, SHAPE, STEP, JunkSender, click_flood, drive, make_learner,
                                    play)

pytestmark = pytest.mark.ros   # rclpy nodes in this process

W, MU, SIGMA = 0.5, 1.0, 0.3
HASTY = 6             # clicks just after the robot passed its obstacle


@pytest.fixture(scope='module')
def library(ros_context):
    return load_or_build_library(LibrarySpec(shape=tuple(SHAPE), omegas=tuple(OMEGAS)))


def test_fits_resume_after_a_click_flood(ros_context, tmp_path, library):
    n, store = len(PHASE2_OFFSETS), tmp_path / 'clicks.jsonl'
    node = make_learner(ros_context, store)
    driver, spin = drive(ros_context, node)
    try:
        driver.wait_for(spin)
        watcher = Watcher(library.entry(W), mu=MU, sigma=SIGMA, seed=5)
        n_iv = play(spin, node, driver, phase2_events(watcher, PHASE2_OFFSETS, dt=STEP, t0=1.0))
        spin.until(lambda: driver.fit().get('fitted_encounters') == str(n), 30.0, 'the fit before the flood')
        published = int(driver.fit()['published'])
        assert published >= 1
        # the flood
        n_iv += play(spin, node, driver, click_flood(2000.0, 500))
        spin.until(lambda: driver.fit().get('set_aside') == str(HASTY + FAR), 30.0,
                   'every hasty click set aside')
        fit = driver.fit()
        assert fit['interventions'] == str(n_iv) and fit['rejected'] == '0'
        assert 'no library entry explains its encounter' in fit['last_set_aside'] or \
            'outside the library grid' in fit['last_set_aside']
        # and the person calms down: the same supervisor again, the fits go on
        n_iv += play(spin, node, driver, phase2_events(watcher, PHASE2_OFFSETS, dt=STEP, t0=4000.0,
                                                       first_obstacle=1000))
        driver.publish(('pose', 'robot_0', 9000.0, (-30.0, 0.0, 0.0)))
        try:
            spin.until(lambda: driver.fit().get('fitted_encounters') == str(2 * n), 60.0,
                       'a fit on every encounter but the hasty ones')
        except AssertionError as exc:
            raise AssertionError(f'{exc}; last status {driver.fits[-1:]}') from None
        fit = driver.fit()
        assert math.isfinite(float(fit['log_likelihood'])) and fit['estimator'] == 'first-passage'
        assert int(fit['encounters']) == 2 * n + HASTY        # the hasty ones stay stored
        assert fit['interventions'] == str(n_iv) and fit['set_aside'] == str(HASTY + FAR)
        assert int(fit['refits']) > 0 and int(fit['published']) >= published
        stored = store.read_text().count('\n')
        assert stored == n_iv             # every click kept, the far ones too
    finally:
        spin.shutdown()
        node.close()
        node.destroy_node()
        driver.node.destroy_node()


def _pose(frame, x, y, sec=0, nanosec=0):
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    msg.pose.position.x, msg.pose.position.y = float(x), float(y)
    msg.pose.orientation.w = 1.0
    return msg


def test_unstamped_interventions_without_a_clock_are_not_each_others_duplicates(ros_context, tmp_path):
    node = make_learner(ros_context, tmp_path / 'u.jsonl', estimator='paper', use_sim_time=True)
    from rclpy.node import Node
    sender = Node('unstamped_sender', context=ros_context)
    pub = sender.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
    spin = Spinner(ros_context, node, sender)
    try:
        spin.until(lambda: matched(pub), 20.0, 'the learner')
        assert node.get_clock().now().nanoseconds == 0        # use_sim_time, and no /clock
        for k in range(3):
            pub.publish(_pose('obstacle_4', -3.0 + 0.5 * k, 0.5))
            spin.until(lambda: len(node.store) == k + 1, 10.0, f'unstamped intervention {k} stored')
        stamps = [e.stamp_ns for e in node.store.entries]
        assert all(s > 0 for s in stamps) and len(set(stamps)) == 3 and node.counts['duplicates'] == 0
        # the same event spelled otherwise (stamped) is one record
        pub.publish(_pose('obstacle_8', -3.0, 0.5, sec=7))
        pub.publish(_pose('obstacle_0008', -3.0, 0.5, sec=7))
        spin.until(lambda: node.counts['duplicates'] == 1, 10.0, 'the duplicate')
        assert len(node.store) == 4
    finally:
        spin.shutdown()
        node.close()
        node.destroy_node()
        sender.destroy_node()


def test_a_burst_of_junk_is_told_per_reason_on_time_and_in_totals(ros_context, tmp_path):
    node = make_learner(ros_context, tmp_path / 'j.jsonl', estimator='paper')
    junk = JunkSender(ros_context, node)
    sender, pub, rosout, spin = junk.node, junk.pub, junk.rosout, junk.spin
    try:
        kinds = {'frame names no obstacle': lambda k: _pose('map', -3, 0.5, sec=k + 1),
                 'invalid stamp': lambda k: _pose('obstacle_1', -3, 0.5, sec=1, nanosec=2_000_000_000 + k)}
        burst = 300
        for k in range(burst):
            for make in kinds.values():
                pub.publish(make(k))
        spin.until(lambda: node.counts['rejected'] == 2 * burst, 30.0, 'every message read')

        def lines(reason):
            return [m for m in rosout.logs if m.name == 'learner' and f'({reason})' in m.msg]

        def told(reason):
            out = 0
            for m in lines(reason):
                out += int(m.msg.split()[0]) if m.msg.split()[1] == 'more' else 1
            return out

        # nothing more is sent: each reason's count comes by itself
        spin.until(lambda: all(told(r) == burst for r in kinds), 20.0, 'each reason\'s count')
        for reason in kinds:
            got = lines(reason)
            assert all(m.level == 30 for m in got)      # WARN
            stamps = [m.stamp.sec + m.stamp.nanosec * 1e-9 for m in got]
            assert all(b - a >= 0.95 for a, b in zip(stamps, stamps[1:])), stamps   # at most once a second
            assert got[0].msg.startswith(f'intervention rejected ({reason}): ')
            assert all('latest: ' in m.msg for m in got[1:])
        assert 0 < len(rosout.logs) < 40
        # the totals at shutdown
        node.close()
        spin.until(lambda: any('interventions rejected this run: 600' in m.msg for m in rosout.logs), 10.0,
                   'the totals')
        total = next(m.msg for m in rosout.logs if 'rejected this run' in m.msg)
        assert 'frame names no obstacle 300' in total and 'invalid stamp 300' in total
    finally:
        spin.shutdown()
        node.destroy_node()
        sender.destroy_node()
