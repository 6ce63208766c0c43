"""The online first-passage learner through the real graph: a short Phase II session.

Clock, world (no respawn), one robot, the simulated supervisor (w_max 0.5, mu 1.0,
sigma 0.3) and the learner (first-passage, robots [robot_0]) as processes; the study's
Phase II conductor sets each scene (/world/set_obstacles, robot_0/initialpose) and
drives the robot straight. The learner must count one encounter per scene, with an
intervention exactly where the conductor saw one, and none unmatched. (Recovery
accuracy is tested on synthetic streams in test_nodes_learner_first_passage.py.)
"""
import json
import time

import pytest

from supersafe_ros.learning.encounters import EncounterRecord
from supersafe_ros.team import Team, node_argv, team_env, team_layout

pytestmark = pytest.mark.ros   # node processes

OFFSETS = [-2.25, 0.0, 2.25, -1.0, 2.0]
STEP = 0.2
LIB = {'library_shape': [41, 41, 24]}
SUP = {'w_max': 0.5, 'mu': 1.0, 'sigma': 0.3, 'seed': 11, 'robots': ['robot_0'], 'grid_nxy': 41,
       'grid_ntheta': 24}


def argvs(store):
    layout = team_layout(1, 0.0, seed=3, step=STEP, with_filter=False, learner_store=store,
                         overrides={'world': {'respawn': False, 'robots': ['robot_0'], 'n_obstacles': 0},
                                    'learner': {'estimator': 'first-passage', **LIB},
                                    'supervisor': SUP})
    out = []
    for spec in layout:
        if spec.kind == 'planner':
            continue                      # the conductor drives
        params = dict(spec.params)
        if spec.kind == 'dubins_robot':
            params.update(initial_x=-8.0, initial_y=OFFSETS[0], initial_theta=0.0,
                          timeout_behavior='straight')
        if spec.kind == 'supervisor':
            params.update(SUP)
        out.append(node_argv(spec.kind, spec.namespace, params, spec.remaps))
    return out


def test_phase2_session_through_the_graph_counts_every_encounter(tmp_path):
    import os
    from diagnostic_msgs.msg import DiagnosticStatus
    from supersafe_ros.ros_io import rosmsg
    from supersafe_ros.study.conductor import Phase2Conductor
    store = tmp_path / 'subject.jsonl'
    env = team_env(int(os.environ['ROS_DOMAIN_ID']))
    conductor = Phase2Conductor(env, OFFSETS, x0=-8.0, x_end=2.5, step_length=3.0 * STEP,
                                learners=('learner',))
    fits = []
    conductor.node.create_subscription(DiagnosticStatus, '/safe_set/fit',
                                       lambda m: fits.append(rosmsg.diagnostic_values(m)), rosmsg.QOS_LATCHED)
    team = Team(argvs(store), env, tmp_path / 'logs')
    try:
        team.start()
        deadline = time.monotonic() + 240.0
        while not conductor.done.wait(0.2):
            assert not team.dead(), f'processes exited: {team.dead()} (logs in {tmp_path / "logs"})'
            assert time.monotonic() < deadline, f'Phase II stuck at scene {conductor.scene_index}'
        scenes = conductor.scenes
        n_iv = sum(s['intervened'] for s in scenes)
        # every intervention reaches the learner and its encounter (the last scene's
        # encounter without intervention becomes final at shutdown)
        deadline = time.monotonic() + 30.0
        while not (fits and fits[-1].get('interventions') == str(n_iv)
                   and int(fits[-1].get('encounters', 0)) >= len(scenes) - 1):
            assert time.monotonic() < deadline, f'learner status {fits[-1] if fits else None}'
            time.sleep(0.1)
        assert fits[-1]['unmatched_interventions'] == '0'
    finally:
        codes = team.stop()
        conductor.close()
    assert codes.get('learner') == 0, codes
    records = [EncounterRecord.from_json(line)
               for line in (tmp_path / 'subject.encounters.jsonl').read_text().splitlines()]
    # A scene reset can set the next obstacle before the robot's teleport is read: the robot,
    # still past the last obstacle, is briefly near the new one, and that encounter ends at
    # the teleport ('jump'), as specified (seen in 2 of 6 runs on an idle machine). Each
    # scene's own encounter is the one that did not end in a jump.
    first = {}
    for r in records:
        if r.reason != 'jump':
            first.setdefault(r.obstacle, r)
    scene_records = [first.get(int(s['obstacle'])) for s in scenes]
    assert None not in scene_records, (records, scenes)
    assert [r.intervened for r in scene_records] == [s['intervened'] for s in scenes]
    assert sum(r.intervened for r in records) == n_iv
    stored = [json.loads(line) for line in store.read_text().splitlines()]
    assert len(stored) == n_iv
    for r, s in zip(scene_records, scenes):
        # from the start line (a first pose read before its obstacle set may be missed)
        assert r.frames[0][0] <= -8.0 + 2 * 3.0 * STEP + 0.05 and abs(r.frames[0][1] - s["y0"]) < 0.05
