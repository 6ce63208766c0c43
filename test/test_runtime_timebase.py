"""The filter's time base (ROS-free): honest ages with or without a running /clock."""
import pytest

from supersafe_ros.runtime.timebase import FilterTime


def test_wall_mode_follows_the_steady_clock_whatever_ros_time_does():
    tb = FilterTime(sim=False)
    assert tb.now(ros_s=100.0, steady_s=5.0) == 0.0
    assert tb.now(ros_s=100.0, steady_s=5.7) == pytest.approx(0.7)
    assert tb.now(ros_s=50.0, steady_s=6.0) == pytest.approx(1.0)     # system time jumped back


def test_sim_time_rules_while_the_clock_advances_at_any_rate():
    tb = FilterTime(sim=True, stall_timeout=1.0)
    tb.now(10.0, 0.0)
    # slow sim: one 0.05 s step every 0.8 wall s -> tau moves by sim time only
    for k in range(1, 6):
        tau = tb.now(10.0 + 0.05 * k, 0.8 * k)
    assert tau == pytest.approx(0.25) and not tb.stalled
    # fast sim: 1 s of sim time in 0.01 wall s
    assert tb.now(11.25, 4.01) == pytest.approx(1.25)


def test_without_clock_ages_follow_the_wall_from_the_stall_start():
    tb = FilterTime(sim=True, stall_timeout=1.0)
    assert tb.now(0.0, 100.0) == 0.0           # use_sim_time and no /clock: ROS time stays 0
    assert tb.now(0.0, 100.4) == pytest.approx(0.4) and tb.stalled   # no clock: the wall at once
    assert tb.now(0.0, 103.0) == pytest.approx(3.0)
    # the clock comes: sim time rules, from where tau was
    assert tb.now(7.0, 103.1) == pytest.approx(3.0) and not tb.stalled
    assert tb.now(7.2, 103.2) == pytest.approx(3.2)
    # and stops: after stall_timeout the wall again, counted from the stop
    assert tb.now(7.2, 104.0) == pytest.approx(3.2)
    assert tb.now(7.2, 104.5) == pytest.approx(4.5) and tb.stalled


def test_a_stopped_clock_makes_an_input_stale_after_its_timeout_in_wall_seconds():
    tb = FilterTime(sim=True, stall_timeout=0.3)
    arrival = tb.now(5.0, 0.0)
    tau = tb.now(5.0, 0.6)         # /clock stopped right after the pose
    assert tau - arrival == pytest.approx(0.6)


def test_stamps_map_onto_tau_by_their_age_and_not_when_unusable():
    tb = FilterTime(sim=True)
    tau = tb.now(20.0, 1.0)
    assert tb.stamp_to_tau(19.9, 20.0, tau) == pytest.approx(tau - 0.1)
    assert tb.stamp_to_tau(20.5, 20.0, tau) == pytest.approx(tau)   # from the future: arrival
    assert tb.stamp_to_tau(0.0, 20.0, tau) is None                  # unstamped
    assert tb.stamp_to_tau(19.0, 0.0, tau) is None                  # ROS time unusable


def test_time_going_back_never_moves_tau_back():
    tb = FilterTime(sim=True)
    tb.now(50.0, 0.0)
    tau = tb.now(51.0, 0.1)
    assert tb.now(2.0, 0.2) == pytest.approx(tau)       # simulator reset
    assert tb.now(2.5, 0.3) == pytest.approx(tau + 0.5)
