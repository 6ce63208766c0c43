"""The study's figures (PNG): the paper's Figs. 5 (FP per set), 6 (learned sets), 7
(Phase II interventions over reachable sets), the model validity of Sec. V-C
(``validity``), the alpha sweep of Sec. II-D and the H2 efficiency panel (Sec. V-B);
``make_plots`` draws them all for one study."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..learning.levels import learned_alpha
from ..reach.plots import theta_slice as _slice
from .analysis import H2_MEASURES, LABELS, ordered, significance_stars
from .protocol import TRUE_RADIUS
from .records import record_learned

COLORS = {'standard': '0.55', 'learned': 'tab:blue', 'learned_fp': 'tab:green',
          'learned_online': 'tab:purple', 'conservative': 'tab:orange'}


def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _save(plt, fig, path, dpi: int) -> None:
    """Lay out, write and free a figure (pyplot keeps every open figure otherwise)."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def plot_false_positives(path, fp: dict, tests: dict) -> None:
    """Mean FP per set (SEM bars, subjects as dots) with the paired post-hoc tests' stars
    (Holm-corrected; ``tests``: posthoc['pairs'])."""
    plt = _plt()
    conds = ordered(fp)
    n = len(conds)
    fig, ax = plt.subplots(figsize=(1.5 + 1.2 * n, 4))
    means = [np.mean(fp[c]) for c in conds]
    sems = [np.std(fp[c], ddof=1) / np.sqrt(len(fp[c])) if len(fp[c]) > 1 else 0 for c in conds]
    ax.bar(range(n), means, yerr=sems, capsize=4, color=[COLORS[c] for c in conds])
    for i, c in enumerate(conds):
        ax.scatter(np.full(len(fp[c]), i) + np.linspace(-0.15, 0.15, len(fp[c])), fp[c],
                   s=10, color='k', zorder=3)
    top = max(max(np.max(fp[c]) for c in conds), 1) * 1.1
    pairs = [(a, b) for a in range(n) for b in range(a + 1, n)]
    for k, (a, b) in enumerate(pairs):
        key = f'{conds[a]}-{conds[b]}'
        if key in tests:
            y = top * (1 + 0.1 * k)
            ax.plot([a, a, b, b], [y, y * 1.02, y * 1.02, y], color='k', lw=1)
            ax.text((a + b) / 2, y * 1.03, significance_stars(tests[key]['p']), ha='center', fontsize=8)
    ax.set_xticks(range(n), [LABELS[c] for c in conds])
    ax.set_ylabel('False positives per game')
    ax.set_title('False positives per safe set (paired t, Holm)')
    ax.set_ylim(0, top * (1.2 + 0.1 * len(pairs)))
    _save(plt, fig, path, dpi=120)


def plot_efficiency(path, conditions: dict, h2: dict) -> None:
    """H2: one panel per measure, subjects as lines across the conditions; the title of the
    arc panel gives the paper's comparison (learned arcs shorter than conservative)."""
    plt = _plt()
    conds = ordered(conditions)
    titles = {'path_per_trip': 'path per completed trip [m]',
              'avoidance_length': 'extra length per avoidance arc [m]',
              'override_fraction': 'fraction of robot time overriding',
              'min_clearance': 'minimum clearance to obstacles [m]'}
    fig, axes = plt.subplots(1, len(H2_MEASURES), figsize=(4 * len(H2_MEASURES), 3.8))
    for ax, m in zip(axes, H2_MEASURES):
        v = np.array([[np.nan if x is None else x for x in conditions[c][m]] for c in conds], dtype=float)
        for s in range(v.shape[1]):
            ax.plot(range(len(conds)), v[:, s], '-', color='0.8', lw=0.8, zorder=1)
        for i, c in enumerate(conds):
            ax.scatter(np.full(v.shape[1], i), v[i], s=12, color=COLORS[c], zorder=2)
            if np.any(np.isfinite(v[i])):
                ax.plot([i - 0.25, i + 0.25], [np.nanmean(v[i])] * 2, color='k', lw=2, zorder=3)
        ax.set_xticks(range(len(conds)), [LABELS[c] for c in conds], fontsize=8)
        title = titles[m]
        if m == 'avoidance_length' and h2.get('shorter_arcs_than_conservative'):
            title += '\n' + ', '.join(f'{LABELS[c]} < Cons.: {r["shorter"]}/{r["of"]}'
                                      for c, r in h2['shorter_arcs_than_conservative'].items()
                                      if c != 'standard') + ' (paper 9/11)'
        ax.set_title(title, fontsize=9)
    fig.suptitle('H2: efficiency per safe set (one line per subject, bar = mean)', fontsize=10)
    _save(plt, fig, path, dpi=110)


