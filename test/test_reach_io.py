"""Grid interpolation, value-function files, the library cache and the CLI."""
import json
import subprocess
import sys

import numpy as np
import pytest

from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.library import LibrarySpec, load_or_build_library, load_or_solve
from supersafe_ros.reach.value_function import ValueFunction

GRID = Grid((-4, -3), (4, 5), (17, 21, 12))


def test_trilinear_is_exact_for_multilinear_functions_and_wraps_heading():
    X, Y, TH = GRID.mesh()
    f = lambda x, y, k: 1.0 + 2.0 * x - 0.5 * y + 0.25 * x * y + 0.1 * k  # noqa: E731
    k_index = np.arange(12)[None, None, :] * np.ones_like(X)
    values = f(X, Y, k_index)
    rng = np.random.default_rng(0)
    pts = np.stack([rng.uniform(-4, 4, 300), rng.uniform(-3, 5, 300),
                    GRID.theta[rng.integers(0, 12, 300)]], -1)
    k = np.round((pts[:, 2] + np.pi) / GRID.spacing[2])
    assert np.allclose(GRID.interpolate(values, pts), f(pts[:, 0], pts[:, 1], k))
    # theta = pi is the same heading as -pi; halfway between the last node and 2 pi wraps
    a = GRID.interpolate(values, np.array([[0.5, 0.5, np.pi]]))
    b = GRID.interpolate(values, np.array([[0.5, 0.5, -np.pi]]))
    assert np.allclose(a, b)
    mid = GRID.interpolate(values, np.array([[0.0, 1.0, GRID.theta[-1] + GRID.spacing[2] / 2]]))
    assert np.allclose(mid, 0.5 * (f(0, 1, 11) + f(0, 1, 0)))


def test_flat_gathers_equal_indexed_gathers_bit_for_bit():
    # contiguous node values are read through one flat index; any other layout (a view of a
    # vector field's component) by three index arrays: the two must agree exactly, on and off
    # the grid (clamped) and across the heading wrap
    rng = np.random.default_rng(3)
    field = rng.normal(size=GRID.shape + (3,)).astype(np.float32)
    strided = field[..., 1]
    assert not strided.flags.c_contiguous
    contiguous = np.ascontiguousarray(strided)
    pts = np.stack([rng.uniform(-6, 6, 2000), rng.uniform(-5, 7, 2000), rng.uniform(-7, 7, 2000)], -1)
    a, b = GRID.interpolate(contiguous, pts), GRID.interpolate(strided, pts)
    assert np.array_equal(a, b)
    assert np.array_equal(GRID.interpolate(field, pts)[:, 1], a)
    # signed zeros too (the sum starts from 0.0 in both): all nodes -0.0 read +0.0 everywhere
    zeros = np.full(GRID.shape, -0.0)
    a, b = GRID.interpolate(zeros, pts), GRID.interpolate(np.asfortranarray(zeros), pts)
    assert not np.signbit(a).any() and not np.signbit(b).any()


