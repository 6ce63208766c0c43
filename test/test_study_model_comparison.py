"""The supervisor models' comparison tables (study.model_comparison) and the crash counts
beside false positives in Table 1 and the paired tests (study.analysis, study.posthoc)."""
import json

from supersafe_ros.study.analysis import LABELS, format_table1
from supersafe_ros.study.model_comparison import comparison, main
from supersafe_ros.study.posthoc import format_posthoc, paired_posthoc


def study(model, fp, crashes):
    """A study JSON's parts the comparison reads: per condition FP and crashes per subject."""
    conds = {}
    for c in ('standard', 'learned', 'conservative'):
        conds[c] = {'false_positives': fp[c], 'crashes': crashes[c], 'trips': [16] * len(fp[c]),
                    'observed_fp_ratio': sum(fp[c]) / sum(fp['standard'])}
    posthoc = paired_posthoc({c: v['false_positives'] for c, v in conds.items()}, list(conds))
    pooled = {c: {'predicted': 0.5, 'observed': conds[c]['observed_fp_ratio'], 'games_predicted': 0.6}
              for c in ('learned', 'conservative')}
    return {'options': {'supervisor': model}, 'conditions': conds, 'posthoc': posthoc,
            'anova': {'F': 9.0, 'df_num': 2, 'df_den': 4, 'p': 0.03},
            'validity': {'pooled': pooled, 'gap': {'learned': {'fp_after_override': 0.25, 'false_positives': 8}}}}


def test_one_row_per_model_and_the_papers_with_crashes_beside_false_positives(tmp_path, capsys):
    a = study('memoryless', {'standard': [10, 12, 14], 'learned': [9, 9, 9], 'conservative': [4, 5, 3]},
              {'standard': [0, 1, 0], 'learned': [0, 0, 0], 'conservative': [2, 1, 0]})
    b = study('attentive', {'standard': [8, 10, 12], 'learned': [6, 6, 7], 'conservative': [3, 4, 3]},
              {'standard': [0, 1, 1], 'learned': [1, 0, 0], 'conservative': [2, 2, 0]})
    text = comparison([a, b])
    rows = {line.split('|')[1].strip(): line for line in text.splitlines() if line.startswith('| ')}
    assert '12.00; 1 crashes, 48 trips' in text                         # memoryless Standard
    assert '6.33 (63.3 %); 1 crashes' in text                           # attentive Learned: 19 / 30
    assert 'crashes 2 / 4' in text                                      # attentive Standard - Conservative
    assert '58.3 %' in text and 'p = 0.0328' in text                    # the paper's rows
    assert sum(1 for line in text.splitlines() if line.startswith('| attentive |')) == 3
    assert 'memoryless' in rows and 'paper' in rows
    paths = []
    for doc in (a, b):
        p = tmp_path / f'{doc["options"]["supervisor"]}.json'
        p.write_text(json.dumps(doc))
        paths.append(str(p))
    assert main(paths) == 0
    assert capsys.readouterr().out.strip() == text
    assert main([str(tmp_path / 'missing.json')]) == 2


def test_table1_and_the_paired_tests_print_crashes_when_the_study_has_them():
    rows = {'standard': {'inside': 9, 'total': 10, 'predicted_fp_ratio': 1.0, 'average_fp': 12.0,
                         'observed_fp_ratio': 1.0, 'crashes': 3},
            'learned': {'inside': 5, 'total': 10, 'predicted_fp_ratio': 5 / 9, 'average_fp': 6.0,
                        'observed_fp_ratio': 0.5, 'crashes': 11}}
    table = format_table1(rows, paper=False).splitlines()
    assert table[0].rstrip().endswith('Crashes') and table[-1].rstrip().endswith('11')
    posthoc = paired_posthoc({'standard': [10, 12, 14], 'learned': [5, 7, 6]}, ['standard', 'learned'])
    posthoc['pairs']['standard-learned']['crashes'] = [3, 11]
    assert 'crashes 3 / 11' in format_posthoc(posthoc, LABELS)
