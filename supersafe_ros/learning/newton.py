"""A projected Newton maximiser for many independent 2-parameter problems at once.

The first-passage estimator maximises one log-likelihood per library entry over the
natural parameters (eta, tau) = (mu/sigma, 1/sigma) within box bounds; each is
log-concave, so Newton converges in a few steps, and running every entry's problem
as one row of an array keeps the cost in numpy rather than in a Python loop.

Per row, with f the function, g its gradient and H its Hessian (by finite differences
of g), a step solves (H - s I) d = -g, where the shift s >= 0 makes H - s I negative
definite, so d ascends; a coordinate at a bound whose gradient points out of the box
is held there; the step length halves until Armijo's condition
f(x + t d) >= f(x) + 1e-4 t g.d holds.
"""
from __future__ import annotations

import numpy as np


def newton_maximise(fun, x, lower, upper, max_iter=100, tol=1e-10):
    """Maximise m independent smooth 2-parameter functions at once, within box bounds.

    fun(x (k, 2), rows) -> (f (k,), g (k, 2)) for the given rows (None: all m rows).
    Projected Newton with a finite-difference Hessian of the analytic gradient, made
    negative definite when it is not, a coordinate held at a bound while the gradient
    pushes it out, and a per-row Armijo backtracking line search. Stops when every
    row's Newton decrement g.d is below ``tol`` times (1 + |f|). Returns x (m, 2), f (m,).
    """
    f, g = fun(x, None)
    active = np.ones(len(x), dtype=bool)
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        xa, ga = x[idx], g[idx]
        H = np.empty((idx.size, 2, 2))
        for j in range(2):
            h = 1e-6 * np.maximum(1.0, np.abs(xa[:, j]))
            xh = xa.copy()
            # difference inward from an upper bound, outward from a lower one
            xh[:, j] = np.where(xa[:, j] + h > upper[j], xa[:, j] - h, xa[:, j] + h)
            _, gh = fun(xh, idx)
            H[:, :, j] = (gh - ga) / (xh[:, j] - xa[:, j])[:, None]
        H = 0.5 * (H + np.swapaxes(H, 1, 2))
        # bounds: freeze a coordinate sitting on a bound with the gradient pointing out
        frozen = np.stack([(xa[:, j] <= lower[j]) & (ga[:, j] < 0) |
                           (xa[:, j] >= upper[j]) & (ga[:, j] > 0) for j in range(2)], axis=1)
        # make -H positive definite (Levenberg shift) so that d = -H^-1 g ascends
        eig_max = np.linalg.eigvalsh(H)[:, -1]
        shift = np.where(eig_max >= 0.0, eig_max + 1e-8 * (1.0 + np.abs(H).max(axis=(1, 2))), 0.0)
        Hn = H - shift[:, None, None] * np.eye(2)
        gf = np.where(frozen, 0.0, ga)
        Hn[:, 0, 1] = np.where(frozen.any(axis=1), 0.0, Hn[:, 0, 1])
        Hn[:, 1, 0] = Hn[:, 0, 1]
        d = -np.linalg.solve(Hn, gf[:, :, None])[:, :, 0]
        decrement = np.sum(gf * d, axis=1)
        done = decrement <= tol * (1.0 + np.abs(f[idx]))
        step = np.ones(idx.size)
        pending = ~done
        for _ls in range(60):
            if not pending.any():
                break
            rows = idx[pending]
            xn = np.clip(x[rows] + step[pending, None] * d[pending], lower, upper)
            fn, gn = fun(xn, rows)
            ok = np.isfinite(fn) & (fn >= f[rows] + 1e-4 * step[pending] * decrement[pending])
            x[rows[ok]], f[rows[ok]], g[rows[ok]] = xn[ok], fn[ok], gn[ok]
            sub = np.flatnonzero(pending)
            step[sub[~ok]] *= 0.5
            pending[sub[ok]] = False
        done |= pending           # no ascent along d: converged to rounding
        active[idx[done]] = False
    return x, f
