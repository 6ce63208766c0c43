"""Headless Chromium for the console's browser tests and benchmark.

Debian's chromium and chromium-driver (scripts/setup.sh installs them), driven by
selenium with the driver's path given explicitly, so selenium-manager never tries to
download anything.
"""
from __future__ import annotations

import asyncio
import os
import select
import shutil
import signal
import socket
import tempfile
import time
import urllib.error
import urllib.request

CHROMIUM = os.environ.get('SUPERSAFE_CHROMIUM', '/usr/bin/chromium')
CHROMEDRIVER = os.environ.get('SUPERSAFE_CHROMEDRIVER', '/usr/bin/chromedriver')
FLAGS = ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
         '--disable-background-networking', '--disable-component-update', '--disable-sync',
         '--disable-dev-shm-usage']
# screens a participant's page must fit: a 1280x800 laptop and a 1920x1080 screen. Headless
# Chromium's window keeps 143 px for its bars, as a desktop browser does: the page gets
# 1280x657 and 1920x937 (window.innerWidth x innerHeight).
LAPTOP = (1280, 800)
DESKTOP = (1920, 1080)


class Browser:
    """A headless Chromium with a fresh profile; ``driver`` is the selenium WebDriver.
    ``size``: the window, which headless Chromium makes the viewport (innerWidth x innerHeight)."""

    def __init__(self, size=(1200, 760)):
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
        for path in (CHROMIUM, CHROMEDRIVER):
            if not os.access(path, os.X_OK):
                raise RuntimeError(f'{path} is missing: apt-get install -y chromium chromium-driver '
                                   '(scripts/setup.sh does this as root)')
        self.profile = tempfile.mkdtemp(prefix='supersafe-chromium-')
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for flag in FLAGS + [f'--user-data-dir={self.profile}', f'--window-size={size[0]},{size[1]}']:
            options.add_argument(flag)
        self.driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)

    def pid(self) -> int | None:
        """The browser's process id (for CPU accounting)."""
        try:
            return self.driver.service.process.pid
        except AttributeError:
            return None

    def close(self):
        try:
            self.driver.quit()
        finally:
            shutil.rmtree(self.profile, ignore_errors=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def http_status(url: str, timeout: float = 5.0) -> int:
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code


def wait_until(predicate, timeout: float, what: str, period: float = 0.1):
    """Poll ``predicate`` until it returns a truthy value (returned) or ``timeout`` passes.
    ``what`` may be a callable, evaluated at the time-out (to describe the state then)."""
    deadline = time.monotonic() + timeout
    last_exc = None
    while time.monotonic() < deadline:
        try:
            value = predicate()
            if value:
                return value
        except Exception as exc:   # e.g. connection refused while a server starts
            last_exc = exc
        time.sleep(period)
    raise AssertionError(f'timed out after {timeout} s waiting for {what() if callable(what) else what}'
                         + (f' (last error: {last_exc!r})' if last_exc else ''))


def wait_for_sim(predicate, clock, sim_seconds: float, what, stalled_after: float = 120.0, period: float = 0.1):
    """Poll ``predicate`` until it returns a truthy value (returned); fail once ``clock()``,
    a simulated clock, has run ``sim_seconds`` since the call, or has not moved for
    ``stalled_after`` wall seconds. A bound in the simulation's own time holds however
    loaded the machine is; the wall-clock guard only catches a clock that stopped. A clock
    that goes back (a new run's clock, from 0) counts on from there. ``what`` and errors
    as in ``wait_until``."""
    def read():
        try:
            return float(clock())
        except Exception as exc:    # e.g. a page being reloaded
            errors[:] = [exc]
            return last
    errors, last = [], None
    start = last = read()
    elapsed, moved_wall = 0.0, time.monotonic()
    while True:
        try:
            value = predicate()
            if value:
                return value
        except Exception as exc:
            errors[:] = [exc]
        now = read()
        if now != last:
            if last is not None:
                elapsed += now - last if now > last else now
            last, moved_wall = now, time.monotonic()
        stalled = time.monotonic() - moved_wall > stalled_after
        if stalled or elapsed > sim_seconds:
            described = what() if callable(what) else what
            error = f' (last error: {errors[-1]!r})' if errors else ''
            raise AssertionError(
                f'the simulated clock stood at {now} s for {stalled_after} s waiting for {described}{error}'
                if stalled else
                f'{sim_seconds} simulated s passed waiting for {described} (clock from {start} s to {now} s){error}')
        time.sleep(period)


def wait_for_server(url: str, timeout: float = 60.0):
    wait_until(lambda: http_status(url, timeout=2.0) == 200, timeout, f'{url} to answer 200')


async def closed_by_server(reader, timeout=30.0) -> bool:
    """The server closed the connection (an end of file, or a reset: it had unread bytes)."""
    try:
        return await asyncio.wait_for(reader.read(), timeout) == b''
    except ConnectionResetError:
        return True


def dump_stacks(proc, timeout: float = 10.0) -> str:
    """SIGUSR1 to a running ``supersafe session`` (its stdout a pipe, stderr joined to it):
    the stack of every thread, read here until the main thread's (printed last) is complete
    or ``timeout`` passes. A signal sent while the dump is being written could end the
    process under it: the caller signals only after this returns."""
    if proc.poll() is not None:
        return ''
    proc.send_signal(signal.SIGUSR1)
    fd, chunks = proc.stdout.fileno(), []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.2)
        if ready:
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            chunks.append(chunk)
            if b'in _run_module_as_main' in b''.join(chunks):
                break
    return b''.join(chunks).decode(errors='replace')