def test_one_state_in_python_floats_reads_what_numpy_reads_bit_for_bit():
    """Grid.interpolate_at and ValueFunction.value_at (one state, Python floats; a robot's
    own filter reads V this way) equal the array versions bit for bit, signed zeros
    included: on and off the grid (clamped, or ``outside``), across the heading wrap,
    for a rotationally symmetric value function (read on the two heading nodes) and for
    one that is not. They rely on numpy's float64 cos and sin being the C library's,
    checked first so that a platform where they differ says so."""
    import math
    rng = np.random.default_rng(4)
    angles = rng.uniform(-40.0, 40.0, 20000)
    assert np.array_equal(np.cos(angles), [math.cos(a) for a in angles]), 'numpy cos is not the C library\'s'
    assert np.array_equal(np.sin(angles), [math.sin(a) for a in angles]), 'numpy sin is not the C library\'s'
    pts = np.stack([rng.uniform(-6, 6, 3000), rng.uniform(-5, 7, 3000), rng.uniform(-9, 9, 3000)], -1)
    pts[:40, 2] = -np.pi + np.arange(40) % 12 * (2 * np.pi / 12)        # on heading nodes
    field = rng.normal(size=GRID.shape).astype(np.float32)
    field[field > 1.5] = 0.0                                              # ties at zero
    flat = memoryview(field.reshape(-1))
    want = GRID.interpolate(field, pts)
    got = np.array([GRID.interpolate_at(flat, *p) for p in pts.tolist()])
    assert repr(got.tolist()) == repr(want.tolist())
    symmetric = load_or_solve(GRID, 3.0, 1.0, 1.0, 1.0)
    assert symmetric.rotationally_symmetric
    plain = ValueFunction(GRID, field, {'model': 'dubins'})
    assert not plain.rotationally_symmetric
    for vf in (symmetric, plain):
        for outside in (None, np.inf):
            want = vf.value(pts, outside=outside)
            got = np.array([vf.value_at(*p, outside=outside) for p in pts.tolist()])
            assert repr(got.tolist()) == repr(want.tolist())
    grad = symmetric.theta_gradient()
    got = [GRID.interpolate_at(symmetric.flat_theta_gradient(), *p) for p in pts.tolist()]
    assert repr(got) == repr(GRID.interpolate(grad, pts).tolist())
    from supersafe_ros.filter.law import avoid_turn, avoid_turn_at
    assert [avoid_turn_at(symmetric, *p) for p in pts.tolist()] == avoid_turn(symmetric, pts).tolist()


def test_a_heading_layer_is_read_bilinearly_on_its_own_nodes():
    """Grid.interpolate_layer (a rotationally symmetric set's reads, rotated onto heading nodes)
    reads layer k alone: exact for functions bilinear in (x, y), whatever the other layers
    hold; layers wrap modulo nth; it is the trilinear read at the node's heading to round-off;
    and interpolate_layer_at reads the same bits in Python floats."""
    rng = np.random.default_rng(6)
    X, Y, TH = GRID.mesh()
    k_index = np.arange(12)[None, None, :] * np.ones_like(X)
    # odd layers 1e12 above the even ones: a trilinear read at an even node's heading, with its
    # round-off weight on a neighbouring layer, misses by far more than 1e-9 at some states
    values = 1.0 + 2.0 * X - 0.5 * Y + 0.25 * X * Y + 1e12 * (k_index % 2)
    x, y = rng.uniform(-4, 4, 500), rng.uniform(-3, 5, 500)
    layer = 2 * rng.integers(-15, 15, 500)
    want = 1.0 + 2.0 * x - 0.5 * y + 0.25 * x * y
    got = GRID.interpolate_layer(values, x, y, layer)
    assert np.allclose(got, want, rtol=0.0, atol=1e-9)
    nodes = -np.pi + (layer % 12) * GRID.spacing[2]
    off = np.abs(GRID.interpolate(values, np.stack([x, y, nodes], -1)) - want)
    assert np.all(off < 1e-2) and np.sum(off > 1e-9) > 20
    field = rng.normal(size=GRID.shape).astype(np.float32)
    field[field > 1.5] = -0.0
    xs, ys = rng.uniform(-6, 6, 2000), rng.uniform(-5, 7, 2000)     # off the grid too (clamped)
    layers = rng.integers(-30, 30, 2000)
    flat = memoryview(field.reshape(-1))
    want = GRID.interpolate_layer(field, xs, ys, layers)
    got = [GRID.interpolate_layer_at(flat, a, b, int(k)) for a, b, k in zip(xs.tolist(), ys.tolist(), layers)]
    assert repr(got) == repr(want.tolist())


def test_gradient_of_a_linear_function():
    X, Y, TH = GRID.mesh()
    vf = ValueFunction(GRID, 3.0 * X - 2.0 * Y + 0.0 * TH)
    g = vf.gradient(np.array([[0.3, 0.7, 1.0], [-2.2, 4.1, -3.0]]))
    assert np.allclose(g, [[3.0, -2.0, 0.0]] * 2, atol=1e-5)


