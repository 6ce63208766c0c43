"""`supersafe session --participant ID [--out DIR]`: the paper's protocol for one person,
in the console (issue 8).

One web server for the whole session (session.html); per phase a graph of node
processes (as `supersafe team` starts them) and, in this process, a node of the
session standing in for the simulated supervisor: it feeds the page, publishes the
person's interventions on /interventions, and acknowledges every pose on
/supervisor/step_done so the lockstep clock runs in real time with the person.

1. Phase I: ``--phase1-seconds`` (60) of free driving of one robot with the arrow keys
   (the session answers each pose with the keys' turn rate on robot_0/cmd_vel).
2. Phase II: the study's conductor (study/conductor.py) plays the calibration scenes
   from the participant's shuffled offsets; Space or a click intervenes. Each scene is
   saved as it ends, with or without an intervention.
3. Fit: the paper's estimator and the first-passage estimator over the candidate
   library (conservative prior); the page shows the fitted set over Standard and
   Conservative (fit.png). The Learned games use ``--estimator`` (paper: alpha = mu).
4. Phase III: three games (``--game-seconds``, 120) in the participant's Latin-square
   order, the conditions unnamed on the page; the Likert items after games 2 and 3.
Results: <out>/<ID>/session.json (everything, saved after every step) and, when
complete, subject.json + learned_vf.npz in the study's subject layout (session.py).
Ctrl-C or a closed tab: run the same command again; the session resumes at the scene
or game that was running. A complete participant is never overwritten.
"""
from __future__ import annotations

import json
from pathlib import Path
import sys
import threading
import time

from ..team import Team, _param_value, node_argv, process_name, run_team, team_env, team_layout
from .session import (LIKERT_ITEMS, LIKERT_POINTS, ParticipantExists, SessionStore,
                      check_answers, game_pairs, intervention_states, load_subject,
                      participant_number, subject_record, write_subject)
from .state import ConsoleState, Field

# rclpy, the console's web server and the study's modules (numpy, scipy, matplotlib) are
# imported where a phase needs them: `supersafe` imports this module to build its parser

GAME_LABELS = ('Game 1', 'Game 2', 'Game 3')


class PhaseNode:
    """This process's node for one phase's graph: named 'supervisor' so that its
    ~/step_done is the observer topic the sim clock waits for. Own context, own thread."""

    def __init__(self, env, state: ConsoleState, robots, drive_robot: str | None = None,
                 keys=None, w_max: float = 1.0, set_msg=None, on_first_pose=None):
        from ..rosenv import ensure_local_ros_env
        ensure_local_ros_env()
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from geometry_msgs.msg import Twist
        from ..nodes.common import StepAcknowledger
        from ..ros_io import rosmsg
        from .bridge import ConsoleBridge
        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, args=[], domain_id=int(env['ROS_DOMAIN_ID']))
        self.node = rclpy.create_node('supervisor', context=self.context)
        state.reset(robots)
        self.Twist = Twist
        self.keys = keys
        self.w_max = w_max
        self.on_first_pose = on_first_pose     # the clock has started: the phase runs
        self.cmd_pub = (self.node.create_publisher(Twist, f'/{drive_robot}/cmd_vel', rosmsg.QOS_STREAM)
                        if drive_robot else None)
        self.acks = StepAcknowledger(self.node, robots)
        self.bridge = ConsoleBridge(self.node, state, on_pose=self._after_pose)
        self.acks.watch(*self.bridge.pose_subscriptions)
        self.set_gate = SetGate(self.node, set_msg, len(robots)) if set_msg is not None else None
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:   # the context was shut down under the executor by close()
            pass

    def _after_pose(self, robot, msg):
        if self.on_first_pose is not None:
            callback, self.on_first_pose = self.on_first_pose, None
            callback()
        if self.cmd_pub is not None:
            # the person's arrow keys: left turns left (+u); this is also the lockstep answer
            left, right = self.keys() if self.keys else (False, False)
            self.cmd_pub.publish(self.Twist(angular=type(self.Twist().angular)(
                z=self.w_max * (float(left) - float(right)))))
        self.acks.processed(robot, msg.header.stamp)

    def close(self):
        self.bridge.state.reset([])     # the phase is over: its scene leaves the page
        self._rclpy.try_shutdown(context=self.context)
        self.thread.join(timeout=2.0)
        try:
            self.executor.shutdown()
            self.node.destroy_node()
        except Exception:
            pass


