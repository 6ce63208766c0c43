"""The noisy idealized supervisor and the Phase II protocol, on hand-made value functions."""
import numpy as np
import pytest

from supersafe_ros.learning.data import PHASE2_OFFSETS, phase2_encounters, phase2_pass
from supersafe_ros.learning.supervisor import NoisySupervisor
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.value_function import ValueFunction


def linear_vf(a=1.0, b=0.0, c=0.0, shape=(33, 33, 12)):
    """V = a x + b y + c: exact under trilinear interpolation."""
    g = Grid((-8.0, -8.0), (8.0, 8.0), shape)
    X, Y, _ = g.mesh()
    return ValueFunction(g, a * X + b * Y + c, {'omega_max': 1.0})


def approach(n=200):
    """Frames x from 8 down to -8 at y = 0: V = x falls steadily."""
    x = np.linspace(8.0, -8.0, n)
    return np.stack([x, np.zeros(n), np.zeros(n)], axis=1)


def test_noise_free_supervisor_intervenes_at_first_frame_at_or_below_mu():
    sup = NoisySupervisor(linear_vf(), mu=1.3, sigma=0.0, rng=0)
    frames = approach()
    k = sup.judge_encounter(frames)
    v = frames[:, 0]
    assert v[k] <= 1.3 < v[k - 1]


def test_supervisor_lets_the_robot_pass_when_values_stay_above_the_threshold():
    sup = NoisySupervisor(linear_vf(c=20.0), mu=1.0, sigma=0.1, rng=0)
    assert sup.judge_encounter(approach()) is None


def test_one_draw_per_encounter_makes_intervention_values_gaussian_about_mu():
    # With one w per judgement and a steady fall of V, V at the intervention is
    # mu + w up to one frame step. Per-frame draws would bias it upwards (many chances).
    mu, sigma = 1.0, 0.4
    sup = NoisySupervisor(linear_vf(), mu, sigma, rng=3)
    frames = approach(1601)                  # 0.01 per frame
    vals = np.array([frames[sup.judge_encounter(frames), 0] for _ in range(3000)])
    assert abs(vals.mean() - (mu - 0.005)) < 0.03
    assert abs(vals.std() - sigma) < 0.03


def test_streaming_matches_batch_with_the_same_seed():
    frames = approach(300)
    batch = NoisySupervisor(linear_vf(), 0.5, 0.8, rng=11)
    stream = NoisySupervisor(linear_vf(), 0.5, 0.8, rng=11)
    for _ in range(50):
        k = batch.judge_encounter(frames)
        stream.start_encounter()
        hits = [i for i, f in enumerate(frames) if stream.observe(f)]
        assert hits == ([] if k is None else [k])     # one intervention at most, at the same frame


def test_streaming_threshold_is_fixed_within_an_encounter_and_redrawn_between():
    sup = NoisySupervisor(linear_vf(c=100.0), 0.0, 1.0, rng=5)
    sup.start_encounter()
    first = sup.threshold
    for f in approach(20):
        sup.observe(f)
    assert sup.threshold == first
    sup.start_encounter()
    assert sup.threshold != first


def test_observe_rejects_bad_frames_and_constructor_rejects_bad_parameters():
    sup = NoisySupervisor(linear_vf(), 1.0, 0.1, rng=0)
    with pytest.raises(ValueError):
        sup.observe([np.nan, 0.0, 0.0])
    with pytest.raises(ValueError):
        sup.observe([1.0, 2.0])
    with pytest.raises(ValueError):
        sup.judge_encounter(np.zeros((4, 2)))
    with pytest.raises(ValueError):
        NoisySupervisor(linear_vf(), 1.0, -0.1)
    with pytest.raises(ValueError):
        NoisySupervisor(linear_vf(), np.nan, 0.1)
    with pytest.raises(TypeError):
        NoisySupervisor(np.zeros((3, 3, 3)), 1.0, 0.1)


def test_phase2_pass_drives_straight_from_x0_and_stops_at_the_obstacle_or_the_far_side():
    frames, t = phase2_pass(0.5, speed=3.0, radius=1.8, x0=-8.0, dt=0.05)
    assert np.allclose(frames[0], [-8.0, 0.5, 0.0])
    assert np.allclose(np.diff(frames[:, 0]), 0.15) and np.all(frames[:, 1:] == [0.5, 0.0])
    assert np.hypot(*frames[-1, :2]) <= 1.8 < np.hypot(*frames[-2, :2])
    assert np.allclose(t, np.arange(len(frames)) * 0.05)
    wide, _ = phase2_pass(2.0, dt=0.05)                         # misses the disc
    assert wide[-1, 0] <= 8.0 and wide[-1, 0] > 8.0 - 0.15


def test_phase2_encounters_follow_the_supervisor_and_keep_the_full_pass():
    offsets = np.tile(PHASE2_OFFSETS, 2)
    exact = NoisySupervisor(linear_vf(a=-1.0), mu=3.0, sigma=0.0)   # V = -x: intervene at x >= -3
    enc = phase2_encounters(exact, offsets, dt=0.05)
    assert len(enc) == len(offsets)
    for e, y0 in zip(enc, offsets):
        full, _ = phase2_pass(y0, dt=0.05)
        assert np.array_equal(e.full_pass, full)
        assert np.array_equal(e.states, full[:len(e.states)])
        assert e.intervened and e.states[-1, 0] >= -3.0 > e.states[-2, 0]
    never = NoisySupervisor(linear_vf(a=-1.0), mu=-30.0, sigma=0.0)
    assert not any(e.intervened for e in phase2_encounters(never, offsets, dt=0.05))
    # the rng argument makes the protocol reproducible and leaves the supervisor's own rng alone
    noisy = NoisySupervisor(linear_vf(a=-1.0), mu=3.0, sigma=1.0, rng=0)
    state = noisy.rng.bit_generator.state
    a = phase2_encounters(noisy, offsets, dt=0.05, rng=7)
    b = phase2_encounters(noisy, offsets, dt=0.05, rng=7)
    assert [len(e.states) for e in a] == [len(e.states) for e in b]
    assert len({len(e.states) for e in a}) > 3              # the draws differ between scenes
    assert noisy.rng.bit_generator.state == state
