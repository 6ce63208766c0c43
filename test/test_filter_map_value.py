"""The local map's one avoid value (filter.sensing.map_value): against disc values, a wall's closed form, a door;
its window; the background worker."""
import math
import threading

import numpy as np
import pytest

from supersafe_ros.filter.sensing import map_value
from supersafe_ros.filter.sensing.map_value import (MapArrays, MapValueSettings, MapValueWorker, solve_map_value,
                                                    value_lattice_node, window_half_widths)
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.field import FREE
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import AvoidSolver, solve_avoid

CELL = 0.05                     # the map's cell (a Nav2 robot's costmap)
SPEED, OMEGA, CLEARANCE = 0.5, 1.0, 0.25
RHO = SPEED / OMEGA             # the turning radius
WALL_TERM = CELL * (math.sqrt(2) - 1) / 2      # a node facing a wall of cells squarely: D - c sqrt(2)/2 = d - this


def empty_map(origin=(-5.0, -5.0), size=200, version=1):
    return MapArrays(origin, CELL, np.zeros((size, size), bool), version)


def with_cells(snapshot, *rects, version=None):
    """The map with every cell inside the rectangles (x_min, x_max, y_min, y_max) occupied."""
    occupied = snapshot.occupied.copy()
    x0, y0 = snapshot.origin
    xs = x0 + snapshot.cell * np.arange(occupied.shape[0])
    ys = y0 + snapshot.cell * np.arange(occupied.shape[1])
    for xa, xb, ya, yb in rects:
        inside_x = (xs >= xa - 1e-9) & (xs + snapshot.cell <= xb + 1e-9)
        inside_y = (ys >= ya - 1e-9) & (ys + snapshot.cell <= yb + 1e-9)
        occupied[np.ix_(inside_x, inside_y)] = True
    return MapArrays(snapshot.origin, snapshot.cell, occupied, snapshot.version + 1 if version is None else version)


def solve(snapshot, centre, **kw):
    return solve_map_value(snapshot, centre, SPEED, OMEGA, CLEARANCE, MapValueSettings(**kw))


def sound_nodes(mv):
    g = mv.vf.grid
    X, Y = np.meshgrid(g.x, g.y, indexing='ij')
    h = mv.sound_half_width + 1e-9
    return (np.abs(X - mv.centre[0]) <= h) & (np.abs(Y - mv.centre[1]) <= h)


# -- the value against known ones ------------------------------------------------------------
def test_one_occupied_cell_is_the_disc_that_holds_it():
    snap = with_cells(empty_map(), (0.0, 0.05, 0.0, 0.05))
    mv = solve(snap, (0.4, -0.3))
    holder = Disc(0.025, 0.025, CELL * math.sqrt(2) / 2 + CLEARANCE)
    disc = solve_avoid(mv.vf.grid, DubinsCar(SPEED, OMEGA), holder, 3.0)
    inner = sound_nodes(mv)
    err = np.abs(mv.vf.values - disc.values)[inner]
    assert err.max() < 0.01
    assert np.min(mv.vf.values[inner]) < 0.0 < np.max(mv.vf.values[inner])      # the set is in the window
    assert mv.vf.meta['keepout']['type'] == 'occupancy' and not mv.vf.rotationally_symmetric


def test_a_disc_of_cells_is_the_disc_that_holds_them_within_a_cell():
    snap = empty_map()
    x0, y0 = snap.origin
    centres_x = x0 + CELL * (np.arange(200) + 0.5)
    centre = (0.525, 0.025)
    occupied = np.hypot(centres_x[:, None] - centre[0], centres_x[None, :] - centre[1]) <= 0.5
    snap = MapArrays(snap.origin, CELL, occupied, 2)
    mv = solve(snap, (0.3, 0.0))
    holder = Disc(*centre, 0.5 + CELL * math.sqrt(2) / 2 + CLEARANCE)
    disc = solve_avoid(mv.vf.grid, DubinsCar(SPEED, OMEGA), holder, 3.0)
    g = mv.vf.grid
    X, Y = np.meshgrid(g.x, g.y, indexing='ij')
    outside = sound_nodes(mv) & (np.hypot(X - centre[0], Y - centre[1]) > 0.5 + CELL)    # not in the cells
    # inside an occupied cell the field is -(c sqrt(2)/2 + clearance), no deeper: compare down to that
    floor = -(CELL * math.sqrt(2) / 2 + CLEARANCE)
    diff = (mv.vf.values - np.maximum(disc.values, floor))[outside]
    assert diff.min() > -0.01                   # the cells lie inside the disc: no lower value
    assert diff.max() < CELL + 0.01             # and fill it to within a cell


