"""`supersafe session --analyse DIR...`: the researcher's view of a study's folders.

1. Every participant found (a folder with session.json or subject.json) with its state:
   complete, or incomplete and the phase it reached.
2. The complete ones (human and simulated alike) through the study's ``summarize``; from
   its result ``table1``, ``conditions``, ``anova`` and ``posthoc`` are read. A subject's
   count per treatment is the mean over the treatment's games (two each in the paper's
   form, one in the short form and in the simulated study's same-world form). A
   descriptive table always; the repeated-measures ANOVA and the paired post-hoc tests
   (Holm; Tukey's independent-groups p beside them as a reference) only with at least
   MIN_SUBJECTS_FOR_TESTS subjects, else a plain statement that no test is meaningful (and
   no test's warnings).
3. The questionnaires (``study.subjective``): per comparison and item, both teams' mean
   ratings and, from MIN_SUBJECTS_FOR_TESTS answering participants, the paper's tests
   (repeated-measures ANOVA of the two teams' ratings; preference against neutral).
   Simulated supervisors answer no questionnaire: the analysis says how many subjects
   that leaves out.
4. ``--csv NAME.csv``: one row per participant and game (treatment, comparison, place in
   the pair, task version, counts, H2 measures), and NAME_answers.csv beside it: one row
   per participant, comparison and item (both teams' ratings; for preference the rating
   and its value turned towards the second-named treatment), for R or SPSS; ``--json``:
   the summary, the subjective analysis, the answers and the listing.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path
import sys
import warnings

import numpy as np

from ..study.subjective import PREFERENCE, TEAM_ITEMS, format_subjective, ratings, subjective_analysis
from .protocol import load_subject

MIN_SUBJECTS_FOR_TESTS = 3
COUNTS = ('false_positives', 'interventions', 'crashes', 'trips')
MEASURES = ('path_per_trip', 'avoidance_length', 'override_fraction', 'min_clearance')


def phase_reached(data: dict) -> str:
    """Where an unfinished session.json stopped, in words."""
    scenes, offsets = len(data.get('scenes') or []), len(data.get('offsets') or [])
    design = data.get('plan') or {}
    n_games, n_questions = len(design.get('games') or []) or 3, len(design.get('questionnaires') or []) or 2
    games = len(data['plays']) if 'plays' in data else len(data.get('games') or {})
    answers = len(data.get('answers') or [])
    if not scenes and data.get('phase1') is None:
        return 'Phase I (not started or interrupted)'
    if scenes < offsets:
        return f'Phase II, {scenes} of {offsets} scenes'
    if data.get('fit') is None:
        return 'the fit'
    if games < n_games or answers < n_questions:
        return f'Phase III, {games} of {n_games} games, {answers} of {n_questions} questionnaires'
    return 'the end (subject.json not written)'


def find_participants(dirs) -> list:
    """[{'dir', 'participant', 'kind', 'state', 'complete'}] for every folder under ``dirs``
    holding a session.json or a subject.json, sorted by path."""
    folders = sorted({p.parent for d in dirs for name in ('session.json', 'subject.json')
                      for p in Path(d).rglob(name)})
    out = []
    for folder in folders:
        entry = {'dir': str(folder), 'participant': folder.name, 'kind': 'simulated', 'complete': False}
        session = folder / 'session.json'
        try:
            data = json.loads(session.read_text()) if session.exists() else None
        except (OSError, ValueError) as exc:
            entry.update(kind='human', state=f'unreadable session.json ({exc})')
            out.append(entry)
            continue
        if data is not None:
            entry.update(kind='human', participant=str(data.get('participant', folder.name)))
        if (folder / 'subject.json').exists() and (data is None or data.get('complete')):
            entry.update(state='complete', complete=True)
        else:
            entry['state'] = f'incomplete: {phase_reached(data or {})}'
        out.append(entry)
    return out


def _mean_sd(values) -> str:
    v = np.array([x for x in values if x is not None], dtype=float)
    v = v[np.isfinite(v)]
    if not len(v):
        return '-'
    return f'{v.mean():.2f}' + (f' ({v.std(ddof=1):.2f})' if len(v) > 1 else '')


def descriptive_table(summary: dict) -> str:
    """Per condition: the counts' mean (sd) over subjects, and Table 1's pooled Phase II
    column (interventions the condition's set would leave alone)."""
    heads = ('False positives', 'Interventions', 'Crashes', 'Trips', 'Phase II in set')
    lines = [f'{"condition":14s}' + ''.join(f'{h:>17s}' for h in heads)]
    for c, row in summary['conditions'].items():
        t1 = summary['table1'].get(c, {})
        inside = f'{t1.get("inside", 0)} / {t1.get("total", 0)}'
        lines.append(f'{c:14s}' + ''.join(f'{_mean_sd(row[k]):>17s}' for k in COUNTS) + f'{inside:>17s}')
    return '\n'.join(lines)


def _plain(row: dict) -> dict:
    return {k: ('' if v is None or (isinstance(v, float) and not math.isfinite(v)) else v) for k, v in row.items()}


def record_form(r: dict) -> str:
    """A record's Phase III form: paper, short (a session) or same-world (the simulated study's
    default); records from before the plan: short for a human, same-world for a simulated one."""
    default = 'short' if r['subject'].get('kind') == 'human' else 'same-world'
    return (r.get('design') or {}).get('form', default)


def subject_plays(r: dict) -> list:
    """A record's games one by one: ``plays`` (a session; the study's paper form), or one per
    treatment of ``games`` (the study's same-world form, older sessions)."""
    if r.get('plays'):
        return r['plays']
    order = list(r['subject'].get('order') or r['games'])
    return [dict(g, treatment=c, game=order.index(c) + 1 if c in order else '') for c, g in r['games'].items()]


def csv_rows(records: list) -> list:
    """One dict per participant and game: treatment, comparison, place in the pair, task
    version and world seed, the set that ran, counts and H2 measures."""
    rows = []
    for r in records:
        subject = r['subject']
        pid = str(subject.get('participant', subject.get('index')))
        form = record_form(r)
        for g in subject_plays(r):
            row = {'participant': pid, 'kind': subject.get('kind', 'simulated'), 'form': form,
                   'game': g.get('game', ''), 'treatment': g['treatment'], 'comparison': g.get('comparison'),
                   'position_in_pair': g.get('position_in_pair'), 'version': g.get('version'),
                   'world_seed': g.get('world_seed'), 'ran': g.get('played', g.get('set', g['treatment'])),
                   'alpha': g.get('alpha')}
            row.update({k: g.get(k) for k in COUNTS + ('sim_time',) + MEASURES})
            rows.append(_plain(row))
    return rows


def answer_rows(records: list) -> list:
    """One dict per participant, comparison and item: the two games, their treatments and
    ratings (for preference: the raw rating, and ``towards_second_named`` = the rating
    turned towards the comparison's second-named treatment, 4 = neutral)."""
    rows = []
    for r in records:
        pid = str(r['subject'].get('participant', r['subject'].get('index')))
        for a in r.get('answers') or []:
            got = ratings(a, a.get('comparison', ''))
            if not got:
                continue
            games, treatments, values = a['games'], a['treatments'], a['values']
            base = {'participant': pid, 'comparison': a['comparison'], 'after_game': a.get('after_game'),
                    'first_game': games[0], 'first_treatment': treatments[0],
                    'second_game': games[1], 'second_treatment': treatments[1]}
            for key, _ in TEAM_ITEMS:
                rows.append(_plain(dict(base, item=key, first_rating=values[key][0], second_rating=values[key][1],
                                        preference='', towards_second_named='')))
            rows.append(_plain(dict(base, item=PREFERENCE[0], first_rating='', second_rating='',
                                    preference=values[PREFERENCE[0]], towards_second_named=got[2])))
    return rows


def write_csv(path, rows: list) -> None:
    columns = []
    for row in rows:
        columns += [k for k in row if k not in columns]
    with open(path, 'w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=columns, restval='')
        w.writeheader()
        w.writerows(rows)


def analyse(dirs, json_path=None, csv_path=None, out=sys.stdout) -> int:
    from ..study.analysis import LABELS
    from ..study.posthoc import format_posthoc
    from ..study.protocol import reference_sets
    from ..study.records import jsonable
    from ..study.summary import summarize
    found = find_participants(dirs)
    if not found:
        print(f'no participant (session.json or subject.json) under {[str(d) for d in dirs]}', file=sys.stderr)
        return 2
    print(f'{len(found)} participants:', file=out)
    for e in found:
        print(f'  {e["participant"]:16s} {e["kind"]:9s} {e["state"]:50s} {e["dir"]}', file=out)
    complete = [e for e in found if e['complete']]
    if not complete:
        print('no complete participant yet: nothing to analyse', file=out)
        return 0
    records = [load_subject(e['dir']) for e in complete]
    n = len(records)
    humans = sum(1 for r in records if r['subject'].get('kind') == 'human')
    standard, conservative = reference_sets()
    with warnings.catch_warnings(), np.errstate(all='ignore'):
        if n < MIN_SUBJECTS_FOR_TESTS:     # the tests inside summarize divide by zero; not shown
            warnings.simplefilter('ignore')
        summary = summarize(records, standard, conservative)
    print(f'\n{n} complete ({humans} human, {n - humans} simulated): mean (sd) per subject', file=out)
    print(descriptive_table(summary), file=out)
    forms = sorted({record_form(r) for r in records})
    print(f'Phase III forms: {", ".join(forms)} (a treatment played twice counts as the mean of its two games)',
          file=out)
    if n < MIN_SUBJECTS_FOR_TESTS:
        print(f'\nWith {n} subject{"s" if n != 1 else ""} no statistical test is meaningful (at least '
              f'{MIN_SUBJECTS_FOR_TESTS} are needed): the table is descriptive only.', file=out)
    else:
        a = summary['anova']
        print(f"\nrepeated-measures ANOVA (false positives, {n} subjects): F({a['df_num']:g}, {a['df_den']:g}) = "
              f"{a['F']:.3g}, p = {a['p']:.3g}" + (f"  ({a['note']})" if 'note' in a else ''), file=out)
        if summary.get('posthoc'):
            print(format_posthoc(summary['posthoc'], LABELS, tukey=summary.get('tukey')), file=out)
    answered = [r for r in records if r.get('answers')]
    subjective = subjective_analysis([r['answers'] for r in answered])
    print(f'\nquestionnaires: {len(answered)} of {n} subjects answered', file=out)
    if n - humans:
        print(f'({n - humans} simulated subject{"s" if n - humans != 1 else ""}: a simulated supervisor answers '
              'no questionnaire, so only the human participants enter this analysis)', file=out)
    if answered:
        with warnings.catch_warnings(), np.errstate(all='ignore'):
            warnings.simplefilter('ignore')
            print(format_subjective(subjective, LABELS), file=out)
    if csv_path:
        rows = csv_rows(records)
        write_csv(csv_path, rows)
        print(f'\n{len(rows)} rows (participant x game) in {csv_path}', file=out)
        arows = answer_rows(records)
        apath = Path(csv_path).with_name(Path(csv_path).stem + '_answers.csv')
        write_csv(apath, arows)
        print(f'{len(arows)} rows (participant x comparison x item) in {apath}', file=out)
    if json_path:
        doc = {'participants': found, 'table1': summary['table1'], 'conditions': summary['conditions'],
               'anova': summary['anova'] if n >= MIN_SUBJECTS_FOR_TESTS else None,
               'posthoc': summary.get('posthoc') if n >= MIN_SUBJECTS_FOR_TESTS else None,
               'tests_meaningful': n >= MIN_SUBJECTS_FOR_TESTS,
               'subjective': subjective, 'answered': len(answered),
               'answers': {str(r['subject'].get('participant', r['subject'].get('index'))): r['answers']
                           for r in records if r.get('answers')}}
        Path(json_path).write_text(json.dumps(jsonable(doc), indent=1))
    return 0
