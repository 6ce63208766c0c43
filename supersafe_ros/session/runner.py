"""`supersafe session --participant ID [--out DIR]`: the paper's protocol for one person,
in the console (issue 8); `supersafe session --analyse DIR...`: the researcher's view.

One web server for the whole session (session.html); per phase a graph of node
processes (as `supersafe team` starts them) and, in this process, a node of the
session standing in for the simulated supervisor: it feeds the page, publishes the
person's interventions on /interventions, and acknowledges every pose on
/supervisor/step_done so the lockstep clock runs in real time with the person.

1. Phase I: ``--phase1-seconds`` (60) of free driving of one robot with the arrow keys
   (the session answers each pose with the keys' turn rate on robot_0/cmd_vel); the
   driven path is saved.
2. Phase II: the study's conductor (study/conductor.py) plays the calibration scenes
   from the participant's shuffled offsets; Space or a click intervenes. Each scene is
   saved as it ends, with or without an intervention; the clock pauses 3 s between scenes.
3. Fit: the paper's estimator and the first-passage estimator over the candidate
   library (conservative prior). The page says in words what changes; the numbers go
   to the terminal, session.json and fit.png. The Learned games use ``--estimator``.
4. Phase III (``--phase3``): ``paper`` (the default, the paper's protocol: three
   pairwise comparisons of two games, six games on six task versions, in the
   participant's row of the balanced design of ``study.design``; the questionnaire
   after each comparison, naming its two games) or ``short`` (three games, one per
   treatment; questionnaires after games 2 and 3). Games last ``--game-seconds`` (120);
   the treatments are unnamed on the page. The form is fixed when the participant is
   created: a resumed session keeps it.
Results: <out>/<ID>/session.json (everything, saved after every step) and, when
complete, subject.json + learned_vf.npz in the study's subject layout (session.py).
Ctrl-C (SIGINT) or SIGTERM at any point: the session ends within about a second with
everything done so far on disk; the same command resumes at the scene or game that was
running. A complete participant is never overwritten. SIGUSR1 writes every thread's
stack to stderr and the session goes on (what a hung session is doing).
"""
from __future__ import annotations

import faulthandler
from pathlib import Path
import signal
import sys
import threading
import time

from ..team import team_env
from ..console.state import ConsoleState, Field
from .phases import SessionPhases
from .protocol import ParticipantExists, SessionStore, check_answers, subject_record, write_subject

# rclpy, the console's web server and the study's modules (numpy, scipy, matplotlib) are
# imported where a phase needs them: `supersafe` imports this module to build its parser

STOP_GRACE = 1.2        # s the phase's processes get to exit after a signal (then SIGKILL)


