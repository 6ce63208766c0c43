"""A participant session's wall time, and how fast a signal ends it.

Part ``run``: `supersafe session` with a scripted participant in headless Chromium on a
1280x800 laptop screen. The participant presses Start at once and answers at once, so
the time is the session's own (a person adds their reading and answering time). In
Phase II they stop the robot in every other scene, 3-5 m before the obstacle; in each
game they click one obstacle. Prints the wall time of each phase (from the page's phase
changes) and of the whole session. ``--paper``: the paper's timing (rate 1, 60 s of
Phase I, 42 scenes, games of 120 s); default: the CI test's short options. ``--phase3``:
paper (default: six games, three questionnaires) or short (three games, two).
``--screenshot PATH``: a picture of game 1 under way (after ``--shot-after`` sim s, with
no robot within 0.5 m of an obstacle), for the README.

Part ``stop``: SIGINT (``--signal``) at Start of Phase I, in Phase I, in Phase II, on
the fit screen and in a game, the participant scripted over the WebSocket; the time from
the signal to the command's exit, and whether it printed the resume hint and no traceback.

    .venv/bin/python bench/bench_session.py run [--paper] [--phase3 paper|short] [--screenshot PATH]
    .venv/bin/python bench/bench_session.py stop [--signal SIGTERM]
"""
import argparse
import asyncio
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))
from console_support import LAPTOP, Browser, free_port, wait_for_server, wait_until  # noqa: E402

PAPER = ('--offsets', '42', '--phase1-seconds', '60', '--game-seconds', '120', '--rate-factor', '1')
CI = ('--offsets', '3', '--phase1-seconds', '4', '--game-seconds', '6', '--rate-factor', '2')
STOP_POINTS = ('phase1-wait', 'phase1-run', 'phase2-run', 'fit-wait', 'game-run')

STATE = """
const r = [...document.querySelectorAll('[data-robot][data-x]')].filter(e => e.getAttribute('visibility') !== 'hidden');
const o = [...document.querySelectorAll('[data-obstacle-id]')];
return {phase: document.body.dataset.phase, waiting: document.body.dataset.waiting,
        running: document.body.dataset.running, sim: window.supersafeConsole.simTime,
        robots: r.map(e => [parseFloat(e.dataset.x), parseFloat(e.dataset.y)]),
        obstacles: o.map(e => [e.dataset.obstacleId, ...['cx', 'cy', 'r'].map(a => parseFloat(e.getAttribute(a)))]),
        crashes: document.querySelectorAll('[data-crash]').length};
"""


def session(out, pid, options, port):
    argv = [sys.executable, '-m', 'supersafe_ros.cli', 'session', '--participant', pid, '--out', str(out),
            '--port', str(port), *options]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)


def clear(s, margin=0.5):
    return s['robots'] and not s['crashes'] and all(
        (x - cx) ** 2 + (y - cy) ** 2 > (r + margin) ** 2 for x, y in s['robots'] for _, cx, cy, r in s['obstacles'])