def test_a_wall_head_on_and_at_an_angle_against_the_closed_form():
    """A car at distance d from an infinite wall, heading psi off its normal, escapes by turning away
    at full rate: it advances rho (1 - sin psi) towards the wall, V = d - rho (1 - sin psi) (T >= pi / 2w)."""
    snap = with_cells(empty_map(), (1.5, 1.7, -4.5, 4.5))
    mv = solve(snap, (0.625, 0.025))
    g = mv.vf.grid
    k0 = g.shape[2] // 2                        # heading 0: at the wall
    for x in (0.425, 0.525, 0.625, 0.725):
        d = 1.5 - x - CLEARANCE - WALL_TERM     # l at the car
        i, j = int(np.argmin(np.abs(g.x - x))), int(np.argmin(np.abs(g.y - 0.025)))
        assert mv.covers(g.x[i], g.y[j])
        for dk in (0, 1, 2, 4):
            psi = dk * g.spacing[2]
            exact = d - RHO * (1.0 - math.sin(psi))
            # l is linear and the parallel heading a step's end: the solver is exact here
            assert abs(mv.vf.values[i, j, k0 + dk] - exact) < 1e-3, (x, dk)
            assert abs(mv.vf.values[i, j, k0 - dk] - exact) < 1e-3, (x, -dk)


def test_a_door_along_its_centre_line_is_safe_and_off_its_axis_is_not():
    """A 1.2 m door in a wall, clearance 0.25: on the centre line the closest approach is to the jambs,
    0.6 m: V = 0.35 less the cell term (the jamb's cell centres are half a cell inside it). 1 m off
    the axis, 0.8 m before the wall, the car cannot turn into the door: it turns away, V = 0.8 - 0.25 - rho
    less the cell term."""
    snap = with_cells(empty_map(), (1.5, 1.6, -4.5, -0.6), (1.5, 1.6, 0.6, 4.5))
    mv = solve(snap, (0.7, 0.0))
    centre_line = float(mv.vf.value(np.array([0.7, 0.0, 0.0])))
    off_axis = float(mv.vf.value(np.array([0.7, 1.0, 0.0])))
    assert mv.covers(0.7, 0.0) and mv.covers(0.7, 1.0)
    assert 0.35 - WALL_TERM - 0.05 < centre_line <= 0.35 - WALL_TERM + 0.01
    assert off_axis < centre_line - 0.2
    assert abs(off_axis - (0.8 - CLEARANCE - RHO - WALL_TERM)) < 0.03
    # the same wall without the door: no way through
    closed = solve(with_cells(snap, (1.5, 1.6, -0.6, 0.6)), (0.7, 0.0))
    assert float(closed.vf.value(np.array([0.7, 0.0, 0.0]))) < 0.1


def test_no_occupied_cell_is_large_everywhere():
    mv = solve(empty_map(), (0.0, 0.0))
    assert np.all(mv.vf.values == np.float32(FREE))


# -- the window ------------------------------------------------------------------------------------
def test_the_window_is_centred_on_the_value_lattice_and_sound_where_it_says():
    assert value_lattice_node((0.31, -0.27), CELL, 0.1) == pytest.approx((0.325, -0.275))
    rng = np.random.default_rng(3)
    snap = empty_map()
    occupied = rng.random(snap.occupied.shape) < 0.01
    occupied[90:110, 90:110] = False
    snap = MapArrays(snap.origin, CELL, occupied, 5)
    mv = solve(snap, (0.31, -0.27))
    half, sound = window_half_widths(SPEED, OMEGA, MapValueSettings())
    assert mv.centre == pytest.approx((0.325, -0.275)) and mv.vf.meta['window']['half_width'] == pytest.approx(half)
    assert mv.sound_half_width == pytest.approx(sound) and sound >= MapValueSettings().reach - 1e-9
    assert mv.version == 5 and mv.vf.meta['map']['version'] == 5
    (x0, y0), (x1, y1) = AvoidSolver(mv.vf.grid, DubinsCar(SPEED, OMEGA)).read_bounds()
    (f0, g0), (f1, g1) = mv.keepout.lo, mv.keepout.hi
    assert f0 < x0 and g0 < y0 and f1 > x1 and g1 > y1          # the solver never reads the field's outside
    big = solve(snap, (0.31, -0.27), reach=3.0)
    g = mv.vf.grid
    here = big.vf.value(np.stack(np.meshgrid(g.x, g.y, g.theta, indexing='ij'), axis=-1))
    diff = np.abs(mv.vf.values - here)
    assert diff[sound_nodes(mv)].max() < 1e-5
    assert not mv.covers(mv.centre[0] + sound + 0.01, mv.centre[1])


