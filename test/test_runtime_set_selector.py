"""LearnedSetSelector (runtime.set_selector): which safe set is in force, without ROS.

Messages are given as bytes; the decoder here looks them up in a table (the node
passes ros_io.cdr.serialized_to_value_function), the level is alpha = mu + k sigma, the value functions are
signed distances to discs (V = l), so "more conservative" is "a larger disc".
"""
import threading

import numpy as np
import pytest

import supersafe_ros.runtime.set_selector as set_selector
from supersafe_ros.runtime.set_selector import LearnedSetSelector
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.value_function import ValueFunction

from filter_support import Log

WAIT = 20.0


def disc_vf(radius, shape=(41, 41, 12), source='learned', **meta):
    g = Grid((-8.0, -8.0), (8.0, 8.0), shape)
    x, y, _ = g.mesh()
    return ValueFunction(g, (np.hypot(x, y) - radius).astype(np.float32),
                         {'model': 'dubins', 'omega_max': 1.0, 'source': source, **meta})


STANDARD = disc_vf(1.8, source='standard')


class Messages:
    """bytes -> value function (a table), counting what was decoded."""

    def __init__(self):
        self.table, self.decoded = {}, []

    def add(self, vf) -> bytes:
        data = f'message {len(self.table)}'.encode()
        self.table[data] = vf
        return data

    def decode(self, data):
        self.decoded.append(data)
        if data not in self.table:
            raise ValueError('serialized value function is truncated')
        return self.table[data]


def level(meta, k):
    return float(meta['mu']) + k * float(meta['sigma'])


@pytest.fixture
def make():
    made = []

    def make(**kw):
        msgs, log = Messages(), Log()
        args = dict(alpha_offset=0.0, use_learned=True, max_bytes=1024)
        args.update(kw)
        s = LearnedSetSelector(STANDARD, args.pop('standard_alpha', 0.0), decode=msgs.decode, level=level,
                               log=log, lock=threading.RLock(), **args)
        made.append(s)
        return s, msgs, log
    yield make
    for s in made:
        s.close()


def offer(s, data):
    s.offer(data)
    assert s.wait_idle(WAIT)


def test_the_standard_set_is_in_force_at_the_start(make):
    s, _, _ = make(standard_alpha=0.25)
    assert s.safe_set is s.standard and s.standard.source == 'standard' and s.standard.alpha == 0.25
    assert s.standard.vf is STANDARD
    assert s.set_update == ('none', 'no value function received') and s.idle()


def test_an_admissible_learned_set_goes_in_force_at_its_level(make):
    s, msgs, log = make(alpha_offset=2.0)
    offer(s, msgs.add(disc_vf(2.5, mu=0.1, sigma=0.05, interventions=9)))
    assert s.safe_set.source == 'learned' and s.safe_set.alpha == pytest.approx(0.2)
    assert s.set_update[0] == 'accepted' and s.set_update[1].startswith('learned set in force: ')
    assert '9 interventions; decoded in ' in s.set_update[1] and s.set_updates == {'accepted': 1, 'rejected': 0}
    assert log.said('info', 'learned set in force') and log.said('debug', 'decoding and checking it off the')


def test_an_oversize_message_is_rejected_unread(make):
    s, msgs, log = make(max_bytes=8)
    s.offer(msgs.add(disc_vf(2.5, mu=0.0, sigma=0.0)))
    assert msgs.decoded == [] and s.safe_set is s.standard
    assert s.set_update == ('rejected', 'value function message of 9 bytes exceeds max_value_function_bytes '
                                        '(8); not decoded; keeping the standard set')
    assert log.said('error', 'exceeds max_value_function_bytes')
    s.max_bytes = 1024            # a live parameter: the next one is read
    offer(s, msgs.add(disc_vf(2.5, mu=0.0, sigma=0.0)))
    assert s.safe_set.source == 'learned'