def test_theta_gradient_alone_is_the_full_gradients_theta_component_bit_for_bit():
    """The filter builds only dV/dtheta of a received set (a 50 MB set: 0.9 s instead of 6.7 s);
    it must be the theta component of node_gradient exactly, in any row chunking, whichever
    of the two is built first."""
    from supersafe_ros.reach.grid import node_gradient, theta_node_gradient
    values = np.random.default_rng(3).normal(size=GRID.shape).astype(np.float32)
    full = node_gradient(GRID, values).astype(np.float32)[..., 2]
    for rows in (1, 5, 16, 100):
        assert np.array_equal(theta_node_gradient(GRID, values, rows=rows), full)
    alone, both = ValueFunction(GRID, values), ValueFunction(GRID, values)
    both.node_gradient()
    assert np.array_equal(alone.theta_gradient(), full) and alone._grad is None
    assert np.array_equal(both.theta_gradient(), full)


def test_flow_composes_and_goes_straight_without_turning():
    car = DubinsCar(3.0, 1.0)
    s = np.array([1.0, -2.0, 0.4])
    assert np.allclose(car.flow(car.flow(s, 0.7, 0.3), 0.7, 0.5), car.flow(s, 0.7, 0.8))
    assert np.allclose(car.flow(s, 0.0, 2.0), [1 + 6 * np.cos(0.4), -2 + 6 * np.sin(0.4), 0.4])
    # a full circle of radius v / w comes back
    assert np.allclose(car.flow(s, 1.0, 2 * np.pi)[:2], s[:2], atol=1e-9)


def test_npz_and_helperoc_round_trips(tmp_path):
    X, Y, TH = GRID.mesh()
    vf = ValueFunction(GRID, np.sin(X) + Y * np.cos(TH), {'omega_max': 0.5, 'speed': 3.0})
    vf.save_npz(tmp_path / 'v.npz')
    back = ValueFunction.load_npz(tmp_path / 'v.npz')
    assert back.grid == GRID and np.array_equal(back.values, vf.values) and back.meta == vf.meta
    with np.load(tmp_path / 'v.npz') as f:
        assert f['value'].dtype == np.float32 and f['value'].shape == (17, 21, 12)
        assert np.allclose(f['theta'], -np.pi + np.arange(12) * 2 * np.pi / 12)
        assert f['x'][0] == -4 and f['x'][-1] == 4
    vf.save_helperoc_json(tmp_path / 'v.json')
    d = json.loads((tmp_path / 'v.json').read_text())
    assert d['gN'] == [17, 21, 12] and d['gperiodicity'] == [0, 0, 1]
    back = ValueFunction.load_helperoc_json(tmp_path / 'v.json')
    assert back.grid == GRID and np.allclose(back.values, vf.values)


def test_reads_the_authors_files(s3_data):
    vf = ValueFunction.load_helperoc_json(s3_data / 'standard_reachset.json')
    assert vf.grid.shape == (65, 65, 42)
    # far from the obstacle and heading away, V is the distance minus the radius
    assert vf.value(np.array([[6.0, 0.0, 0.0]]))[0] == pytest.approx(6.0 - 1.8, abs=0.05)
    cons = ValueFunction.load_helperoc_json(s3_data / 'conservative_reachset.json')
    assert cons.grid.shape == (65, 65, 41)


def test_rejects_malformed_value_functions():
    with pytest.raises(ValueError):
        ValueFunction(GRID, np.zeros((17, 21, 11)))
    bad = np.zeros(GRID.shape)
    bad[3, 3, 3] = np.nan
    with pytest.raises(ValueError):
        ValueFunction(GRID, bad)