def test_cells_beyond_the_map_edge_keep_their_distance_to_the_map():
    """A window that reaches past the map: the field there is the distance to the map's cells (no jump to
    free at the map's edge), the same as a larger map with the same occupied cells."""
    small = with_cells(empty_map(origin=(-1.0, -1.0), size=40), (0.9, 1.0, -1.0, 1.0))     # a wall on the edge
    large = with_cells(empty_map(origin=(-5.0, -5.0), size=200), (0.9, 1.0, -1.0, 1.0))
    a, b = solve(small, (1.0, 0.0)), solve(large, (1.0, 0.0))
    assert np.array_equal(a.vf.grid.x, b.vf.grid.x)
    assert np.max(np.abs(a.vf.values - b.vf.values)) < 1e-5
    assert a.vf.value(np.array([1.2, 0.0, np.pi])) < 0.0      # beyond the map, facing the wall


def test_settings_and_problems_are_checked():
    with pytest.raises(ValueError, match='cell'):
        MapValueSettings(cell=0.0)
    with pytest.raises(ValueError, match='recentre'):
        MapValueSettings(recentre=2.0)
    with pytest.raises(ValueError, match='headings'):
        MapValueSettings(headings=2)
    with pytest.raises(ValueError, match='no state would be sound'):
        solve(empty_map(), (0.0, 0.0), max_half_width=1.0)
    with pytest.raises(ValueError, match='clearance'):
        solve_map_value(empty_map(), (0.0, 0.0), SPEED, OMEGA, -0.1)
    with pytest.raises(ValueError, match='origin'):
        solve_map_value(MapArrays((math.nan, 0.0), CELL, np.zeros((4, 4), bool)), (0.0, 0.0), SPEED, OMEGA, 0.1)


# -- the worker ---------------------------------------------------------------------------------------
def snapshots():
    base = empty_map()
    return [with_cells(base, (1.0, 1.2, -1.0, 1.0), version=1),
            with_cells(base, (1.0, 1.2, -1.0, 1.0), (-1.0, -0.5, 0.5, 0.7), version=2),
            with_cells(base, (0.5, 0.6, -2.0, 0.0), version=3)]


def wait_for(condition, what):
    """Wait for a condition the worker's thread makes true (bounded: a stuck worker fails, not hangs)."""
    done = threading.Event()
    for _ in range(2000):
        if condition():
            return
        done.wait(0.01)
    raise AssertionError(f'the worker never got to: {what}')


def test_inline_equals_threaded():
    inline = MapValueWorker(SPEED, OMEGA, CLEARANCE, inline=True)
    threaded = MapValueWorker(SPEED, OMEGA, CLEARANCE)
    try:
        for i, snap in enumerate(snapshots()):
            inline.submit(snap, (0.1 * i, 0.0), stamp=i)
            threaded.submit(snap, (0.1 * i, 0.0), stamp=i)
            wait_for(lambda: threaded.latest() is not None and threaded.latest().stamp == i, f'stamp {i}')
            a, b = inline.latest(), threaded.latest()
            assert np.array_equal(a.vf.values, b.vf.values) and a.centre == b.centre and a.version == b.version
    finally:
        assert threaded.close()


def test_latest_wins_a_request_submitted_during_a_solve_replaces_the_pending_one(monkeypatch):
    started, release, solved = threading.Event(), threading.Event(), []
    real = map_value.solve_map_value

    def held(snapshot, centre, *args, stamp=None, **kw):
        started.set()
        release.wait(10.0)
        solved.append(stamp)
        return real(snapshot, centre, *args, stamp=stamp, **kw)

    monkeypatch.setattr(map_value, 'solve_map_value', held)
    worker = MapValueWorker(SPEED, OMEGA, CLEARANCE)
    try:
        snaps = snapshots()
        worker.submit(snaps[0], (0.0, 0.0), stamp='first')
        assert started.wait(10.0)
        worker.submit(snaps[1], (0.0, 0.0), stamp='second')
        worker.submit(snaps[2], (0.0, 0.0), stamp='third')
        worker.submit(snaps[1], (0.0, 0.0), stamp='fourth')
        release.set()
        wait_for(lambda: worker.latest() is not None and worker.latest().stamp == 'fourth', 'the fourth request')
        assert solved == ['first', 'fourth']
        assert (worker.submitted, worker.solved, worker.replaced) == (4, 2, 2)
        assert worker.latest().version == 2
    finally:
        release.set()
        assert worker.close()


