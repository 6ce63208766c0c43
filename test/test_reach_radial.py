"""ValueFunction.radial_minimum: a lower bound of every read of V over a band of radii, and the
filter's pair reads that skip the holds it rules out (the same decisions)."""
import numpy as np
import pytest

from supersafe_ros.filter.constraints.pairs import pair_reads
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import solve_avoid
from supersafe_ros.reach.value_function import ValueFunction

DISC = {'model': 'dubins', 'keepout': {'type': 'disc', 'cx': 0.0, 'cy': 0.0, 'r': 1.8}}


@pytest.fixture(scope='module')
def solved():
    vf = solve_avoid(Grid((-8, -8), (8, 8), (33, 33, 16)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=2.0)
    assert vf.rotationally_symmetric
    return vf


def value_functions(solved):
    """The solved set (read rotated onto heading nodes), the same values read trilinearly (no
    symmetry), and noise on an off-centre grid with the symmetric read: no smoothness or
    symmetry to lean on, and rotations that leave the rectangle (clamped reads); and V growing
    with the radius on an off-centre grid, and falling with it (a read nearer the origin, or
    farther from it, than its bound allows is lower, and shows); and V falling with the radius on a grid that
    does not hold the origin (its clamped reads can land farther out than the state)."""
    rng = np.random.default_rng(4)
    noise = Grid((-5, -2), (9, 7), (15, 19, 12))
    ramp = Grid((-6, -3), (9, 8), (61, 45, 24))        # V grows with the radius: lower reads show
    away = Grid((1.75, -4.65), (6.65, 1.65), (21, 29, 6))     # the origin outside: clamps go outward too
    x, y, th = ramp.mesh()
    ax, ay, _ = away.mesh()
    return [solved, ValueFunction(solved.grid, solved.values, {}),
            ValueFunction(noise, rng.normal(0, 3, noise.shape), dict(DISC)),
            ValueFunction(noise, rng.normal(0, 3, noise.shape), {}),
            ValueFunction(ramp, np.hypot(x, y) - 2.0 + 0.1 * np.sin(th), dict(DISC)),
            ValueFunction(ramp, 12.0 - np.hypot(x, y) + 0.1 * np.sin(th), dict(DISC)),
            ValueFunction(away, 10.0 - np.hypot(ax, ay) + rng.normal(0, 0.1, away.shape), dict(DISC))]


def test_no_read_is_below_the_radial_minimum_of_its_band(solved):
    rng = np.random.default_rng(5)
    for vf in value_functions(solved):
        g = vf.grid
        s = np.stack([rng.uniform(g.lo[0], g.hi[0], 20000), rng.uniform(g.lo[1], g.hi[1], 20000),
                      rng.uniform(-7, 7, 20000)], axis=1)
        s[:200, :2] = np.array([g.lo[0], g.hi[1]])              # corners and edges of the rectangle
        s[200:400, 0] = g.hi[0]
        v = vf.value(s)
        r = np.hypot(s[:, 0], s[:, 1])
        exact = vf.radial_minimum(r, r)
        assert np.all(v >= exact)
        widen = rng.uniform(0, 3, (2, len(r)))
        assert np.all(vf.radial_minimum(r - widen[0], r + widen[1]) <= exact)     # a wider band: no higher
        # not vacuous: the bound is finite, and within the values' spread of what is read
        assert np.all(np.isfinite(exact))
        assert np.median(v - exact) < 0.5 * (vf.values.max() - vf.values.min())
        beyond = ((np.hypot(*np.abs([g.lo[:2], g.hi[:2]]).max(axis=0)) + 2 * np.hypot(*g.spacing[:2]))
                  / (1 - g.spacing[2]))
        assert np.all(vf.radial_minimum(np.full(3, beyond), np.full(3, beyond + 1)) == np.inf)


def test_pair_reads_skip_only_holds_that_cannot_reach_the_level(solved):
    """V is read everywhere as before; V next exactly wherever it is at or below the level (and
    wherever the bound allows it), above the level wherever the holds were skipped; so every
    pair looks ahead exactly as with every hold read, and most holds away from the obstacle
    are skipped."""
    rng = np.random.default_rng(7)
    for k, (vf, level) in enumerate(zip(value_functions(solved), (0.0, 0.3, 1.0, -2.0, 0.5, 5.0, 4.0))):
        n = 4000
        g = vf.grid
        rel = np.stack([rng.uniform(g.lo[0] - 3, g.hi[0] + 3, n), rng.uniform(g.lo[1] - 3, g.hi[1] + 3, n),
                        rng.uniform(-4, 4, n)], axis=1)
        rel[::2, :2] = rng.uniform(-4, 4, (n // 2, 2))        # half of them near the obstacle
        bang = rng.choice([1.0, 0.5, 2.0], n)
        omega = np.clip(rng.uniform(-3, 3, n), -bang, bang)
        horizon = rng.choice([0.0, 0.02, 0.1, 0.3], n)
        speed = rng.choice([3.0, 1.0], n)
        v_all, next_all = pair_reads(vf, rel, omega, horizon, speed, bang)
        v, nxt = pair_reads(vf, rel, omega, horizon, speed, bang, level)
        assert repr(v.tolist()) == repr(v_all.tolist())
        assert np.array_equal(nxt <= level, next_all <= level)
        low = nxt <= level
        assert np.array_equal(nxt[low], next_all[low]) and low.sum() > 50
        skipped = nxt != next_all
        assert np.all(nxt[skipped] > level)
        if k in (0, 1, 4, 5, 6):     # not noise (noise has every value near every radius)
            assert skipped.sum() > 0.2 * np.isfinite(next_all).sum()