def plot_learned_sets(path, standard, conservative, learned: list, radius: float) -> None:
    """learned: list of (value_function, alpha, label[, condition])."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 5))
    g = standard.grid
    ax.contour(g.x, g.y, _slice(standard).T, levels=[0.0], colors='k', linewidths=2)
    ax.contour(conservative.grid.x, conservative.grid.y, _slice(conservative).T, levels=[0.0],
               colors='tab:orange', linewidths=2)
    styles = {'learned': ('tab:blue', '--'), 'learned_fp': ('tab:green', ':')}
    seen = set()
    for item in learned:
        vf, alpha = item[0], item[1]
        cond = item[3] if len(item) > 3 else 'learned'
        seen.add(cond)
        color, style = styles.get(cond, styles['learned'])
        ax.contour(vf.grid.x, vf.grid.y, _slice(vf).T, levels=[alpha],
                   colors=[color], linewidths=1, linestyles=style)
    ax.plot([], [], 'k', label='Standard')
    ax.plot([], [], color='tab:orange', label='Conservative')
    for cond in ordered(seen):
        color, style = styles[cond]
        ax.plot([], [], color=color, linestyle=style, label=f'{LABELS[cond]} (one per subject)')
    ax.add_patch(plt.Circle((0, 0), radius, color='0.4', alpha=0.4))
    ax.set_aspect('equal')
    ax.legend(loc='upper left', fontsize=8)
    ax.set_title('Learned safe sets at $\\theta$ = 0 over the baselines')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    _save(plt, fig, path, dpi=120)


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
    _save(plt, fig, path, dpi=120)


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
    _save(plt, fig, path, dpi=120)


def plot_validity(path, validity: dict) -> None:
    """Model validity: left, observed FP ratio against the predicted share, per subject (small
    marks) and pooled (large, 95 % CIs; hollow: the prediction from the games' own states);
    middle, where the FP came from; right, V - alpha at override onsets by bearing."""
    plt = _plt()
    fig, (ax, bx, cx) = plt.subplots(1, 3, figsize=(14, 4.4))
    top = 1.2
    for c, rows in validity['per_subject'].items():
        for r in rows:
            if np.isfinite(r['predicted']) and np.isfinite(r['observed']):
                ax.plot(r['predicted'], r['observed'], 'o', ms=3.5, alpha=0.45, color=COLORS[c])
                top = max(top, min(r['observed'], 3.0))
    for c, p in validity['pooled'].items():
        if not (np.isfinite(p['predicted']) and np.isfinite(p['observed'])):
            continue
        xerr = [[p['predicted'] - p['predicted_ci'][0]], [p['predicted_ci'][1] - p['predicted']]]
        yerr = [[p['observed'] - p['observed_ci'][0]], [p['observed_ci'][1] - p['observed']]]
        ax.errorbar(p['predicted'], p['observed'], xerr=xerr, yerr=yerr, fmt='s', ms=9, color=COLORS[c],
                    capsize=3, label=f'{LABELS[c]} (pooled)')
        if np.isfinite(p['games_predicted']):
            ax.plot(p['games_predicted'], p['observed'], 's', ms=9, mfc='none', color=COLORS[c])
            ax.annotate('', (p['games_predicted'], p['observed']), (p['predicted'], p['observed']),
                        arrowprops={'arrowstyle': '->', 'color': COLORS[c], 'lw': 0.8})
    ax.plot([0, top], [0, top], 'k:', lw=1)
    ax.set_xlim(0, top)
    ax.set_ylim(0, top)
    ax.set_xlabel('predicted FP vs Standard (Phase II states inside the set)')
    ax.set_ylabel('observed FP vs Standard')
    ax.set_title('Model validity (hollow: predicted from the games\' states)', fontsize=9)
    ax.legend(fontsize=7, loc='upper left')
    conds = list(validity['gap'])
    keys = (('fp_after_override', 'after an override'), ('fp_tangential', 'tangential bearing'),
            ('fp_inside_set', 'inside the set (predicted)'))
    width = 0.8 / len(keys)
    for k, (key, label) in enumerate(keys):
        bx.bar(np.arange(len(conds)) + (k - 1) * width, [validity['gap'][c][key] for c in conds], width,
               label=label)
    bx.set_xticks(range(len(conds)), [f'{LABELS[c]}\n{validity["gap"][c]["false_positives"]} FP' for c in conds],
                  fontsize=8)
    bx.set_ylim(0, 1)
    bx.set_ylabel('share of the false positives')
    bx.set_title('Where the games\' false positives come from', fontsize=9)
    bx.legend(fontsize=7)
    for k, bearing in enumerate(('head-on', 'oblique')):
        med = [validity['gap'][c]['onset_v_minus_alpha'][bearing] for c in conds]
        cx.errorbar(np.arange(len(conds)) + (k - 0.5) * 0.3, [m['median'] for m in med],
                    yerr=[[m['median'] - m['q25'] for m in med], [m['q75'] - m['median'] for m in med]],
                    fmt='o', capsize=3, label=f'{bearing} (median, IQR)')
    cx.axhline(0, color='k', lw=0.8)
    cx.set_xticks(range(len(conds)), [LABELS[c] for c in conds], fontsize=8)
    cx.set_ylabel('V - alpha where overriding starts [m]')
    cx.set_title('How far from its level the filter starts to act', fontsize=9)
    cx.legend(fontsize=7)
    _save(plt, fig, path, dpi=110)


def plot_online(path, report: dict) -> None:
    """False positives per quarter of the game, per condition (learned_online learns during it)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    for c, q in report['fp_per_quarter'].items():
        ax.plot(range(1, len(q) + 1), q, 'o-', color=COLORS[c], lw=2.5 if c == 'learned_online' else 1.2,
                label=LABELS[c])
    ax.set_xticks(range(1, len(q) + 1), [f'Q{k}' for k in range(1, len(q) + 1)])
    ax.set_xlabel('quarter of the 120 s game')
    ax.set_ylabel('false positives (mean over subjects)')
    ax.set_ylim(bottom=0)
    ax.set_title('Learning from the games: false positives across the game', fontsize=9)
    ax.legend(fontsize=7)
    _save(plt, fig, path, dpi=120)


def make_plots(out_dir: Path, summary: dict, records: list, standard_vf, conservative_vf) -> list:
    """Every figure of a study (``summary.summarize``'s ``summary`` of ``records``) into
    ``out_dir``; returns their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    fp = {c: summary['conditions'][c]['false_positives'] for c in summary['conditions']}
    p = out_dir / 'false_positives.png'
    plot_false_positives(p, fp, summary['posthoc']['pairs'])
    paths.append(p)
    p = out_dir / 'efficiency.png'
    plot_efficiency(p, summary['conditions'], summary['h2'])
    paths.append(p)
    learned = []
    for r in records:
        for c, (vf, fit) in record_learned(r).items():
            if vf is not None and c != 'learned_online':      # it starts from learned_fp's set
                learned.append((vf, learned_alpha(fit), f"subject {r['subject']['index']}", c))
    p = out_dir / 'learned_sets.png'
    plot_learned_sets(p, standard_vf, conservative_vf, learned, TRUE_RADIUS)
    paths.append(p)
    states = np.vstack([np.asarray(r['states'], dtype=float).reshape(-1, 3) for r in records])
    p = out_dir / 'phase2_interventions.png'
    plot_phase2(p, states, standard_vf, conservative_vf, TRUE_RADIUS)
    paths.append(p)
    if summary.get('validity', {}).get('pooled'):
        p = out_dir / 'validity.png'
        plot_validity(p, summary['validity'])
        paths.append(p)
    if summary.get('online') and summary['online']['fp_per_quarter']:
        p = out_dir / 'online.png'
        plot_online(p, summary['online'])
        paths.append(p)
    sweep = {label: v for label, v in summary['alpha_sweep'].items() if v['predicted']}
    if sweep:
        p = out_dir / 'alpha_sweep.png'
        plot_alpha_sweep(p, sweep)
        paths.append(p)
    return paths