def test_errors_are_kept_not_raised_and_the_last_value_stays():
    bad = MapArrays((0.0, 0.0), CELL, np.zeros(5, bool), 9)        # not a 2-D map
    for inline in (True, False):
        worker = MapValueWorker(SPEED, OMEGA, CLEARANCE, inline=inline)
        try:
            worker.submit(snapshots()[0], (0.0, 0.0), stamp=1)
            wait_for(lambda: worker.latest() is not None, 'a first value')
            worker.submit(bad, (0.0, 0.0), stamp=2)
            wait_for(lambda: worker.error_count == 1, 'the error')
            assert 'ValueError' in worker.error and '2-D' in worker.error and worker.errors == [worker.error]
            assert worker.latest().stamp == 1
        finally:
            assert worker.close()


def test_close_returns_and_later_submits_are_ignored():
    worker = MapValueWorker(SPEED, OMEGA, CLEARANCE)
    worker.submit(snapshots()[0], (0.0, 0.0))
    assert worker.close(timeout=30.0)
    assert not worker._thread.is_alive()
    worker.submit(snapshots()[1], (0.0, 0.0))
    assert worker.close()


def test_nothing_changed_nothing_solved_and_the_window_stays_while_the_robot_is_near_it():
    worker = MapValueWorker(SPEED, OMEGA, CLEARANCE, inline=True)
    snap = snapshots()[0]
    worker.submit(snap, (0.0, 0.0), stamp=1)
    first = worker.latest()
    same = MapArrays(snap.origin, snap.cell, snap.occupied.copy(), 7)      # a new version, the same cells
    worker.submit(same, (0.3, -0.2), stamp=2)                              # within recentre (0.5)
    assert (worker.solved, worker.skipped) == (1, 1)
    kept = worker.latest()
    assert kept.vf is first.vf and kept.stamp == 2 and kept.version == 7 and kept.centre == first.centre
    worker.submit(same, (0.7, 0.0), stamp=3)                                # beyond it: a new window
    assert worker.solved == 2 and worker.latest().centre == pytest.approx((0.725, 0.025))
    worker.submit(snapshots()[1], (0.7, 0.0), stamp=4)                      # the map changed
    assert worker.solved == 3
    worker.submit(snapshots()[1], (0.7, 0.0), omega_max=0.5, stamp=5)       # another turn bound
    assert worker.solved == 4 and worker.latest().omega_max == 0.5 and worker.latest().vf.omega_max == 0.5


def test_a_change_beyond_the_windows_reach_solves_nothing():
    """The window's field is all a solve reads: a cell changed where no node of it is nearer to that cell
    than to the walls about the window keeps the value; one inside it does not."""
    boxed = with_cells(empty_map(), (-4.0, 4.0, -4.0, -3.7), (-4.0, 4.0, 3.7, 4.0), (-4.0, -3.7, -4.0, 4.0),
                       (3.7, 4.0, -4.0, 4.0), version=1)
    first = solve(boxed, (0.0, 0.0))
    beyond = with_cells(boxed, (4.5, 4.55, 4.5, 4.55), version=2)
    kept = solve_map_value(beyond, (0.0, 0.0), SPEED, OMEGA, CLEARANCE, MapValueSettings(), stamp='b', previous=first)
    assert kept.vf is first.vf and kept.stamp == 'b' and kept.version == 2
    inside = with_cells(boxed, (1.0, 1.05, 0.0, 0.05), version=3)
    fresh = solve_map_value(inside, (0.0, 0.0), SPEED, OMEGA, CLEARANCE, MapValueSettings(), previous=first)
    assert fresh.vf is not first.vf and fresh.version == 3
    other = solve_map_value(beyond, (0.0, 0.0), SPEED, OMEGA, 0.2, MapValueSettings(), previous=first)
    assert other.vf is not first.vf                 # another clearance: another problem
    worker = MapValueWorker(SPEED, OMEGA, CLEARANCE, inline=True)
    for snap in (boxed, beyond, inside):
        worker.submit(snap, (0.0, 0.0))
    assert (worker.solved, worker.skipped) == (2, 1)