def run(args):
    from selenium.common.exceptions import ElementNotInteractableException
    from selenium.webdriver.common.keys import Keys
    out = Path(tempfile.mkdtemp(prefix='bench-session-'))
    port = free_port()
    options = (PAPER if args.paper else CI) + ('--phase3', args.phase3)
    proc = session(out, 'b1', options, port)
    browser = None
    phases, t0 = [], None
    try:
        wait_for_server(f'http://127.0.0.1:{port}/', timeout=120)
        browser = Browser(size=LAPTOP)
        d = browser.driver
        d.get(f'http://127.0.0.1:{port}/')
        t0 = time.monotonic()
        scene, stopped, clicked, shot = None, set(), set(), False
        while proc.poll() is None:
            s = d.execute_script(STATE)
            key = (s['phase'], s['waiting'], s['running'])
            if not phases or phases[-1][0] != key:
                phases.append((key, time.monotonic()))
                print(f'{time.monotonic() - t0:8.1f} s  {s["phase"]}{" (waiting)" if s["waiting"] == "true" else ""}'
                      f'{" (running)" if s["running"] == "true" else ""}', flush=True)
            if s['waiting'] == 'true':
                try:
                    d.find_element('id', 'start').click()
                except ElementNotInteractableException:   # the screen is changing: next round
                    pass
            elif s['phase'] == 'phase2' and s['obstacles'] and s['robots']:
                oid, x = s['obstacles'][0][0], s['robots'][0][0]
                if oid != scene:
                    scene = oid
                if int(oid) % 2 == 0 and oid not in stopped and -5.0 <= x <= -3.0:
                    d.find_element('tag name', 'body').send_keys(Keys.SPACE)
                    stopped.add(oid)
            elif s['phase'] == 'game' and s['running'] == 'true':
                game = len([p for p in phases if p[0] == ('game', 'false', 'true')])
                if args.screenshot and not shot and game == 1 and s['sim'] >= args.shot_after and clear(s):
                    if d.save_screenshot(args.screenshot) and clear(d.execute_script(STATE)):
                        shot = True
                        print(f'screenshot of game 1 at sim {s["sim"]:.1f} s: {args.screenshot}', flush=True)
                if game not in clicked and s['obstacles'] and s['sim'] > 10:
                    d.find_element('css selector', '[data-obstacle-id]').click()
                    clicked.add(game)
            elif s['phase'] == 'likert':
                radios = d.execute_script("""const seen = new Set(); const out = [];
                    for (const r of document.querySelectorAll('input[data-likert]')) {
                      if (!seen.has(r.name) && r.value === '4') { seen.add(r.name); out.push(r); } }
                    return out;""")
                for r in radios:
                    r.click()
                d.find_element('css selector', 'button[data-action="answers"]').click()
                wait_until(lambda: d.execute_script('return document.body.dataset.phase') != 'likert', 60,
                           'the questionnaire to go')
            time.sleep(0.05)
        total = time.monotonic() - t0
    finally:
        if browser:
            browser.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(30)
    text = proc.stdout.read()
    print(text[-1500:])
    # wall time per phase: from a phase's first view to the next phase's
    spans = {}
    for (key, t), (_, t_next) in zip(phases, phases[1:] + [(None, t0 + total)]):
        spans[key[0]] = spans.get(key[0], 0.0) + (t_next - t)
    data = json.loads((out / 'b1' / 'session.json').read_text())
    print(f'options: {" ".join(options)}; exit code {proc.returncode}; '
          f'{len(data["scenes"])} scenes ({sum(s["intervened"] for s in data["scenes"])} stopped), '
          f'{len(data["plays"])} games, {len(data["answers"])} questionnaires')
    print('wall time per phase (s): ' + ', '.join(f'{k} {v:.1f}' for k, v in spans.items()))
    print(f'whole session: {total:.1f} s ({total / 60:.1f} min), the participant answering at once; '
          f'load {open("/proc/loadavg").read().split()[0]}')


async def script_until(port, target, proc, sig):
    """Press Start and answer as a page would, over the WebSocket, until ``target``; then the signal."""
    import aiohttp
    for _ in range(400):
        try:
            async with aiohttp.ClientSession() as s:
                async with s.ws_connect(f'http://127.0.0.1:{port}/ws') as ws:
                    while True:
                        m = json.loads((await ws.receive(timeout=300)).data)
                        v = m.get('session') if m['type'] == 'hello' else (m if m['type'] == 'session' else None)
                        if not v:
                            continue
                        here = v['phase'] + ('-wait' if v.get('waiting') else '') + ('-run' if v.get('running') else '')
                        if here == target:
                            if here.endswith('-run'):
                                await asyncio.sleep(1.0)
                            proc.send_signal(sig)
                            return time.monotonic()
                        if v.get('waiting'):
                            await ws.send_str(json.dumps({'type': 'start'}))
        except (aiohttp.ClientError, OSError):
            await asyncio.sleep(0.3)
    raise RuntimeError(f'never reached {target}')


def stop(args):
    sig = getattr(signal, args.signal)
    out = Path(tempfile.mkdtemp(prefix='bench-session-stop-'))
    options = ('--offsets', '3', '--phase1-seconds', '6', '--game-seconds', '8', '--rate-factor', '1')
    for target in STOP_POINTS:
        port = free_port()
        proc = session(out, 'st', options, port)
        t_sig = asyncio.run(script_until(port, target, proc, sig))
        code = proc.wait(60)
        dt = time.monotonic() - t_sig
        text = proc.stdout.read()
        print(f'{args.signal} at {target:12s}: exit {code} after {dt:.2f} s; resume hint '
              f'{"interrupted: resume with the same command" in text}; traceback {"Traceback" in text}; '
              f'load {open("/proc/loadavg").read().split()[0]}', flush=True)
    bags = {b.name: (b / 'metadata.yaml').exists() for b in sorted((out / 'st').glob('recording-*'))}
    print(f'bags left by the {len(STOP_POINTS)} runs: {bags}')


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('part', choices=('run', 'stop'))
    ap.add_argument('--paper', action='store_true', help="run: the paper's timing (default: the CI test's)")
    ap.add_argument('--phase3', choices=('paper', 'short'), default='paper',
                    help="run: the session's Phase III form (default paper: six games)")
    ap.add_argument('--screenshot', default=None, help='run: save a picture of game 1 here')
    ap.add_argument('--shot-after', type=float, default=40.0, help='run: sim seconds into game 1 for the picture')
    ap.add_argument('--signal', default='SIGINT', choices=('SIGINT', 'SIGTERM'))
    args = ap.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(120 + os.getpid() % 50))
    print(f'load before: {open("/proc/loadavg").read().strip()}  cores {os.cpu_count()}', flush=True)
    run(args) if args.part == 'run' else stop(args)


if __name__ == '__main__':
    main()