SET_GATE_TOPIC = '/session/set_in_force'


class SetGate:
    """Publishes one value-function message, latched, on /safe_set/value_function, and opens
    a gate (a publisher on ``SET_GATE_TOPIC``, which the game's sim clock waits for) once
    ``n_filters`` safety filters have said on /rosout that a set from it is in force: a
    game's first step then runs on the condition's set, not on the one a filter starts with."""

    def __init__(self, node, msg, n_filters: int):
        from rcl_interfaces.msg import Log
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Empty, Float32MultiArray
        from ..ros_io import rosmsg
        self.node, self.n_filters, self.Empty = node, int(n_filters), Empty
        self.in_force = set()
        self.gate = None
        rosout = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(Log, '/rosout', self.on_log, rosout)
        self.pub = node.create_publisher(Float32MultiArray, '/safe_set/value_function', rosmsg.QOS_LATCHED)
        self.pub.publish(msg)

    def on_log(self, log):
        # "learned set in force: ..." or "... the local standard set is in force ..."
        if log.name.endswith('safety_filter') and (' set in force' in log.msg or ' set is in force' in log.msg):
            self.in_force.add(log.name)
            if len(self.in_force) >= self.n_filters and self.gate is None:
                from ..ros_io import rosmsg
                self.gate = self.node.create_publisher(self.Empty, SET_GATE_TOPIC, rosmsg.QOS_LATCHED)


def add_clock_gate(argvs, topic):
    """The sim clock also waits for one publisher on ``topic`` before its first step."""
    for a in argvs:
        if process_name(a) == 'sim_clock':
            for i, item in enumerate(a):
                if item.startswith('wait_for_publishers:='):
                    entries = [t for t in item.split(':=', 1)[1].strip('[]').split(',') if t]
                    a[i] = f'wait_for_publishers:={_param_value(entries + [f"{topic}=1"])}'
    return argvs


def without(argvs, *names):
    return [a for a in argvs if process_name(a) not in names]


def set_clock_param(argvs, key, value):
    """Replace one -p parameter of the sim clock's argv."""
    for a in argvs:
        if process_name(a) == 'sim_clock':
            for i, item in enumerate(a):
                if item.startswith(f'{key}:='):
                    a[i] = f'{key}:={_param_value(value)}'
    return argvs


