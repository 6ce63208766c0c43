"""The supervisor models side by side: one study JSON per model -> the comparison tables.

``python -m supersafe_ros.study.model_comparison A/study.json B/study.json ...`` prints, as
Markdown (docs/study.md, "Supervisor models: the comparison"), one row per study (its
``options.supervisor``) and the paper's row:

* Table 1: false positives per game and the ratio to Standard for every condition, with
  the crashes and trips beside them (sums over subjects);
* the paired tests (``posthoc``, Holm): mean difference and p of Standard - Learned,
  Standard - Conservative and Learned - Conservative, with both conditions' crashes, and
  the repeated-measures ANOVA;
* the model validity (``validity``): Learned and Conservative predicted from Phase II
  against observed, and the share of Learned's false positives that came after the filter
  had turned the robot away (skirting).

Nothing is computed here that the study did not store; the numbers are the JSONs'.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys

from .analysis import LABELS, PAPER_STATS, PAPER_TABLE1, ordered

PAIRS = ('standard-learned', 'standard-conservative', 'learned-conservative')


def load(path) -> dict:
    doc = json.loads(Path(path).read_text())
    doc['_path'] = str(path)
    return doc


def model_name(doc: dict) -> str:
    return str(doc.get('options', {}).get('supervisor', 'memoryless'))


def _pct(x) -> str:
    return f'{100 * x:.1f} %' if x is not None and x == x else '-'


def table1_rows(docs) -> list:
    conditions = ordered({c for d in docs for c in d['conditions']})
    head = '| supervisor | ' + ' | '.join(LABELS[c] for c in conditions) + ' |'
    lines = [head, '|---' * (len(conditions) + 1) + '|']
    for d in docs:
        cells = []
        for c in conditions:
            v = d['conditions'].get(c)
            if v is None:
                cells.append('')
                continue
            n = len(v['false_positives'])
            ratio = '' if c == 'standard' else f' ({_pct(v["observed_fp_ratio"])})'
            cells.append(f'{sum(v["false_positives"]) / n:.2f}{ratio}; {sum(v["crashes"])} crashes, '
                         f'{sum(v["trips"])} trips')
        lines.append(f'| {model_name(d)} | ' + ' | '.join(cells) + ' |')
    paper = []
    for c in conditions:
        p = PAPER_TABLE1.get(c)
        paper.append('' if p is None else f'{p["average_fp"]:.2f}'
                     + ('' if c == 'standard' else f' ({_pct(p["observed_fp_ratio"])})'))
    lines.append('| paper | ' + ' | '.join(paper) + ' |')
    return lines


def posthoc_rows(docs) -> list:
    lines = ['| supervisor | ' + ' | '.join(f'{LABELS[a]} - {LABELS[b]}' for a, b in (p.split('-') for p in PAIRS))
             + ' | ANOVA |', '|---' * (len(PAIRS) + 2) + '|']
    for d in docs:
        cells = []
        for pair in PAIRS:
            r = d['posthoc']['pairs'].get(pair)
            if r is None:
                cells.append('')
                continue
            a, b = pair.split('-')
            crashes = r.get('crashes') or [sum(d['conditions'][a]['crashes']), sum(d['conditions'][b]['crashes'])]
            cells.append(f'{r["mean_difference"]:+.2f} FP, p {r["p"]:.2g}'
                         + (f'; crashes {crashes[0]} / {crashes[1]}' if crashes else ''))
        a = d['anova']
        cells.append(f'F({a["df_num"]:g}, {a["df_den"]:g}) = {a["F"]:.3g}, p {a["p"]:.2g}')
        lines.append(f'| {model_name(d)} | ' + ' | '.join(cells) + ' |')
    lines.append('| paper (Tukey) | ' + ' | '.join(PAPER_STATS['tukey'].get(p, '') for p in PAIRS)
                 + f' | {PAPER_STATS["anova"]} |')
    return lines


def validity_rows(docs) -> list:
    lines = ['| supervisor | Learned: predicted / observed / games-predicted | Conservative: predicted / '
             'observed | Learned FP after the filter turned the robot away |', '|---|---|---|---|']
    for d in docs:
        pooled, gap = d['validity']['pooled'], d['validity']['gap']
        cells = []
        for c, games in (('learned', True), ('conservative', False)):
            r = pooled.get(c)
            cells.append('' if r is None else f'{_pct(r["predicted"])} / {_pct(r["observed"])}'
                         + (f' / {_pct(r["games_predicted"])}' if games else ''))
        g = gap.get('learned') or {}
        cells.append(f'{_pct(g.get("fp_after_override"))} of {g.get("false_positives", "-")}')
        lines.append(f'| {model_name(d)} | ' + ' | '.join(cells) + ' |')
    p = PAPER_TABLE1
    lines.append(f'| paper | {_pct(p["learned"]["predicted_fp_ratio"])} / {_pct(p["learned"]["observed_fp_ratio"])}'
                 f' | {_pct(p["conservative"]["predicted_fp_ratio"])} / '
                 f'{_pct(p["conservative"]["observed_fp_ratio"])} | |')
    return lines


def comparison(docs) -> str:
    """The three tables (module doc) as Markdown."""
    return '\n'.join(['Table 1: false positives per game (ratio to Standard); crashes and trips, sums over '
                      'subjects', ''] + table1_rows(docs)
                     + ['', 'Paired tests (Holm; mean difference in FP per game) with the crashes of both '
                        'conditions', ''] + posthoc_rows(docs)
                     + ['', 'Model validity (pooled)', ''] + validity_rows(docs))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('studies', nargs='+', type=Path, help='study.json of each model')
    args = ap.parse_args(argv)
    try:
        docs = [load(p) for p in args.studies]
    except (OSError, ValueError) as exc:
        print(f'model_comparison: {exc}', file=sys.stderr)
        return 2
    print(comparison(docs))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
