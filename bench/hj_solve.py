"""Solve the benchmark's avoid problem with hj_reachability (run by bench/.venv-hj's python).

Same problem and the same output file layout as `supersafe reach`: a Dubins car
x' = v cos th, y' = v sin th, th' = u, |u| <= w, a disc of radius R at the origin,
l = |p| - R, and V(x) = max_u min_{t in [0, T]} l(x(t)).

In hj_reachability's terms: the value is propagated backward in time from 0 to -T with the
control maximising the Hamiltonian (no disturbance), and the Hamiltonian is clipped at
zero from above (`solver.backwards_reachable_tube`), which makes the solution the tube
value min over time of l rather than the value at the final time alone.

Usage: hj_solve.py --speed 3 --omega-max 1 --radius 1 --horizon 3
       --grid-min -10 -10 --grid-max 10 10 --shape 101 101 64 --out FILE.npz
"""
import argparse
import json
import time

T_START = time.perf_counter()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import hj_reachability as hj  # noqa: E402


class DubinsAvoid(hj.ControlAndDisturbanceAffineDynamics):
    """Dubins car with a bounded turn rate that maximises the value; no disturbance."""

    def __init__(self, speed, omega_max):
        self.speed = speed
        control_space = hj.sets.Box(jnp.array([-omega_max]), jnp.array([omega_max]))
        disturbance_space = hj.sets.Box(jnp.array([0.0]), jnp.array([0.0]))
        super().__init__('max', 'min', control_space, disturbance_space)

    def open_loop_dynamics(self, state, time):
        return jnp.array([self.speed * jnp.cos(state[2]), self.speed * jnp.sin(state[2]), 0.0])

    def control_jacobian(self, state, time):
        return jnp.array([[0.0], [0.0], [1.0]])

    def disturbance_jacobian(self, state, time):
        return jnp.array([[0.0], [0.0], [0.0]])


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--speed', type=float, required=True)
    p.add_argument('--omega-max', type=float, required=True)
    p.add_argument('--radius', type=float, required=True)
    p.add_argument('--horizon', type=float, required=True)
    p.add_argument('--grid-min', type=float, nargs=2, required=True)
    p.add_argument('--grid-max', type=float, nargs=2, required=True)
    p.add_argument('--shape', type=int, nargs=3, required=True)
    p.add_argument('--accuracy', default='very_high', choices=['low', 'medium', 'high', 'very_high'])
    p.add_argument('--out', required=True)
    a = p.parse_args()

    grid = hj.Grid.from_lattice_parameters_and_boundary_conditions(
        hj.sets.Box(np.array([a.grid_min[0], a.grid_min[1], -np.pi]),
                    np.array([a.grid_max[0], a.grid_max[1], np.pi])),
        tuple(a.shape), periodic_dims=2)
    target = jnp.linalg.norm(grid.states[..., :2], axis=-1) - a.radius     # l(x): the obstacle's signed distance
    settings = hj.SolverSettings.with_accuracy(
        a.accuracy, hamiltonian_postprocessor=hj.solver.backwards_reachable_tube)
    dynamics = DubinsAvoid(a.speed, a.omega_max)
    t0 = time.perf_counter()
    values = hj.solve(settings, dynamics, grid, np.array([0.0, -a.horizon]), target, progress_bar=False)
    value = np.asarray(jax.block_until_ready(values[-1]), dtype=np.float32)
    solve_time = time.perf_counter() - t0

    # the same nodes in float64 (jax computes them in float32, a few ulp off)
    x = np.linspace(a.grid_min[0], a.grid_max[0], a.shape[0])
    y = np.linspace(a.grid_min[1], a.grid_max[1], a.shape[1])
    theta = -np.pi + np.arange(a.shape[2]) * (2 * np.pi / a.shape[2])
    for mine, theirs in zip((x, y, theta), grid.coordinate_vectors):
        assert np.allclose(mine, np.asarray(theirs), atol=1e-5), 'grid conventions differ'
    meta = {'solver': f'hj_reachability {hj.__version__}', 'jax': jax.__version__,
            'accuracy': a.accuracy, 'speed': a.speed, 'omega_max': a.omega_max,
            'radius': a.radius, 'horizon': a.horizon, 'solve_time_s': solve_time,
            'process_time_to_save_s': time.perf_counter() - T_START}
    np.savez(a.out, value=value, x=x, y=y, theta=theta, meta=np.array(json.dumps(meta)))
    print(json.dumps(meta))


if __name__ == '__main__':
    main()