class Session:
    def __init__(self, args, out=sys.stdout):
        from .server import ConsoleServer
        self.args = args
        self.out = out
        self.store = SessionStore(args.out, args.participant, args.offsets)
        self.env = team_env(args.domain_id)
        self.state = ConsoleState(['robot_0'], Field())
        self.server = ConsoleServer(self.state, self.intervene, port=args.port, log=self.say,
                                    extra_handlers={'start': self.on_start, 'keys': self.on_keys,
                                                    'answers': self.on_answers})
        self.server.index_page = 'session.html'
        self.server.files_dir = self.store.dir
        self.server.hello_extra = lambda: {'session': self.view}
        self.view = {'type': 'session', 'phase': 'welcome'}
        self.started = threading.Event()
        self.answers = None
        self.answered = threading.Event()
        self.keys = (False, False)
        self.phase_node = None
        self.interventions_open = False

    # -- page ------------------------------------------------------------------------------
    def say(self, text):
        print(text, file=self.out, flush=True)

    def show(self, phase, **fields):
        self.view = {'type': 'session', 'phase': phase, **fields}
        self.server.push(self.view)

    def wait_for_start(self, phase, **fields):
        self.started.clear()
        self.show(phase, waiting=True, **fields)
        while not self.started.wait(0.2):
            pass
        self.show(phase, waiting=False, **fields)

    def on_start(self, msg):
        self.started.set()
        return {'type': 'session_ack', 'ok': True}

    def on_keys(self, msg):
        self.keys = (bool(msg.get('left')), bool(msg.get('right')))
        return None

    def on_answers(self, msg):
        try:
            values = check_answers(msg.get('values'))
        except ValueError as exc:
            return {'type': 'error', 'message': str(exc)}
        self.answers = values
        self.answered.set()
        return {'type': 'session_ack', 'ok': True}

    def intervene(self, obstacle_id):
        node = self.phase_node
        if node is None or not self.interventions_open:
            return {'ok': False, 'message': 'no intervention in this phase'}
        return node.bridge.intervene(obstacle_id)

    # -- phases ----------------------------------------------------------------------------
    def start_recording(self):
        """Every topic of this run of the session, into a new bag beside its results
        (recording-1, then recording-2 after a resume, ...; a bag is never overwritten)."""
        from ..ros_io.bag_recorder import start_recorder
        k = 1
        while (self.store.dir / f'recording-{k}').exists():
            k += 1
        bag = self.store.dir / f'recording-{k}'
        self.recorder = start_recorder(bag, domain_id=int(self.env['ROS_DOMAIN_ID']))
        self.say(f'recording every topic to {bag} (ros2 bag play {bag}, or Foxglove)')

    def run(self) -> int:
        port = self.server.start()
        self.say(f'console: http://127.0.0.1:{port}/')
        self.say(f'participant {self.store.pid}: {"resuming" if self.store.resumed else "new"}, '
                 f'results in {self.store.dir}')
        data = self.store.data
        self.recorder = None
        if self.args.record:
            self.start_recording()
        try:
            if data['phase1'] is None and self.args.phase1_seconds > 0:
                self.wait_for_start('phase1', seconds=self.args.phase1_seconds)
                self.phase1()
            if self.store.remaining_offsets():
                self.wait_for_start('phase2', scenes=len(data['offsets']),
                                    done=len(data['scenes']))
                self.phase2()
            if self.args.stop_after == 'phase2':
                return 0
            if data['fit'] is None:
                self.show('fitting')
                self.fit()
            fit_view = self.fit_view()
            self.wait_for_start('fit', **fit_view)
            if self.args.stop_after == 'fit':
                return 0
            order = data['order']
            pairs = game_pairs(order)
            for i, cond in enumerate(order):
                if cond not in data['games']:
                    self.wait_for_start('game', game=GAME_LABELS[i], seconds=self.args.game_seconds)
                    self.game(i, cond)
                if i >= 1 and len(data['answers']) < i:
                    self.ask(i, pairs[i - 1])
            write_subject(self.store.dir, subject_record(data, self.learned_vf(),
                                                         self.args.estimator))
            data['complete'] = True
            self.store.save()
            self.show('done')
            self.say(f'session complete: {self.store.dir / "subject.json"}')
            time.sleep(1.0)   # the page gets its last message
            return 0
        except KeyboardInterrupt:
            self.say(f'interrupted: everything done so far is in {self.store.path}; '
                     'run the same command to resume')
            return 130
        finally:
            if self.phase_node is not None:
                self.phase_node.close()
            if self.recorder is not None:
                self.recorder.stop()
            self.server.stop()

    def _graph(self, argvs, robots, name, duration, drive_robot=None, set_msg=None):
        self.phase_node = PhaseNode(self.env, self.state, robots, drive_robot=drive_robot,
                                    keys=lambda: self.keys, set_msg=set_msg,
                                    on_first_pose=lambda: self.show(self.view['phase'], **dict(
                                        {k: v for k, v in self.view.items() if k not in ('type', 'phase')},
                                        running=True)))
        try:
            log_dir = self.store.dir / 'logs' / name
            with open(self.store.dir / 'logs' / f'{name}.runner.log', 'w') as out:
                result = run_team(argvs, duration, 3 * duration + 120, int(self.env['ROS_DOMAIN_ID']),
                                  log_dir, print_period=1e9, out=out)
        finally:
            self.phase_node.close()
            self.phase_node = None
        if result['reason'].startswith('signal'):
            raise KeyboardInterrupt(result['reason'])
        return result

    def phase1(self):
        (self.store.dir / 'logs').mkdir(exist_ok=True)
        layout = team_layout(1, self.args.rate_factor, seed=participant_number(self.store.pid) % 100000,
                             duration=self.args.phase1_seconds, step=0.05, with_filter=False,
                             with_learner=False, overrides={'world': {'robots': ['robot_0']}})
        argvs = without([node_argv(n.kind, n.namespace, n.params, n.remaps) for n in layout],
                        'robot_0/planner', 'supervisor')
        # pose readers: the world and this session (no planner)
        set_clock_param(argvs, 'wait_for_subscriptions', ['/robot_0/pose=2', '/clock=1'])
        self.show('phase1', seconds=self.args.phase1_seconds, running=False)
        result = self._graph(argvs, ['robot_0'], 'phase1', self.args.phase1_seconds, drive_robot='robot_0')
        self.store.data['phase1'] = {'seconds': self.args.phase1_seconds,
                                     'stats': result.get('stats', {}), 'reason': result['reason']}
        self.store.save()

    def phase2(self):
        from ..study.conductor import Phase2Conductor
        from ..study.graph_phase2 import phase2_argvs
        from ..study.population import Subject
        from ..study.protocol import PHASE2_X0, PHASE2_X_END, SPEED, StudyOptions
        (self.store.dir / 'logs').mkdir(exist_ok=True)
        offsets = self.store.remaining_offsets()
        done0 = len(self.store.data['scenes'])
        opts = StudyOptions(step=0.05, rate_factor=self.args.rate_factor)
        stand_in = Subject(index=0, omega_max=1.0, mu=0.0, sigma=0.1,
                           seed=participant_number(self.store.pid) % 100000)
        log_dir = self.store.dir / 'logs' / f'phase2-{done0:02d}'
        store = log_dir / 'learner-interventions.jsonl'
        # the study's Phase II graph with this session in the supervisor's place
        argvs = without(phase2_argvs(stand_in, opts, store, offsets[0]), 'supervisor')
        self.phase_node = PhaseNode(self.env, self.state, ['robot_0'])
        conductor = Phase2Conductor(self.env, offsets, x0=PHASE2_X0, x_end=PHASE2_X_END,
                                    step_length=SPEED * opts.step)
        team = Team(argvs, self.env, log_dir)
        self.interventions_open = True
        try:
            team.start()
            saved = 0
            while True:
                finished = conductor.done.wait(0.2)
                for scene in list(conductor.scenes)[saved:]:
                    self.store.add_scene(scene)
                    saved += 1
                if finished:
                    break
                if self.view.get('done') != len(self.store.data['scenes']):
                    self.show('phase2', running=True, scenes=len(self.store.data['offsets']),
                              done=len(self.store.data['scenes']))
                if team.dead():
                    raise RuntimeError(f'Phase II processes exited: {team.dead()} (logs in {log_dir})')
        finally:
            self.interventions_open = False
            team.stop()
            conductor.close()
            self.phase_node.close()
            self.phase_node = None

    def fit(self):
        from ..learning.estimators import fit_paper
        from ..reach.library import load_or_build_library
        from ..study.fits import first_passage_fit
        from ..study.protocol import TRUE_OMEGA
        scenes = self.store.data['scenes']
        states = intervention_states(scenes)
        lib = load_or_build_library()
        fits = {'paper': None, 'first_passage': None}
        if len(states):
            paper = fit_paper(lib.entries, states, true_vf=lib.entry(TRUE_OMEGA))
            fits['paper'] = {k: v for k, v in paper.to_dict().items() if k not in ('candidates',)}
            _, fp = first_passage_fit(scenes)
            fits['first_passage'] = fp
        self.store.data['fit'] = fits
        self.store.save()
        self.plot_fit()

    def learned_vf(self, estimator=None):
        """The learned value function of ``estimator`` (default --estimator), or None."""
        from ..reach.library import load_or_build_library
        fits = self.store.data.get('fit') or {}
        fit = fits.get((estimator or self.args.estimator).replace('-', '_'))
        if not fit:
            return None
        return load_or_build_library().entry(float(fit['omega_max']))

    def plot_fit(self):
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

    def fit_view(self) -> dict:
        fits = self.store.data['fit'] or {}
        lines = []
        for name in ('paper', 'first_passage'):
            f = fits.get(name)
            lines.append(f'{name.replace("_", "-")}: ' + (
                f'w_max {float(f["omega_max"]):g}, mu {float(f["mu"]):.3f}, sigma {float(f["sigma"]):.3f}'
                if f else 'no fit (no intervention): the Learned game uses the Standard set'))
        n = int(sum(1 for s in self.store.data['scenes'] if s['intervened']))
        return {'figure': 'files/fit.png', 'fits': lines, 'interventions': n,
                'scenes': len(self.store.data['scenes'])}

    def game(self, i, cond):
        """One Phase III game: a fresh graph (world, two robots with planner and filter, no
        supervisor process: the person is the supervisor) whose clock starts once both
        filters have the condition's set in force (``SetGate``)."""
        from ..study.games import condition_message
        from ..study.records import game_counts
        fit = (self.store.data['fit'] or {}).get(self.args.estimator.replace('-', '_'))
        vf = self.learned_vf()
        learned = {'learned': (vf, fit)} if (vf is not None and fit) else {}
        msg, alpha, ran = condition_message(cond, learned)
        world_seed = participant_number(self.store.pid) % 100000
        layout = team_layout(2, self.args.rate_factor, seed=world_seed, duration=self.args.game_seconds,
                             step=0.05, with_learner=False,
                             overrides={'safety_filter': {'use_learned': True, 'alpha_offset': 0.0}})
        argvs = without([node_argv(n.kind, n.namespace, n.params, n.remaps) for n in layout], 'supervisor')
        add_clock_gate(argvs, SET_GATE_TOPIC)
        self.interventions_open = True
        self.show('game', game=GAME_LABELS[i], seconds=self.args.game_seconds, running=False)
        try:
            result = self._graph(argvs, ['robot_0', 'robot_1'], f'game-{i + 1}-{cond}',
                                 self.args.game_seconds, set_msg=msg)
        finally:
            self.interventions_open = False
        counts = game_counts(result)
        counts.update(reason=result['reason'], position=i + 1, played=ran,
                      alpha=alpha, complete=counts['sim_time'] >= self.args.game_seconds - 1e-6)
        self.store.data['games'][cond] = counts
        self.store.save()

    def ask(self, i, pair):
        labels = (GAME_LABELS[i - 1], GAME_LABELS[i])
        self.answered.clear()
        self.show('likert', pair=list(labels), points=LIKERT_POINTS,
                  items=[{'key': k, 'text': t} for k, t in LIKERT_ITEMS])
        while not self.answered.wait(0.2):
            pass
        self.store.data['answers'].append({'after_game': i + 1, 'pair': list(pair),
                                           'labels': list(labels), 'values': self.answers,
                                           'scale': f'1 = much more {labels[0]}, 4 = the same, '
                                                    f'7 = much more {labels[1]}'})
        self.store.save()


