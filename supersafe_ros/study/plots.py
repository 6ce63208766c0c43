"""The study's figures (PNG): the paper's Figs. 5 (FP per set), 6 (learned sets), 7
(Phase II interventions over reachable sets) and the alpha sweep of Sec. II-D."""
from __future__ import annotations

import numpy as np

from ..reach.plots import theta_slice as _slice
from .analysis import CONDITIONS, significance_stars


def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def plot_false_positives(path, fp: dict, tukey: dict) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 4))
    means = [np.mean(fp[c]) for c in CONDITIONS]
    sems = [np.std(fp[c], ddof=1) / np.sqrt(len(fp[c])) if len(fp[c]) > 1 else 0 for c in CONDITIONS]
    ax.bar(range(3), means, yerr=sems, capsize=4, color=['0.55', 'tab:blue', 'tab:orange'])
    for i, c in enumerate(CONDITIONS):
        ax.scatter(np.full(len(fp[c]), i) + np.linspace(-0.15, 0.15, len(fp[c])), fp[c],
                   s=10, color='k', zorder=3)
    top = max(max(np.max(fp[c]) for c in CONDITIONS), 1) * 1.1
    for n, (a, b) in enumerate([(0, 1), (0, 2), (1, 2)]):
        key = f'{CONDITIONS[a]}-{CONDITIONS[b]}'
        if key in tukey:
            y = top * (1 + 0.12 * n)
            ax.plot([a, a, b, b], [y, y * 1.02, y * 1.02, y], color='k', lw=1)
            ax.text((a + b) / 2, y * 1.03, significance_stars(tukey[key]['p']), ha='center')
    ax.set_xticks(range(3), [c.capitalize() for c in CONDITIONS])
    ax.set_ylabel('False positives per game')
    ax.set_title('False positives per safe set (Tukey HSD)')
    ax.set_ylim(0, top * 1.5)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_learned_sets(path, standard, conservative, learned: list, radius: float) -> None:
    """learned: list of (value_function, alpha, label)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 5))
    g = standard.grid
    ax.contour(g.x, g.y, _slice(standard).T, levels=[0.0], colors='k', linewidths=2)
    ax.contour(conservative.grid.x, conservative.grid.y, _slice(conservative).T, levels=[0.0],
               colors='tab:orange', linewidths=2)
    cmap = plt.get_cmap('winter')
    for i, (vf, alpha, label) in enumerate(learned):
        ax.contour(vf.grid.x, vf.grid.y, _slice(vf).T, levels=[alpha],
                   colors=[cmap(i / max(1, len(learned) - 1))], linewidths=1, linestyles='--')
    ax.plot([], [], 'k', label='Standard')
    ax.plot([], [], color='tab:orange', label='Conservative')
    ax.plot([], [], 'b--', label='Learned (one per subject)')
    ax.add_patch(plt.Circle((0, 0), radius, color='0.4', alpha=0.4))
    ax.set_aspect('equal')
    ax.legend(loc='upper left', fontsize=8)
    ax.set_title('Learned safe sets at $\\theta$ = 0 over the baselines')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_phase2(path, states, standard, conservative, radius: float) -> None:
    plt = _plt()
    s = np.asarray(states).reshape(-1, 3)
    fig, ax = plt.subplots(figsize=(6, 5))
    g = standard.grid
    ax.contour(g.x, g.y, _slice(standard).T, levels=[0.0], colors='k', linewidths=1.5)
    ax.contour(conservative.grid.x, conservative.grid.y, _slice(conservative).T, levels=[0.0],
               colors='tab:orange', linewidths=1.5)
    if len(s):
        in_cons = conservative.value(s) <= 0
        in_std = standard.value(s) <= 0
        ax.scatter(s[~in_cons, 0], s[~in_cons, 1], s=12, color='tab:green',
                   label=f'in both safe sets ({np.sum(~in_cons & ~in_std)})')
        ax.scatter(s[in_cons & ~in_std, 0], s[in_cons & ~in_std, 1], s=12, color='tab:red',
                   label=f'inside Conservative reachable set ({np.sum(in_cons & ~in_std)})')
        ax.scatter(s[in_std, 0], s[in_std, 1], s=12, color='0.2',
                   label=f'inside Standard reachable set ({np.sum(in_std)})')
    ax.add_patch(plt.Circle((0, 0), radius, color='0.4', alpha=0.4))
    ax.set_aspect('equal')
    ax.set_xlim(-8, 4)
    ax.set_ylim(-5, 5)
    ax.legend(loc='upper left', fontsize=7)
    ax.set_title('Phase II interventions over the reachable sets ($\\theta$ = 0)')
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_alpha_sweep(path, sweep: dict) -> None:
    """sweep: label -> dict(predicted=[...per subject], observed=[...] or None)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 4))
    labels = list(sweep)
    pred = [np.mean(sweep[k]['predicted']) for k in labels]
    ax.plot(range(len(labels)), pred, 'o-', label='predicted (Phase II states inside)')
    if all(sweep[k].get('observed') is not None for k in labels):
        obs = [np.mean(sweep[k]['observed']) for k in labels]
        ax2 = ax.twinx()
        ax2.plot(range(len(labels)), obs, 's--', color='tab:red', label='observed FP per game')
        ax2.set_ylabel('observed false positives per game', color='tab:red')
        ax2.set_ylim(bottom=0)
    ax.set_xticks(range(len(labels)), labels)
    ax.set_ylabel('fraction of interventions inside the set')
    ax.set_ylim(0, 1)
    ax.set_title('Raising alpha drives false positives down')
    ax.legend(loc='upper right', fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
