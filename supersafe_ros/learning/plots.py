"""The paper's figure of a learned safe set: interventions over the learned value at
theta = 0 with its mu level set, beside the standard set (true dynamics).

matplotlib is imported lazily with the Agg backend (no display needed).
"""
from __future__ import annotations

import os

import numpy as np

from ..reach.value_function import ValueFunction


def theta_slice(vf: ValueFunction, theta=0.0, n=201):
    """(X, Y, V) on an n x n mesh of vf's rectangle at heading ``theta`` (interpolated)."""
    g = vf.grid
    xs = np.linspace(g.lo[0], g.hi[0], n)
    ys = np.linspace(g.lo[1], g.hi[1], n)
    X, Y = np.meshgrid(xs, ys, indexing='xy')
    states = np.stack([X, Y, np.full_like(X, theta)], axis=-1)
    return X, Y, vf.value(states)


def plot_fit(path, learned: ValueFunction, mu: float, interventions, standard: ValueFunction | None,
             *, alpha=None, title=None, radius=None, theta_tol=0.2) -> str:
    """Write a PNG: left, the learned V at theta = 0 (colour, black contours) with its mu
    level set (red) and the intervention states (red circles; those with |theta| >
    theta_tol are hollow grey, as they are not on this slice); right, the standard set's
    zero level (blue, shaded unsafe) with the learned mu level set overlaid."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    s = np.asarray(interventions, dtype=float).reshape(-1, 3)
    on_slice = np.abs((s[:, 2] + np.pi) % (2 * np.pi) - np.pi) <= theta_tol
    ncols = 2 if standard is not None else 1
    fig, axes = plt.subplots(1, ncols, figsize=(6.2 * ncols, 5.4), squeeze=False)
    axes = axes[0]
    X, Y, V = theta_slice(learned)
    ax = axes[0]
    mesh = ax.pcolormesh(X, Y, V, shading='auto', cmap='viridis')
    fig.colorbar(mesh, ax=ax, label='learned V (theta = 0)')
    ax.contour(X, Y, V, levels=10, colors='k', linewidths=0.4)
    ax.contour(X, Y, V, levels=[mu], colors='r', linewidths=2.0)
    if alpha is not None and abs(alpha - mu) > 1e-9:
        ax.contour(X, Y, V, levels=[alpha], colors='orange', linewidths=1.5, linestyles='--')
    ax.plot(s[on_slice, 0], s[on_slice, 1], 'o', mfc='none', mec='r', mew=1.5, ms=6,
            label=f'interventions ({int(on_slice.sum())})')
    if (~on_slice).any():
        ax.plot(s[~on_slice, 0], s[~on_slice, 1], 'o', mfc='none', mec='0.6', ms=4,
                label=f'off-slice ({int((~on_slice).sum())})')
    w = learned.meta.get('omega_max')
    ax.set_title(f'learned: omega_max {w:g}, mu level {mu:.3g}' if w is not None else
                 f'learned: mu level {mu:.3g}')
    _decorate(ax, radius if radius is not None else learned.meta.get('radius'))
    ax.legend(loc='lower left', fontsize=8)
    if standard is not None:
        ax = axes[1]
        Xs, Ys, Vs = theta_slice(standard)
        ax.contourf(Xs, Ys, Vs, levels=[Vs.min() - 1.0, 0.0], colors=['#c6dbef'])
        ax.contour(Xs, Ys, Vs, levels=[0.0], colors='b', linewidths=2.0)
        ax.contour(X, Y, V, levels=[mu], colors='r', linewidths=1.5, linestyles='--')
        ax.plot(s[on_slice, 0], s[on_slice, 1], 'o', mfc='none', mec='r', ms=4)
        ws = standard.meta.get('omega_max')
        ax.set_title('standard set (blue: V = 0' + (f', omega_max {ws:g})' if ws is not None else ')')
                     + '\nred dashed: learned mu level')
        _decorate(ax, radius if radius is not None else standard.meta.get('radius'))
    lo, hi = _view(learned, s, standard)
    for a in axes:
        a.set_xlim(lo[0], hi[0])
        a.set_ylim(lo[1], hi[1])
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = os.fspath(path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _view(learned, states, standard, pad=1.5):
    """Zoom on the interventions and the standard unsafe set (within the grid)."""
    g = learned.grid
    pts = [states[:, :2]]
    if standard is not None:
        X, Y, V = theta_slice(standard, n=101)
        pts.append(np.stack([X[V <= 0], Y[V <= 0]], axis=1))
    pts = np.concatenate([p for p in pts if len(p)] or [np.zeros((1, 2))])
    lo = np.maximum(pts.min(axis=0) - pad, g.lo)
    hi = np.minimum(pts.max(axis=0) + pad, g.hi)
    return lo, hi


def _decorate(ax, radius):
    if radius:
        t = np.linspace(0, 2 * np.pi, 200)
        ax.fill(radius * np.cos(t), radius * np.sin(t), color='0.3', alpha=0.8, lw=0)
    ax.set_aspect('equal')
    ax.set_xlabel('x [m] (obstacle frame)')
    ax.set_ylabel('y [m]')
