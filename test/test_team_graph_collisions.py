"""The real team graph with perfect detection: no crash deeper than 1 cm (issue 9).

CI-sized version of ``bench/bench_collisions.py graph``: 2 robots x 60 sim s at
the study's coarse 0.2 s step, as fast as the graph allows (rate factor 0, the
lockstep's hardest timing), no supervisor and no learner, sensors that never miss
(every obstacle the robots meet is detected), and the world counting every entry
deeper than 1 cm (crash_tolerance 0.01) as a crash.

It was opt-in while the graph crashed 1-8 times per run: the filter's watchdog
answered lockstep steps on poses up to 0.8 s old, and a cluster's union value came
into force sim seconds late. The filter now answers each pose once, on that pose,
and holds the step until a cluster's value lands (``lockstep``,
``cluster_hold_timeout``; docs/graph_safety.md). It was opt-in again after one crash
at 4.2 s in a clean CI run (reproduced once in 9 runs): at start-up filters answered
poses the clock had already passed, and stayed steps behind. They no longer answer
those; cache files are no longer written through one shared temporary name.
"""
import os

import pytest

from supersafe_ros.team import run_team, team_processes

pytestmark = pytest.mark.ros   # node processes


def test_team_at_a_coarse_step_never_enters_a_detected_obstacle(tmp_path):
    duration = 60.0
    argvs = team_processes(n_robots=2, rate_factor=0.0, seed=4, duration=duration, step=0.2,
                           with_supervisor=False, with_learner=False,
                           overrides={'dubins_robot': {'miss_probability': 0.0},
                                      'world': {'crash_tolerance': 0.01}})
    result = run_team(argvs, duration=duration, timeout=300.0, log_dir=tmp_path / 'logs',
                      print_period=1e9, out=open(os.devnull, 'w'))
    stats = result['stats']
    assert result['reason'] == 'duration reached', result['reason']
    # 7-8 trips were measured in this game with seeds 1 and 7 (cold and warm cluster
    # caches): at least 4 says that they really drove across the obstacles, not circled.
    # Seed 4 = the team test's world: this test, run first, solves most of its cluster
    # values (kept on disk), so the team test's steps are rarely held for a solve
    assert int(stats['trips']) >= 4, stats
    assert int(stats['crashes']) == 0, [e for e in result['events'] if e.get('event') == 'crash']


@pytest.mark.slow
def test_the_scan_team_never_enters_an_obstacle_its_lasers_saw(tmp_path):
    """``supersafe team --sensors scan`` (issue 36): robots that publish odometry and a 360-beam scan, each
    filter keeping the scans in a local map judged by its one avoid value (solved inline: the lockstep
    clock waits for it) and cutting its speed between solves; obstacles of radii 0.8, 1.8 and 2.6 m,
    every one seen, 60 sim s at the 0.2 s step: no crash deeper than 1 cm, and the robots get across."""
    duration = 60.0
    argvs = team_processes(n_robots=2, rate_factor=0.0, seed=4, duration=duration, step=0.2,
                           with_supervisor=False, with_learner=False, sensors='scan',
                           overrides={'dubins_robot': {'miss_probability': 0.0},
                                      'world': {'crash_tolerance': 0.01}})
    result = run_team(argvs, duration=duration, timeout=420.0, log_dir=tmp_path / 'logs',
                      print_period=1e9, out=open(os.devnull, 'w'))
    stats = result['stats']
    assert result['reason'] == 'duration reached', result['reason']
    assert int(stats['crashes']) == 0, [e for e in result['events'] if e.get('event') == 'crash']
    assert int(stats['trips']) >= 3, stats
