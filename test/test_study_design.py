"""Phase III's design as the paper ran it (study.design) and its questionnaire (study.subjective),
without ROS: balance over a block, no treatment first twice, treatment x version balance,
Learned meets Standard for everyone; the per-treatment means; the questionnaire's checks and
the paper's tests."""
from collections import Counter
import itertools
import math

import pytest

from supersafe_ros.study import design as D
from supersafe_ros.study import subjective as Q


def plans(rows):
    return [D.paper_plan(r) for r in rows]


def test_over_a_block_every_comparison_is_in_every_position_equally_often():
    for start in (0, 6, 12, 37):          # any block of BLOCK consecutive rows (a row is taken mod 6)
        block = plans(range(start, start + D.BLOCK))
        places = Counter((g['comparison'], g['comparison_number']) for p in block for g in p['games']
                         if g['position_in_pair'] == 1)
        assert len(places) == 3 * 3 and set(places.values()) == {D.BLOCK // 3}
        # and which treatment goes first is balanced within each comparison
        first = Counter((g['comparison'], g['treatment']) for p in block for g in p['games']
                        if g['position_in_pair'] == 1)
        assert len(first) == 6 and set(first.values()) == {D.BLOCK // 2}
        # carry-over (Williams): each comparison directly follows each other one equally often
        follows = Counter((a, b) for p in block for a, b in zip(
            [q['comparison'] for q in p['questionnaires']], [q['comparison'] for q in p['questionnaires']][1:]))
        assert len(follows) == 6 and set(follows.values()) == {2}


def test_no_participant_has_a_treatment_first_in_a_pair_twice_and_everyone_compares_learned_with_standard():
    for r in range(3 * D.BLOCK):
        p = D.paper_plan(r)
        games = p['games']
        assert [g['game'] for g in games] == [1, 2, 3, 4, 5, 6]
        firsts = [g['treatment'] for g in games if g['position_in_pair'] == 1]
        assert sorted(firsts) == sorted(D.TREATMENTS), (r, firsts)      # each exactly once
        assert Counter(g['treatment'] for g in games) == dict.fromkeys(D.TREATMENTS, 2)
        assert {g['comparison'] for g in games} == {'standard-learned', 'standard-conservative',
                                                    'learned-conservative'}
        # a comparison's two games are adjacent, first then second, with its two treatments
        for q in p['questionnaires']:
            a, b = (games[k - 1] for k in q['games'])
            assert q['after_game'] == b['game'] == a['game'] + 1
            assert a['comparison'] == b['comparison'] == q['comparison']
            assert (a['position_in_pair'], b['position_in_pair']) == (1, 2)
            assert D.comparison_name(a['treatment'], b['treatment']) == q['comparison']
        sl = next(q for q in p['questionnaires'] if q['comparison'] == 'standard-learned')
        assert {games[k - 1]['treatment'] for k in sl['games']} == {'standard', 'learned'}
        # a different task version for every game
        assert sorted(g['version'] for g in games) == list(range(D.N_VERSIONS))


def test_each_treatment_meets_each_version_equally_often_over_every_three_and_every_block():
    for size, each in ((3, 1), (D.BLOCK, 2)):
        for start in range(0, 13):
            meets = Counter((g['treatment'], g['version']) for p in plans(range(start, start + size))
                            for g in p['games'])
            assert len(meets) == 3 * D.N_VERSIONS and set(meets.values()) == {each}, (size, start, meets)
    # a study of 4 participants (not a multiple of 3) is unbalanced, as the docs say
    meets = Counter((g['treatment'], g['version']) for p in plans(range(4)) for g in p['games'])
    assert len(set(meets.values())) > 1


def test_versions_are_worlds_and_the_short_form_is_todays_three_games():
    seeds = [D.version_world_seed(v, 3) for v in range(D.N_VERSIONS)]
    assert len(set(seeds)) == 6 and seeds != [D.version_world_seed(v, 4) for v in range(6)]
    with pytest.raises(ValueError):
        D.version_world_seed(6)
    short = D.plan('short', 7)
    assert [g['treatment'] for g in short['games']] == list(D.SHORT_ORDERS[1])
    assert [q['games'] for q in short['questionnaires']] == [[1, 2], [2, 3]]
    assert all(g['version'] is None for g in short['games'])
    with pytest.raises(ValueError):
        D.plan('long', 0)
    assert D.plan('paper', 8) == D.paper_plan(2)


def test_treatment_means_average_a_treatments_two_games_and_keep_the_totals():
    plan = D.paper_plan(0)['games']
    plays = [dict(g, false_positives=fp, interventions=fp + 1, crashes=0, trips=5, avoidance_length=arc,
                  set=g['treatment'], trace={'n': g['game']}, complete=g['game'] != 4)
             for g, fp, arc in zip(plan, (3, 8, 1, 4, 6, 2), (0.5, None, 1.0, float('nan'), 0.2, 2.0))]
    means = D.treatment_means(plays)
    for t in D.TREATMENTS:
        mine = [p for p in plays if p['treatment'] == t]
        assert means[t]['false_positives'] == pytest.approx(sum(p['false_positives'] for p in mine) / 2)
        assert means[t]['totals']['false_positives'] == sum(p['false_positives'] for p in mine)
        assert means[t]['games'] == [p['game'] for p in mine]
        assert means[t]['versions'] == [p['version'] for p in mine]
        assert means[t]['trace'] == mine[0]['trace'] and means[t]['set'] == t
        assert 'comparison' not in means[t] and 'version' not in means[t]
        assert means[t]['complete'] == all(p['game'] != 4 for p in mine)
    # a missing measure (None, NaN) is left out of its mean
    arcs = {t: [p['avoidance_length'] for p in plays if p['treatment'] == t] for t in D.TREATMENTS}
    for t, v in arcs.items():
        known = [x for x in v if x is not None and math.isfinite(x)]
        assert means[t]['avoidance_length'] == pytest.approx(sum(known) / len(known))
    # played once: the game's own values
    one = D.treatment_means(plays[:1])
    assert one[plays[0]['treatment']]['false_positives'] == 3


def answer(comparison, treatments, team, preference):
    return {'comparison': comparison, 'treatments': treatments, 'games': [1, 2],
            'values': dict({k: list(team) for k, _ in Q.TEAM_ITEMS}, preference=preference)}


def test_answers_are_checked_and_turned_towards_the_comparisons_treatments():
    good = dict({k: [3, 6] for k, _ in Q.TEAM_ITEMS}, preference=5)
    assert Q.check_answers(good) == good
    for bad in ({**good, 'trust': [3]}, {**good, 'trust': [3, 8]}, {**good, 'trust': 4},
                {**good, 'preference': 0}, {**good, 'preference': True}, {**good, 'extra': 1},
                {k: v for k, v in good.items() if k != 'preference'}, [1, 2]):
        with pytest.raises(ValueError):
            Q.check_answers(bad)
    # Learned played first: its ratings are the first game's; preference 6 for Standard over Learned
    x, y, pref = Q.ratings(answer('standard-learned', ['learned', 'standard'], (6, 2), 6), 'standard-learned')
    assert x['trust'] == 2 and y['trust'] == 6 and pref == 2        # turned: towards Learned
    x, y, pref = Q.ratings(answer('standard-learned', ['standard', 'learned'], (6, 2), 6), 'standard-learned')
    assert x['trust'] == 6 and y['trust'] == 2 and pref == 6
    assert Q.ratings(answer('standard-learned', ['standard', 'learned'], (6, 2), 6), 'learned-conservative') is None
    old = {'after_game': 2, 'pair': ['standard', 'learned'], 'values': {'trust': 5}}
    assert Q.ratings(old, 'standard-learned') is None


def test_the_papers_tests_per_item_from_three_participants_and_means_below():
    from scipy.stats import ttest_rel
    std = [2, 3, 5, 4]
    lrn = [5, 3, 6, 6]
    prefs = [6, 5, 7, 3]          # raw; Learned second for the even participants
    lists = []
    for i in range(4):
        order = ['standard', 'learned'] if i % 2 == 0 else ['learned', 'standard']
        team = (std[i], lrn[i]) if i % 2 == 0 else (lrn[i], std[i])
        lists.append([answer('standard-learned', order, team, prefs[i]),
                      answer('standard-conservative', ['conservative', 'standard'], (4, 4), 4)])
    lists.append([])                            # a participant without answers (simulated)
    res = Q.subjective_analysis(lists)
    sl = res['standard-learned']
    assert sl['n'] == 4 and res['learned-conservative']['n'] == 0
    trust = sl['items']['trust']
    assert trust['standard'] == pytest.approx(3.5) and trust['learned'] == pytest.approx(5.0)
    t = ttest_rel(lrn, std)
    assert trust['anova']['df_num'] == 1 and trust['anova']['df_den'] == 3
    assert trust['anova']['F'] == pytest.approx(t.statistic ** 2) and trust['anova']['p'] == pytest.approx(t.pvalue)
    towards = [6, 8 - 5, 7, 8 - 3]
    pref = sl['items']['preference']
    assert pref['for'] == 'learned' and pref['mean'] == pytest.approx(sum(towards) / 4)
    from scipy.stats import ttest_1samp
    assert pref['ttest']['p'] == pytest.approx(ttest_1samp(towards, 4).pvalue)
    # identical answers: nothing to test, said so
    assert 'note' in res['standard-conservative']['items']['trust']['anova']
    text = Q.format_subjective(res, {'standard': 'Standard', 'learned': 'Learned', 'conservative': 'Conservative'})
    assert 'Standard vs Learned (4 participants answered)' in text and 'F(1, 3) = ' in text
    assert 'Learned over Standard' in text
    # two participants: means only
    few = Q.subjective_analysis(lists[:2])['standard-learned']
    assert few['items']['trust']['anova'] is None and few['items']['preference']['ttest'] is None
    labels = {'standard': 'S', 'learned': 'L'}
    assert 'no test (fewer than 3)' in Q.format_subjective({'standard-learned': few}, labels)


def test_every_pair_of_rows_in_a_block_differs():
    block = [tuple((g['treatment'], g['version']) for g in p['games']) for p in plans(range(D.BLOCK))]
    assert all(a != b for a, b in itertools.combinations(block, 2))