class Interrupted(BaseException):
    """SIGINT or SIGTERM: raised once, in the main thread, wherever it is."""

    def __init__(self, signum):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class Session(SessionPhases):
    stop_grace = STOP_GRACE

    def __init__(self, args, out=sys.stdout):
        from ..console.server import ConsoleServer
        self.args = args
        self.out = out
        self.store = SessionStore(args.out, args.participant, args.offsets, args.phase3)
        self.env = team_env(args.domain_id)
        self.state = ConsoleState(['robot_0'], Field())
        self.server = ConsoleServer(self.state, self.intervene, port=args.port, log=self.say,
                                    extra_handlers={'start': self.on_start, 'keys': self.on_keys,
                                                    'answers': self.on_answers},
                                    max_connections=args.max_connections, unanswered=self.unanswered)
        self.server.index_page = 'session.html'
        self.server.files_dir = None       # the participant's page shows no files
        self.server.hello_extra = lambda: {'session': self.view}
        self.view = {'type': 'session', 'phase': 'welcome'}
        self.started = threading.Event()
        self.answers = None
        self.answered = threading.Event()
        self.keys = (False, False)
        self.phase_node = self.graph = self.conductor = self.recorder = None
        self.interventions_open = False
        self.signalled = None

    # -- page ------------------------------------------------------------------------------
    def say(self, text):
        print(text, file=self.out, flush=True)

    def show(self, phase, **fields):
        self.view = {'type': 'session', 'phase': phase, **fields}
        self.server.push(self.view)

    def wait_for_start(self, phase, **fields):
        self.started.clear()
        self.show(phase, waiting=True, **fields)
        while not self.started.wait(0.1):
            pass
        self.show(phase, waiting=False, **fields)

    def on_start(self, msg):
        # a Start for another screen (a late double click) starts nothing
        if not self.view.get('waiting') or msg.get('phase', self.view['phase']) != self.view['phase']:
            return {'type': 'error', 'message': 'nothing to start now'}
        self.started.set()
        return {'type': 'session_ack', 'ok': True}

    def on_keys(self, msg):
        self.keys = (bool(msg.get('left')), bool(msg.get('right')))
        return None

    def on_answers(self, msg):
        if self.view.get('phase') != 'likert':
            return {'type': 'error', 'message': 'no questions now'}
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
            return {'ok': False, 'message': 'Nothing to remove right now.'}
        if self.view.get('phase') != 'phase2':
            return node.bridge.intervene(obstacle_id)
        # the clock holds from before the intervention goes out: the scene it ends is
        # followed by the pause, not by the next scene's first steps
        before = self.phase2_intervening()
        result = node.bridge.intervene(obstacle_id)
        if isinstance(result, dict):       # nothing went out: no pause
            self.pause = before
            self.show_phase2()
        return result

    def unanswered(self, obstacle_id, future):
        node = self.phase_node
        if node is None:
            return {'ok': False, 'message': 'Nothing to remove right now.'}
        return node.bridge.unanswered(obstacle_id, future)

    # -- the run ---------------------------------------------------------------------------
    def _on_signal(self, signum, frame):
        if self.signalled is not None:
            return                  # the first one is being handled: the cleanup is bounded
        self.signalled = signum
        raise Interrupted(signum)

    def run(self) -> int:
        handlers = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            try:
                outcome = None
                try:
                    port = self.server.start()
                except OSError as exc:       # the port is taken (another session?)
                    print(f'session: cannot serve the console on port {self.args.port}: {exc.strerror or exc}; '
                          'stop the other program or choose another --port', file=sys.stderr)
                    return 2
                self.say(f'console: http://127.0.0.1:{port}/   (open it on the participant\'s screen)')
                self.say(f'participant {self.store.pid}: {"resuming" if self.store.resumed else "new"}, '
                         f'results in {self.store.dir}')
                form = self.store.data['plan']['form']
                if form != self.args.phase3:
                    self.say(f'Phase III: this participant began in the {form} form, which it keeps '
                             f'(--phase3 {self.args.phase3} applies to new participants)')
                code = self.protocol()
            except (Interrupted, RuntimeError) as exc:
                outcome = exc
            self.cleanup(quick=outcome is not None)
        except Interrupted as exc:       # between the protocol's end and the cleanup
            outcome = exc
            self.cleanup(quick=True)
        finally:
            for s, h in handlers.items():
                signal.signal(s, h)
        if isinstance(outcome, Interrupted):
            self.say(f'interrupted: resume with the same command ({outcome}; everything done so far '
                     f'is in {self.store.path})')
            return 128 + outcome.signum
        if isinstance(outcome, RuntimeError):
            self.say(f'session stopped: {outcome}; everything done so far is in {self.store.path}; '
                     'resume with the same command')
            return 1
        return code

    def cleanup(self, quick: bool):
        """Stop whatever runs, within about STOP_GRACE + 1 s after a signal: the phase's
        processes (SIGINT at once, SIGKILL after the grace), its node, the recorder, the
        page's socket; and save what is in memory."""
        self.signalled = self.signalled or -1       # from here on a signal only waits
        try:
            self.end_graph(grace=self.stop_grace if quick else 5.0)
            self.stop_recording(max_wait=0.4 if quick else 5.0)
            if quick:
                self.show('stopped')
        finally:
            self.store.save()
            self.server.stop(timeout=0.5 if quick else 1.5)

    def protocol(self) -> int:
        data = self.store.data
        a = self.args
        if data['phase1'] is None and a.phase1_seconds > 0:
            self.wait_for_start('phase1', seconds=a.phase1_seconds)
            self.phase1()
        if self.store.remaining_offsets():
            self.wait_for_start('phase2', scenes=len(data['offsets']), done=len(data['scenes']))
            self.phase2()
        if a.stop_after == 'phase2':
            return 0
        if data['fit'] is None:
            self.show('fitting')
            self.fit()
        if not data.get('fit_seen'):       # once: a resumed Phase III goes straight on
            self.wait_for_start('fit', **self.fit_screen())
            data['fit_seen'] = True
            self.store.save()
        if a.stop_after == 'fit':
            return 0
        games, questionnaires = data['plan']['games'], data['plan']['questionnaires']
        for g in games:
            k = g['game']
            if len(data['plays']) < k:
                self.wait_for_start('game', game=f'Game {k}', number=k, of=len(games), seconds=a.game_seconds)
                self.game(g)
            for j, q in enumerate(questionnaires):
                if q['after_game'] == k and len(data['answers']) <= j:
                    self.ask(q)
        write_subject(self.store.dir, subject_record(data, self.learned_vf(), a.estimator))
        data['complete'] = True
        self.store.save()
        self.show('done')
        self.say(f'session complete: {self.store.dir / "subject.json"}')
        time.sleep(0.5)   # the page gets its last message
        return 0


