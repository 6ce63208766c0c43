"""supersafe study --scheduler: subjects on a Dask distributed cluster (a LocalCluster of two
worker processes on loopback) give the records of a local run for the same seed."""
import io

import pytest

from supersafe_ros.study.population import load_population
from supersafe_ros.study.protocol import StudyOptions
from supersafe_ros.study.records import jsonable
from supersafe_ros.study.runner import run_study


def comparable(record):
    """A record without its value-function objects and wall/CPU times."""
    out = {k: v for k, v in record.items() if k != 'learned_vfs'}
    out['games'] = {c: {k: v for k, v in g.items() if k not in ('wall', 'wall_running', 'cpu_s', 'cpu_by_process')}
                    for c, g in record['games'].items()}
    out['phase2'] = {k: v for k, v in record['phase2'].items() if k != 'wall'}
    return jsonable(out)


def test_a_study_on_a_local_dask_cluster_gives_the_records_of_a_local_run(tmp_path):
    distributed = pytest.importorskip('distributed', reason='distributed (requirements.txt) is not installed')
    subjects = load_population('paper').draw(2, seed=4)
    opts = StudyOptions(subjects=2, seed=4, game_seconds=10.0, phase2_offsets=(-1.0, 0.0, 1.0),
                        conditions=('standard', 'learned_fp', 'learned_online'), sweep_subjects=0,
                        out_dir=tmp_path / 'local', workers=1, plots=False)
    local = run_study(subjects, opts, out=io.StringIO())['records']
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host='127.0.0.1',
                                  dashboard_address=None) as cluster:
        opts.scheduler, opts.out_dir = cluster.scheduler_address, tmp_path / 'cluster'
        assert opts.scheduler.startswith('tcp://127.0.0.1:')
        text = io.StringIO()
        remote = run_study(subjects, opts, out=text)['records']
    assert text.getvalue().count('done on the cluster') == 2
    assert [comparable(r) for r in remote] == [comparable(r) for r in local]
    assert all((tmp_path / 'cluster' / 'subjects' / f's{i:02d}' / 'subject.json').is_file() for i in range(2))