def add_parser(subparsers):
    p = subparsers.add_parser('session', help="the paper's protocol for one human participant, "
                              'in the browser console', description=__doc__.splitlines()[0])
    p.add_argument('--participant', help='participant ID (letters, digits, _ . -)')
    p.add_argument('--analyse', nargs='+', type=Path, metavar='DIR',
                   help="instead of a session: the study's analysis (Table 1, ANOVA, Tukey) over "
                        'every subject.json under these folders, human and simulated alike')
    p.add_argument('--json', type=Path, default=None, help='with --analyse: write the summary here')
    p.add_argument('--out', type=Path, default=Path('sessions'), help='results folder (default sessions/)')
    p.add_argument('--port', type=int, default=8765, help='console port on 127.0.0.1 (default 8765)')
    p.add_argument('--offsets', type=int, default=42,
                   help='Phase II scenes: offsets evenly spaced in [-2.25, 2.25] (default 42, the paper)')
    p.add_argument('--phase1-seconds', type=float, default=60.0, help='Phase I free driving (0: skip)')
    p.add_argument('--game-seconds', type=float, default=120.0, help='each Phase III game')
    p.add_argument('--estimator', choices=('paper', 'first-passage'), default='paper',
                   help='the fit the Learned game uses (both are fitted and shown)')
    p.add_argument('--rate-factor', type=float, default=1.0,
                   help='sim seconds per wall second (1 for a person; more for scripted tests)')
    p.add_argument('--stop-after', choices=('phase2', 'fit'), default=None,
                   help='end there (the session stays resumable)')
    p.add_argument('--domain-id', type=int, default=None, help='ROS_DOMAIN_ID (default: inherited)')
    p.add_argument('--no-record', dest='record', action='store_false',
                   help='do not record the session\'s topics (default: a rosbag2 MCAP bag per run, '
                        'DIR/ID/recording-K)')
    p.set_defaults(func=run)
    return p