def test_a_malformed_message_is_rejected_and_the_set_in_force_kept(make):
    s, msgs, log = make()
    offer(s, b'garbage')
    assert s.set_update == ('rejected', 'value function rejected: serialized value function is truncated; '
                                        'keeping the standard set')
    offer(s, msgs.add(disc_vf(2.5, mu=0.0, sigma=0.0)))
    offer(s, b'more garbage')
    assert s.set_update[1].endswith('keeping the learned set') and s.safe_set.source == 'learned'
    assert s.set_updates == {'accepted': 1, 'rejected': 2}


def test_an_inadmissible_learned_set_is_rejected_with_the_reason(make):
    s, msgs, log = make()
    offer(s, msgs.add(disc_vf(1.0, mu=0.0, sigma=0.0)))              # a smaller unsafe region
    assert s.set_update[0] == 'rejected' and 'less conservative than the standard set' in s.set_update[1]
    assert s.set_update[1].startswith('learned set (alpha 0) rejected: ')
    assert s.set_update[1].endswith('; keeping the standard set') and s.safe_set is s.standard
    offer(s, msgs.add(disc_vf(1.8, mu=-100.0, sigma=0.0)))           # well formed, level -100
    assert s.set_update[0] == 'rejected' and s.safe_set is s.standard
    assert log.said('error', 'rejected')


def test_a_level_that_is_not_finite_is_rejected(make):
    s, msgs, _ = make()
    offer(s, msgs.add(disc_vf(2.5, mu=float('nan'), sigma=0.0)))
    assert s.set_update[0] == 'rejected' and s.set_update[1].startswith('learned set rejected: alpha must be finite')


def test_source_standard_resets_to_the_local_standard_set(make):
    s, msgs, log = make(standard_alpha=0.1)
    offer(s, msgs.add(disc_vf(2.5, mu=0.0, sigma=0.0)))
    assert s.safe_set.source == 'learned'
    offer(s, msgs.add(disc_vf(9.0, source='standard', alpha=5.0)))    # its values are not used
    assert s.safe_set is s.standard and s.standard.vf is STANDARD and s.standard.alpha == 0.1
    assert s.set_update == ('accepted', 'standard set requested by the publisher: the local standard set is '
                                        'in force (alpha 0.1)')
    s.set_use_learned(True)                      # nothing learned left to check
    assert s.wait_idle(WAIT) and s.safe_set is s.standard


def test_use_learned_false_ignores_learned_sets_and_true_checks_them_again(make):
    s, msgs, log = make(use_learned=False)
    offer(s, msgs.add(disc_vf(2.5, mu=0.0, sigma=0.0)))
    assert s.safe_set is s.standard
    assert s.set_update == ('ignored', 'learned set received but use_learned is false: the standard set '
                                       'stays in force')
    s.set_use_learned(True)
    assert s.wait_idle(WAIT) and s.safe_set.source == 'learned' and s.set_update[0] == 'accepted'
    s.set_use_learned(False)                     # at once, no check
    assert s.safe_set is s.standard


def test_a_new_standard_level_puts_the_standard_set_at_it_or_checks_the_learned_set_again(make):
    s, msgs, log = make()
    s.set_standard_alpha(0.3)                    # the standard set in force: at once
    assert s.safe_set is s.standard and s.safe_set.alpha == 0.3 and s.idle()
    s.set_standard_alpha(0.0)
    offer(s, msgs.add(disc_vf(2.2, mu=0.0, sigma=0.0)))
    assert s.safe_set.source == 'learned'
    s.set_standard_alpha(0.2)                    # still contained: the disc is 0.4 m larger
    assert s.wait_idle(WAIT) and s.safe_set.source == 'learned' and s.set_updates['accepted'] == 2
    s.set_standard_alpha(1.0)                    # no longer: back to the standard set, at the new level
    assert s.wait_idle(WAIT) and s.safe_set is s.standard and s.standard.alpha == 1.0
    assert s.set_update[0] == 'rejected' and s.set_update[1].endswith('; back to the standard set')


