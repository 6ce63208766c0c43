"""The phases of a participant session (``Session`` in runner.py runs them).

Each phase that moves robots runs a graph of node processes (as `supersafe team`
starts them) without the simulated supervisor, with this process's ``PhaseNode`` in
its place (phase_graph.py). Everything a phase produces is saved in session.json as
soon as it exists: each Phase II scene as it ends, Phase I (with the driven path) and
each game when they end, the fit when it is made, each questionnaire when answered.
"""
from __future__ import annotations

import shutil
import threading
import time

from ..team import node_argv, team_layout
from .fit_view import fit_view
from .phase_graph import SET_GATE_TOPIC, PhaseGraph, PhaseNode, add_clock_gate, set_clock_param, without
from .protocol import LIKERT_POINTS, intervention_states, participant_number

SCENE_PAUSE = 3.0                          # wall s between calibration scenes


class SessionPhases:
    """Mixed into ``Session``: needs self.args, store, env, state, show, say, keys,
    interrupted (an Event set by a signal) and the page's ``view``."""

    # -- the graphs ------------------------------------------------------------------------
    def start_recording(self):
        """Every topic of this run of the session, into a new bag beside its results
        (recording-1, then recording-2 after a resume, ...), from the first graph on: a
        run that starts none leaves no bag."""
        if not self.args.record or self.recorder is not None:
            return
        from ..ros_io.bag_recorder import start_recorder
        k = 1
        while (self.store.dir / f'recording-{k}').exists():
            k += 1
        bag = self.store.dir / f'recording-{k}'
        self.recorder = start_recorder(bag, domain_id=int(self.env['ROS_DOMAIN_ID']))
        self.say(f'recording every topic to {bag} (ros2 bag play {bag}, or Foxglove)')

    def stop_recording(self, max_wait: float = 5.0):
        recorder, self.recorder = self.recorder, None
        if recorder is None:
            return
        info = recorder.stop(quiet=min(0.3, max_wait), max_wait=max_wait)
        if info.message_count == 0:          # nothing ran: no empty bag
            shutil.rmtree(recorder.path, ignore_errors=True)
        else:
            self.say(f'recorded {info.message_count} messages: {recorder.path}')

    def _run_graph(self, argvs, name, node, duration):
        """Start ``argvs`` beside ``node`` (this process's PhaseNode), run ``duration`` sim s."""
        self.start_recording()
        (self.store.dir / 'logs').mkdir(exist_ok=True)
        self.phase_node = node
        self.graph = PhaseGraph(argvs, self.env, self.store.dir / 'logs' / name).start()
        try:
            result = self.graph.run(duration, timeout=3 * duration / self.args.rate_factor + 120)
        finally:
            self.end_graph()
        if result['reason'] != 'duration reached':
            raise RuntimeError(f'{name}: {result["reason"]} (logs in {self.store.dir / "logs" / name})')
        return result

    def end_graph(self, grace: float = 3.0):
        """Stop the running phase's processes and node (both may be None); after a signal
        the processes get ``stop_grace`` s, not ``grace``."""
        if self.signalled is not None:
            grace = min(grace, self.stop_grace)
        graph, node, conductor = self.graph, self.phase_node, self.conductor
        if graph is not None:
            graph.signal_stop()
        for part in (conductor, node):
            if part is not None:
                part.close()
        if self.signalled is not None:
            self.stop_recording(max_wait=0.4)    # while the processes exit
        if graph is not None:
            graph.stop(grace)
        self.graph = self.phase_node = self.conductor = None

    def _running(self):
        """The phase's robots run (the first pose arrived): the page says so."""
        self.show(self.view['phase'], **dict({k: v for k, v in self.view.items() if k not in ('type', 'phase')},
                                             running=True))

    # -- Phase I ---------------------------------------------------------------------------
    def phase1(self):
        seconds = self.args.phase1_seconds
        layout = team_layout(1, self.args.rate_factor, seed=participant_number(self.store.pid) % 100000,
                             duration=seconds, step=0.05, with_filter=False,
                             with_learner=False, overrides={'world': {'robots': ['robot_0']}})
        argvs = without([node_argv(n.kind, n.namespace, n.params, n.remaps) for n in layout],
                        'robot_0/planner', 'supervisor')
        # pose readers: the world and this session (no planner)
        set_clock_param(argvs, 'wait_for_subscriptions', ['/robot_0/pose=2', '/clock=1'])
        self.show('phase1', seconds=seconds, running=False)
        node = PhaseNode(self.env, self.state, ['robot_0'], drive_robot='robot_0', keys=lambda: self.keys,
                         on_first_pose=self._running, record_path=True)
        path = node.path
        result = self._run_graph(argvs, 'phase1', node, seconds)
        self.store.data['phase1'] = {'seconds': seconds, 'stats': result.get('stats', {}),
                                     'reason': result['reason'],
                                     'path_columns': ['t', 'x', 'y', 'theta', 'u'], 'path': path}
        self.store.save()
        self.say(f'Phase I done: {len(path)} poses, crashes {result["stats"].get("crashes", "?")}')

    # -- Phase II --------------------------------------------------------------------------
    def phase2(self):
        from ..study.conductor import Phase2Conductor
        from ..study.graph_phase2 import phase2_argvs
        from ..study.population import Subject
        from ..study.protocol import PHASE2_X0, PHASE2_X_END, SPEED, StudyOptions
        offsets = self.store.remaining_offsets()
        total = len(self.store.data['offsets'])
        done0 = len(self.store.data['scenes'])
        opts = StudyOptions(step=0.05, rate_factor=self.args.rate_factor)
        stand_in = Subject(index=0, omega_max=1.0, mu=0.0, sigma=0.1,
                           seed=participant_number(self.store.pid) % 100000)
        name = f'phase2-{done0:02d}'
        store = self.store.dir / 'logs' / name / 'learner-interventions.jsonl'
        # the study's Phase II graph with this session in the supervisor's place
        argvs = without(phase2_argvs(stand_in, opts, store, offsets[0]), 'supervisor')
        # the pause between scenes holds this node's step acknowledgements: the clock must
        # wait for them that long (it advances without a silent node after ack_timeout)
        set_clock_param(argvs, 'ack_timeout', SCENE_PAUSE + 2.0)
        self.start_recording()
        self.pause = {'until': 0.0, 'scene': -1}
        self.conductor = conductor = Phase2Conductor(self.env, offsets, x0=PHASE2_X0, x_end=PHASE2_X_END,
                                                     step_length=SPEED * opts.step, learners=('learner',))
        self.phase_node = PhaseNode(self.env, self.state, ['robot_0'], hold=self._scene_pause,
                                    rate_factor=self.args.rate_factor)
        self.graph = PhaseGraph(argvs, self.env, self.store.dir / 'logs' / name).start()
        self.interventions_open = True
        try:
            saved = 0
            while True:
                finished = conductor.done.wait(0.1)
                for scene in list(conductor.scenes)[saved:]:
                    self.store.add_scene(scene)
                    saved += 1
                    self.say(f'Phase II: scene {len(self.store.data["scenes"])}/{total} '
                             f'{"stopped" if scene["intervened"] else "let pass"}')
                if finished:
                    break
                if self.view.get('done') != len(self.store.data['scenes']) or not self.view.get('running'):
                    self.show_phase2()
                if self.graph.team.dead():
                    raise RuntimeError(f'Phase II processes exited: {self.graph.team.dead()} '
                                       f'(logs in {self.store.dir / "logs" / name})')
        finally:
            self.interventions_open = False
            self.end_graph()

    def _pause_left(self) -> float:
        return round(max(0.0, self.pause['until'] - time.monotonic()), 2)

    def _scene_pause(self) -> bool:
        """PhaseNode's hold, on every pose: a scene ends (the person intervened, or the robot
        is past the obstacle): hold the clock for SCENE_PAUSE s, unless it was the last."""
        c = self.conductor
        if c is None:
            return False
        k = c.scene_index
        if k != self.pause['scene'] and c.stage == 'E' and k < len(c.offsets) - 1:
            self.start_pause(k)
        return time.monotonic() < self.pause['until']

    def show_phase2(self):
        self.show('phase2', running=True, scenes=len(self.store.data['offsets']),
                  done=len(self.store.data['scenes']), pause=self._pause_left())

    def start_pause(self, scene_index: int):
        self.pause = {'until': time.monotonic() + SCENE_PAUSE, 'scene': scene_index}
        self.show_phase2()

    def phase2_intervening(self) -> dict:
        """The person's intervention is about to go out in Phase II: that scene ends, the
        pause starts (unless it was the last scene). Returns the pause before, to restore
        if nothing went out."""
        before, c = self.pause, self.conductor
        if c is not None and c.scene_index < len(c.offsets) - 1:
            self.start_pause(c.scene_index)
        return before

    # -- the fit -----------------------------------------------------------------------------
    def fit(self):
        """Both estimators over the person's scenes, in a worker thread (a signal is handled
        at once while it runs)."""
        result = {}

        def work():
            try:
                result['fits'] = self._fit()
            except BaseException as exc:      # reported in the main thread
                result['error'] = exc
        worker = threading.Thread(target=work, name='session-fit', daemon=True)
        worker.start()
        while worker.is_alive():
            worker.join(0.1)
        if 'error' in result:
            raise result['error']
        self.store.data['fit'] = result['fits']
        self.store.save()
        self.plot_fit()

    def _fit(self) -> dict:
        from ..learning.estimators import fit_paper
        from ..reach.library import load_or_build_library
        from ..study.fits import first_passage_fit
        from ..study.protocol import TRUE_OMEGA
        scenes = self.store.data['scenes']
        states = intervention_states(scenes)
        fits = {'paper': None, 'first_passage': None}
        if len(states):
            lib = load_or_build_library()
            paper = fit_paper(lib.entries, states, true_vf=lib.entry(TRUE_OMEGA))
            fits['paper'] = {k: v for k, v in paper.to_dict().items() if k not in ('candidates',)}
            _, fp = first_passage_fit(scenes)
            fits['first_passage'] = fp
        return fits

    def learned_vf(self, estimator=None):
        """The learned value function of ``estimator`` (default --estimator), or None."""
        from ..reach.library import load_or_build_library
        fits = self.store.data.get('fit') or {}
        fit = fits.get((estimator or self.args.estimator).replace('-', '_'))
        if not fit:
            return None
        return load_or_build_library().entry(float(fit['omega_max']))

    def plot_fit(self):
        """fit.png beside the results: the researcher's figure (the page draws its own)."""
        from ..study.plots import plot_learned_sets
        from ..study.protocol import TRUE_RADIUS, reference_sets
        standard, conservative = reference_sets()
        learned = []
        for name, label in (('paper', "paper's estimator"), ('first_passage', 'first-passage')):
            fit = self.store.data['fit'].get(name)
            if fit:
                learned.append((self.learned_vf(name), float(fit['mu']),
                                f'{label}: w {float(fit["omega_max"]):g}, mu {float(fit["mu"]):.2f}'))
        plot_learned_sets(self.store.dir / 'fit.png', standard, conservative, learned, TRUE_RADIUS)

    def fit_screen(self) -> dict:
        """The page's fit view; the numbers go to the terminal and session.json."""
        from ..study.protocol import reference_sets
        fits = self.store.data['fit'] or {}
        fit = fits.get(self.args.estimator.replace('-', '_'))
        page, researcher = fit_view(self.store.data['scenes'], fit, self.learned_vf(), reference_sets()[0])
        for name in ('paper', 'first_passage'):
            f = fits.get(name)
            self.say(f'fit {name.replace("_", "-")}: ' + (
                f'w_max {float(f["omega_max"]):g}, mu {float(f["mu"]):.3f}, sigma {float(f["sigma"]):.3f}'
                + (f', {f["set_aside"]} encounter(s) set aside (no library entry explains them)'
                   if f.get('set_aside') else '')
                if f else 'none (no intervention the library can explain): the Learned game uses the '
                'Standard set'))
        std, learned = researcher['turn_distance_standard'], researcher['turn_distance_learned']
        self.say(f'fit screen ({self.args.estimator}): head-on turn at '
                 f'{"-" if std is None else f"{std:.2f} m"} (standard) vs '
                 f'{"-" if learned is None else f"{learned:.2f} m"} (learned): "{researcher["change"]}"')
        if self.store.data.get('fit_screen') != researcher:
            self.store.data['fit_screen'] = researcher
            self.store.save()
        return page

    # -- Phase III -------------------------------------------------------------------------
    def game_world_seed(self, g) -> int:
        """The world of a planned game: its task version's (the paper's form), else the
        participant's own (the short form)."""
        from ..study.design import version_world_seed
        if g.get('version') is None:
            return participant_number(self.store.pid) % 100000
        return version_world_seed(g['version'])

    def game(self, g):
        """One Phase III game of the plan: a fresh graph (world on the game's task version,
        two robots with planner and filter, no supervisor process: the person is the
        supervisor) whose clock starts once both filters have the treatment's set in force
        (``SetGate``)."""
        from ..study.games import condition_message
        from ..study.records import game_counts
        cond, k = g['treatment'], g['game']
        n = len(self.store.data['plan']['games'])
        fit = (self.store.data['fit'] or {}).get(self.args.estimator.replace('-', '_'))
        vf = self.learned_vf()
        learned = {'learned': (vf, fit)} if (vf is not None and fit) else {}
        msg, alpha, ran = condition_message(cond, learned)
        seconds = self.args.game_seconds
        world_seed = self.game_world_seed(g)
        layout = team_layout(2, self.args.rate_factor, seed=world_seed,
                             duration=seconds, step=0.05, with_learner=False,
                             overrides={'safety_filter': {'use_learned': True, 'alpha_offset': 0.0}})
        argvs = without([node_argv(n.kind, n.namespace, n.params, n.remaps) for n in layout], 'supervisor')
        add_clock_gate(argvs, SET_GATE_TOPIC)
        self.show('game', game=f'Game {k}', number=k, of=n, seconds=seconds, running=False)
        node = PhaseNode(self.env, self.state, ['robot_0', 'robot_1'], set_msg=msg, on_first_pose=self._running)
        self.interventions_open = True
        try:
            result = self._run_graph(argvs, f'game-{k}-{cond}', node, seconds)
        finally:
            self.interventions_open = False
        counts = game_counts(result)
        counts.update(reason=result['reason'], played=ran,
                      alpha=alpha, complete=counts['sim_time'] >= seconds - 1e-6)
        counts.update(g, world_seed=world_seed)
        self.store.data['plays'].append(counts)
        self.store.save()
        self.say(f'Game {k} of {n} ({cond}, ' + (f'version {g["version"]}, ' if g.get('version') is not None else '')
                 + f'world {world_seed}) done: trips {counts["trips"]}, crashes {counts["crashes"]}, '
                 f'interventions {counts["interventions"]}, false positives {counts["false_positives"]}')

    def ask(self, q):
        """The questionnaire after a comparison: the statements about each of its two games
        and the preference between them (study.subjective)."""
        from ..study.subjective import PREFERENCE, SCALE, TEAM_ITEMS
        a, b = q['games']
        labels = [f'Game {a}', f'Game {b}']
        games = self.store.data['plan']['games']
        treatments = [games[a - 1]['treatment'], games[b - 1]['treatment']]
        preference = PREFERENCE[1].format(first=labels[0], second=labels[1])
        self.answered.clear()
        self.show('likert', pair=labels, points=LIKERT_POINTS,
                  items=[{'key': k, 'text': t} for k, t in TEAM_ITEMS],
                  preference={'key': PREFERENCE[0], 'text': preference})
        while not self.answered.wait(0.1):
            pass
        self.store.data['answers'].append({'after_game': q['after_game'], 'comparison': q['comparison'],
                                           'games': [a, b], 'labels': labels, 'treatments': treatments,
                                           'pair': treatments, 'values': self.answers,
                                           'preference_statement': preference, 'scale': SCALE})
        self.store.save()
        self.say(f'answers on {labels[0]} and {labels[1]} ({q["comparison"]}): {self.answers}')