def add_parser(subparsers):
    p = subparsers.add_parser('session', help="the paper's protocol for one human participant, "
                              'in the browser console', description=__doc__.splitlines()[0])
    p.add_argument('--participant', help='participant ID (letters, digits, _ . -)')
    p.add_argument('--analyse', nargs='+', type=Path, metavar='DIR',
                   help='instead of a session: list every participant under these folders with its '
                        "state, and run the study's analysis over the complete ones (human and "
                        'simulated alike)')
    p.add_argument('--json', type=Path, default=None, help='with --analyse: write the summary here')
    p.add_argument('--csv', type=Path, default=None,
                   help='with --analyse: one row per participant and game (treatment, comparison, version, '
                        'counts); the answers, one row per participant, comparison and item, go to '
                        'NAME_answers.csv beside it')
    p.add_argument('--out', type=Path, default=Path('sessions'), help='results folder (default sessions/)')
    p.add_argument('--port', type=int, default=8765, help='console port on 127.0.0.1 (default 8765)')
    p.add_argument('--max-connections', type=int, default=4,
                   help='most pages open on the console at once (default 4)')
    p.add_argument('--offsets', type=int, default=42,
                   help='Phase II scenes: offsets evenly spaced in [-2.25, 2.25] (default 42, the paper)')
    p.add_argument('--phase1-seconds', type=float, default=60.0,
                   help="Phase I free driving, s (default 60: the paper's minute; 0: skip)")
    p.add_argument('--game-seconds', type=float, default=120.0, help='each Phase III game')
    p.add_argument('--phase3', choices=('paper', 'short'), default='paper',
                   help="Phase III: paper (default; three pairwise comparisons, six games on six task "
                        'versions, a questionnaire after each comparison) or short (three games, one per '
                        'treatment, for quick runs and demos); a resumed participant keeps its form')
    p.add_argument('--estimator', choices=('paper', 'first-passage'), default='paper',
                   help='the fit the Learned game uses (both are fitted)')
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


def _interrupt(signum, frame):
    raise Interrupted(signum)


def print_stacks_on_sigusr1() -> None:
    """SIGUSR1 prints every thread's stack to stderr, the session going on.

    Printed by a thread of its own that waits for the signal (``sigwait``), with the GIL held:
    faulthandler's own C-level handler (``faulthandler.register``) reads the other threads'
    frames while they run, and a session signalled so was seen to end in SIGSEGV. SIGUSR1 is
    blocked in this thread and every thread it starts after (they inherit the mask); a thread
    started before may still take it, so a Python-level handler prints the same."""
    def dump(*_):
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)

    signal.signal(signal.SIGUSR1, dump)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGUSR1})

    def wait_and_dump():
        while True:
            signal.sigwait({signal.SIGUSR1})
            dump()

    threading.Thread(target=wait_and_dump, name='stacks on SIGUSR1', daemon=True).start()


def run(args) -> int:
    if args.analyse:
        from .analysis import analyse
        return analyse(args.analyse, json_path=args.json, csv_path=args.csv)
    if not args.participant:
        print('session: --participant ID is required (or --analyse DIR ...)', file=sys.stderr)
        return 2
    if args.max_connections < 1 or not args.rate_factor > 0:
        print('session: --max-connections must be >= 1 and --rate-factor > 0', file=sys.stderr)
        return 2
    # evidence from a session that hangs: `kill -USR1 PID` prints where every thread is
    print_stacks_on_sigusr1()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, _interrupt)
    try:
        session = Session(args)      # before its run: a signal here leaves nothing running
    except (ParticipantExists, ValueError) as exc:
        print(f'session: {exc}', file=sys.stderr)
        return 2
    except Interrupted as exc:
        print(f'interrupted: resume with the same command ({exc}; nothing had started)', flush=True)
        return 128 + exc.signum
    # Session.run installs its own handlers over these: there is no moment without one
    return session.run()