def test_a_new_alpha_offset_checks_the_learned_set_again_at_its_new_level(make):
    s, msgs, log = make()
    offer(s, msgs.add(disc_vf(2.5, mu=0.1, sigma=0.1)))
    assert s.safe_set.alpha == pytest.approx(0.1)
    s.set_alpha_offset(2.0)
    assert s.wait_idle(WAIT) and s.safe_set.alpha == pytest.approx(0.3) and s.set_updates['accepted'] == 2
    s.set_use_learned(False)
    s.set_alpha_offset(1.0)                      # not in use: nothing to check
    assert s.idle() and s.set_updates['accepted'] == 2


class Gate:
    """check_learned_set held at its start until released."""

    def __init__(self, monkeypatch):
        self.entered, self.release = threading.Event(), threading.Event()
        check = set_selector.check_learned_set

        def slow_check(*args, **kwargs):
            self.entered.set()
            assert self.release.wait(WAIT)
            return check(*args, **kwargs)
        monkeypatch.setattr(set_selector, 'check_learned_set', slow_check)


def test_use_learned_turned_off_during_the_check_keeps_the_standard_set(make, monkeypatch):
    """The race guard: the checked set goes in force only if use_learned and the levels are
    unchanged since the check began."""
    gate = Gate(monkeypatch)
    s, msgs, _ = make()
    s.offer(msgs.add(disc_vf(2.5, mu=0.0, sigma=0.0)))
    assert gate.entered.wait(WAIT) and s.busy
    s.set_use_learned(False)
    gate.release.set()
    assert s.wait_idle(WAIT)
    assert s.safe_set is s.standard and s.set_updates == {'accepted': 0, 'rejected': 0}
    s.set_use_learned(True)                      # checked anew, then in force
    assert s.wait_idle(WAIT) and s.safe_set.source == 'learned' and s.set_updates['accepted'] == 1


def test_a_level_changed_during_the_check_is_checked_again_at_the_new_level(make, monkeypatch):
    gate = Gate(monkeypatch)
    s, msgs, _ = make()
    s.offer(msgs.add(disc_vf(2.5, mu=0.1, sigma=0.1)))
    assert gate.entered.wait(WAIT)
    s.set_alpha_offset(3.0)
    gate.release.set()
    assert s.wait_idle(WAIT)
    assert s.safe_set.source == 'learned' and s.safe_set.alpha == pytest.approx(0.4)
    assert s.set_updates['accepted'] == 1        # the set checked at the old level never went in force


def test_a_newer_message_supersedes_one_not_yet_handled(make, monkeypatch):
    gate = Gate(monkeypatch)
    s, msgs, _ = make()
    first = msgs.add(disc_vf(2.5, mu=0.1, sigma=0.0))
    s.offer(first)
    assert gate.entered.wait(WAIT)
    skipped, newest = msgs.add(disc_vf(2.5, mu=0.2, sigma=0.0)), msgs.add(disc_vf(2.5, mu=0.3, sigma=0.0))
    s.offer(skipped)
    s.offer(newest)
    s.set_alpha_offset(1.0)                      # a reselect does not replace a queued message
    gate.release.set()
    assert s.wait_idle(WAIT)
    assert msgs.decoded == [first, newest]
    assert s.safe_set.alpha == pytest.approx(0.3)


def test_the_worker_survives_a_failure_and_says_why(make):
    s, msgs, log = make()

    def broken(meta, k):
        raise RuntimeError('no level')
    s._level = broken
    offer(s, msgs.add(disc_vf(2.5, mu=0.0, sigma=0.0)))
    assert s.set_update == ('rejected', 'value function handling failed: RuntimeError: no level; keeping the '
                                        'standard set')
    s._level = level
    offer(s, msgs.add(disc_vf(2.5, mu=0.0, sigma=0.0)))
    assert s.safe_set.source == 'learned'


def test_close_stops_the_worker(make):
    s, _, _ = make()
    s.close()
    assert not s._worker.is_alive()