def test_library_cache_loads_what_it_solved(tmp_path):
    spec = LibrarySpec(omegas=(0.5, 1.0), shape=(33, 33, 24), horizon=1.5)
    first = load_or_build_library(spec, tmp_path)
    assert [e.from_cache for e in first.entries] == [False, False]
    second = load_or_build_library(spec, tmp_path)
    assert [e.from_cache for e in second.entries] == [True, True]
    for a, b in zip(first.entries, second.entries):
        assert np.array_equal(a.values, b.values)
    assert list(second.omegas) == [0.5, 1.0] and second.entry(1.0) is second.entries[1]
    # another horizon is another problem: not served from the cache
    other = load_or_solve(spec.grid, 3.0, 1.0, 1.8, 2.5, tmp_path)
    assert other.from_cache is False and not np.array_equal(other.values, first.entries[1].values)
    # a damaged cache file is solved again rather than trusted
    for f in tmp_path.glob('*.npz'):
        f.write_bytes(b'not a zip file')
    again = load_or_build_library(spec, tmp_path)
    assert [e.from_cache for e in again.entries] == [False, False]


def test_cli_reach_writes_the_documented_file(tmp_path):
    out = tmp_path / 'v.npz'
    r = subprocess.run([sys.executable, '-m', 'supersafe_ros.cli', 'reach', '--speed', '3',
                        '--omega-max', '1', '--radius', '1.8', '--grid-min', '-6', '-6',
                        '--grid-max', '6', '6', '--shape', '25', '25', '16', '--out', str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert 'converged after' in r.stdout
    with np.load(out) as f:
        assert f['value'].shape == (25, 25, 16) and f['value'].dtype == np.float32
        meta = json.loads(str(f['meta']))
    assert meta['omega_max'] == 1.0 and meta['converged'] is True and meta['horizon'] is None
    assert 'solve_time_s' in meta and meta['keepout']['type'] == 'disc'
    r = subprocess.run([sys.executable, '-m', 'supersafe_ros.cli', 'reach', '--speed', '3',
                        '--omega-max', '1', '--out', str(out)], capture_output=True, text=True)
    assert r.returncode == 2 and '--radius' in r.stderr


def _save_many(path, seed, count):
    """One writer process: save a value function to ``path`` ``count`` times."""
    rng = np.random.default_rng(seed)
    vf = ValueFunction(GRID, rng.normal(size=GRID.shape))
    for _ in range(count):
        vf.save_npz(path)


def test_processes_saving_one_cache_file_at_once_never_leave_it_unreadable(tmp_path):
    # a team on a cold cache: every filter solves the same set and saves it under one name.
    # With a shared temporary name, one writer's rename took the other's half-written file
    # (FileNotFoundError in the other, or a damaged file for readers).
    import multiprocessing
    path = tmp_path / 'same.npz'
    ctx = multiprocessing.get_context('spawn')
    writers = [ctx.Process(target=_save_many, args=(str(path), seed, 60)) for seed in (1, 2)]
    for w in writers:
        w.start()
    reads = 0
    while any(w.is_alive() for w in writers):
        if path.exists():
            ValueFunction.load_npz(path)      # whole, from one writer or the other
            reads += 1
    for w in writers:
        w.join()
        assert w.exitcode == 0
    assert reads > 0
    assert ValueFunction.load_npz(path).values.shape == GRID.shape
    assert sorted(p.name for p in tmp_path.iterdir()) == ['same.npz']   # no temporary left


def test_a_damaged_cache_file_is_solved_again(tmp_path):
    grid = Grid((-4, -4), (4, 4), (9, 9, 8))
    vf = load_or_solve(grid, 3.0, 1.0, 1.0, horizon=0.5, cache_dir=tmp_path)
    (path,) = tmp_path.glob('dubins-*.npz')
    path.write_bytes(path.read_bytes()[:200])          # a half-copied file
    with pytest.raises(ValueError, match='not a readable value-function file'):
        ValueFunction.load_npz(path)
    again = load_or_solve(grid, 3.0, 1.0, 1.0, horizon=0.5, cache_dir=tmp_path)
    assert not again.from_cache and np.allclose(again.values, vf.values)
    assert load_or_solve(grid, 3.0, 1.0, 1.0, horizon=0.5, cache_dir=tmp_path).from_cache