def analyse(dirs, json_path=None, out=sys.stdout) -> int:
    from ..study.analysis import format_table1
    from ..study.protocol import reference_sets
    from ..study.records import jsonable
    from ..study.summary import summarize
    found = sorted({p.parent for d in dirs for p in Path(d).rglob('subject.json')})
    if not found:
        print(f'no subject.json under {[str(d) for d in dirs]}', file=sys.stderr)
        return 2
    records = [load_subject(d) for d in found]
    kinds = [r['subject'].get('kind', 'simulated') for r in records]
    standard, conservative = reference_sets()
    summary = summarize(records, standard, conservative)
    print(f'{len(records)} subjects ({kinds.count("human")} human, '
          f'{len(kinds) - kinds.count("human")} simulated)', file=out)
    print(format_table1(summary['table1']), file=out)
    a = summary['anova']
    print(f"repeated-measures ANOVA (false positives): F({a['df_num']:g}, {a['df_den']:g}) = "
          f"{a['F']:.3g}, p = {a['p']:.3g}" + (f"  ({a['note']})" if 'note' in a else ''), file=out)
    for pair, t in summary['tukey'].items():
        print(f"Tukey {pair}: mean difference {t['mean_difference']:+.2f}, p = {t['p']:.3g}", file=out)
    if json_path:
        summary['answers'] = {str(r['subject'].get('participant', r['subject'].get('index'))): r['answers']
                              for r in records if r.get('answers')}
        Path(json_path).write_text(json.dumps(jsonable(summary), indent=1))
    return 0


def run(args) -> int:
    if args.analyse:
        return analyse(args.analyse, args.json)
    if not args.participant:
        print('session: --participant ID is required (or --analyse DIR ...)', file=sys.stderr)
        return 2
    try:
        session = Session(args)
    except (ParticipantExists, ValueError) as exc:
        print(f'session: {exc}', file=sys.stderr)
        return 2
    return session.run()
