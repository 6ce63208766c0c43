"""Figures of value functions (matplotlib, headless)."""
from __future__ import annotations

import numpy as np


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def theta_slice(vf, theta=0.0) -> np.ndarray:
    """V on the (x, y) nodes at heading ``theta`` (interpolated between slices)."""
    X, Y = np.meshgrid(vf.grid.x, vf.grid.y, indexing='ij')
    return vf.value(np.stack([X, Y, np.full_like(X, theta)], axis=-1))


def plot_library(lib, path, theta=0.0) -> None:
    """Zero level sets of every entry at heading theta (the paper's library figure)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 5.6))
    cmap = plt.get_cmap('viridis')
    omegas = lib.omegas
    for i, vf in enumerate(lib.entries):
        Z = theta_slice(vf, theta)
        color = cmap(i / max(1, len(lib.entries) - 1))
        ax.contour(vf.grid.x, vf.grid.y, Z.T, levels=[0.0], colors=[color], linewidths=1.4)
        ax.plot([], [], color=color, label=f'$\\omega_{{max}}$ = {omegas[i]:g}')
    ax.add_patch(plt.Circle((0, 0), lib.spec.radius, color='0.3', alpha=0.5))
    ax.set_aspect('equal')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.set_title(f'Zero level sets at $\\theta$ = {theta:g} (speed {lib.spec.speed:g}, '
                 f'horizon {lib.spec.horizon} s)')
    ax.legend(fontsize=7, loc='upper left', ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
