"""Which safe set is in force: the standard set, or the newest admissible learned set.

``LearnedSetSelector`` takes value-function messages as serialized bytes (``offer``)
and hands them to a worker thread of its own, so decoding and checking a 50 MB set
never runs on the control path:

* a message larger than ``max_bytes`` is refused by its length, unread;
* a message whose ``source`` is ``standard`` resets to the local standard set (a
  received copy of it is not trusted);
* a learned set is put in force only if it is admissible at the current levels: its
  unsafe region at ``level(meta, alpha_offset)`` must contain the standard one at
  ``standard_alpha`` (``filter.admissibility``). One that fails is rejected with the
  reason and the set in force is kept;
* the checked set goes in force under ``lock`` and only if ``use_learned`` and the
  levels are still those it was checked with (they may change while it is checked);
  otherwise it is checked again with the new ones.

Only the newest job matters: a newer message supersedes one not yet handled. Changing
a level or ``use_learned`` (``set_standard_alpha``, ``set_alpha_offset``,
``set_use_learned``) checks the newest learned set anew. ``safe_set`` is the set in
force (the control path reads this one reference); ``set_update`` says what happened
to the last set ((accepted | rejected | ignored | none, why)), ``set_updates`` counts.

No ROS here: the decoder (``ros_io.cdr.serialized_to_value_function``), the level
of a learned set (``learning.levels.learned_alpha``) and the log (debug, info, error)
are given.
"""
from __future__ import annotations

from contextlib import nullcontext
import threading
import time

import numpy as np

from ..filter.admissibility import check_learned_set
from ..filter.types import SafeSet
from ..filter.law import evaluate_pairs

MESSAGE, RESELECT = 'message', 'reselect'    # the worker's jobs: a new message, the same set again


def _num(value) -> str:
    """A number of a set's metadata at 4 significant digits (as sent it has 17); else as it is."""
    return f'{value:.4g}' if isinstance(value, (int, float)) and not isinstance(value, bool) else str(value)


class LearnedSetSelector:
    """The set in force of a filter node, chosen off the control path (see the module)."""

    def __init__(self, standard_vf, standard_alpha, *, alpha_offset, use_learned, max_bytes,
                 decode, level, log, lock=None):
        self.standard_alpha = float(standard_alpha)
        self.alpha_offset = float(alpha_offset)
        self.use_learned = bool(use_learned)
        self.max_bytes = int(max_bytes)
        self.standard = SafeSet(standard_vf, self.standard_alpha, 'standard')
        self.safe_set = self.standard
        self.set_update = ('none', 'no value function received')
        self.set_updates = {'accepted': 0, 'rejected': 0}
        self._decode, self._level, self.log = decode, level, log
        # held by whoever changes the levels (the node's parameter callbacks) and while a
        # checked set goes in force; re-entrant, as the setters below take it too
        self._lock = lock if lock is not None else nullcontext()
        self._learned = None            # the newest well-formed learned value function
        self._work = threading.Condition()
        self._pending = None            # the newest unhandled job: (MESSAGE, bytes) | (RESELECT,)
        self._busy = False
        self._closing = False
        self._worker = threading.Thread(target=self._run_worker, name='value_function_worker', daemon=True)
        self._worker.start()

    # -- inputs -----------------------------------------------------------------------------
    def offer(self, data: bytes) -> None:
        """A serialized value-function message: refused by its size, or queued for the worker."""
        size = len(data)
        if size > self.max_bytes:
            self._reject(f'value function message of {size} bytes exceeds max_value_function_bytes '
                         f'({self.max_bytes}); not decoded')
            return
        # DEBUG: the set that goes in force (or is rejected) is the line at INFO
        self.log.debug(f'value function message received ({size} bytes): decoding and checking it off the '
                       f'control path')
        self._submit((MESSAGE, data))

    def set_standard_alpha(self, alpha: float) -> None:
        with self._lock:
            self.standard_alpha = float(alpha)
            self.standard = SafeSet(self.standard.vf, self.standard_alpha, 'standard')
            if self.safe_set.source == 'standard':
                self.safe_set = self.standard
            else:
                self._submit((RESELECT,))   # the learned set must pass again at the new level

    def set_alpha_offset(self, k: float) -> None:
        with self._lock:
            self.alpha_offset = float(k)
            if self._learned is not None and self.use_learned:
                self._submit((RESELECT,))

    def set_use_learned(self, use: bool) -> None:
        with self._lock:
            self.use_learned = bool(use)
            if not self.use_learned:
                self.safe_set = self.standard
            elif self._learned is not None:
                self._submit((RESELECT,))

    # -- the worker -----------------------------------------------------------------------------
    @property
    def busy(self) -> bool:
        """The worker is handling a job."""
        return self._busy

    def idle(self) -> bool:
        """Nothing queued and nothing being handled."""
        with self._work:
            return self._pending is None and not self._busy

    def wait_idle(self, timeout: float) -> bool:
        """Wait until ``idle()`` (True) or ``timeout`` seconds have passed (False)."""
        with self._work:
            return self._work.wait_for(lambda: self._pending is None and not self._busy, timeout)

    def _submit(self, job):
        with self._work:
            if self._pending is not None and self._pending[0] == MESSAGE and job[0] == RESELECT:
                return   # the queued message selects anew anyway
            self._pending = job    # only the newest set matters: a newer one supersedes
            self._work.notify_all()

    def _run_worker(self):
        while True:
            with self._work:
                while self._pending is None and not self._closing:
                    self._work.wait()
                if self._closing:
                    return
                job, self._pending = self._pending, None
                self._busy = True
            try:
                if job[0] == MESSAGE:
                    self._take_message(job[1])
                else:
                    self._select(revert_on_failure=True)
            except Exception as exc:   # never let the worker die: say why and keep the set
                self._reject(f'value function handling failed: {type(exc).__name__}: {exc}')
            finally:
                with self._work:
                    self._busy = False
                    self._work.notify_all()

    def _take_message(self, data: bytes):
        t0 = time.perf_counter()
        try:
            vf = self._decode(data)
        except (ValueError, TypeError) as exc:   # ValueFunctionMessageError is a ValueError
            self._reject(f'value function rejected: {exc}')
            return
        del data
        if str(vf.meta.get('source', 'learned')) == 'standard':
            # a reset to the standard set: ours, computed locally (a received copy is not trusted)
            self._learned = None
            self.safe_set = self.standard
            self._accept(f'standard set requested by the publisher: the local standard set is in force '
                         f'(alpha {self.standard_alpha:.4g})')
            return
        self._learned = vf
        self._select(revert_on_failure=False, decode_s=time.perf_counter() - t0)

    def _select(self, revert_on_failure, decode_s=None):
        """Put the newest learned set in force if it is admissible at the current levels."""
        vf = self._learned
        if vf is None:
            return
        if not self.use_learned:
            self.set_update = ('ignored', 'learned set received but use_learned is false: the standard '
                                          'set stays in force')
            self.log.info(self.set_update[1])
            return
        settings = (self.use_learned, self.standard_alpha, self.alpha_offset)
        alpha = self._level(vf.meta, self.alpha_offset)
        try:
            candidate = SafeSet(vf, alpha, 'learned')
        except ValueError as exc:
            self._reject(f'learned set rejected: {exc}', revert=revert_on_failure)
            return
        t0 = time.perf_counter()
        verdict = check_learned_set(self.standard.vf, self.standard_alpha, vf, alpha)
        check_s = time.perf_counter() - t0
        if not verdict.ok:
            self._reject(f'learned set (alpha {alpha:.4g}) rejected: {verdict.reason}',
                         revert=revert_on_failure)
            return
        # the law's lazily cached arrays (node gradients: 3 x the values) are built here, not
        # on the first decision that uses the set
        evaluate_pairs(vf, np.zeros((1, 3)))
        with self._lock:
            if (self.use_learned, self.standard_alpha, self.alpha_offset) != settings or self._learned is not vf:
                # the levels or the set changed while it was checked: check again with the new ones
                if self.use_learned:
                    self._submit((RESELECT,))
                return
            self.safe_set = candidate
        timing = f'decoded in {decode_s:.3g} s, ' if decode_s is not None else ''
        m = vf.meta
        self._accept(
            f'learned set in force: omega_max {_num(m.get("omega_max"))}, alpha {alpha:.4g} '
            f'(mu {_num(m.get("mu"))}, sigma {_num(m.get("sigma"))}), grid {vf.grid.shape}, '
            f'{m.get("interventions", "?")} interventions; {timing}checked in {check_s:.3g} s: '
            f'{verdict.reason}')

    # -- verdicts -------------------------------------------------------------------------------
    # the verdict first, then its count: a state built meanwhile (another thread) reads the counts
    # first (filter_state.shared_values), so a state with the new count carries the new verdict
    def _accept(self, reason):
        self.set_update = ('accepted', reason)
        self.set_updates['accepted'] += 1
        self.log.info(reason)

    def _reject(self, reason, revert=False):
        with self._lock:
            if revert and self.safe_set is not self.standard:
                self.safe_set = self.standard
                reason += '; back to the standard set'
            else:
                reason += f'; keeping the {self.safe_set.source} set'
        self.set_update = ('rejected', reason)
        self.set_updates['rejected'] += 1
        self.log.error(reason)

    def close(self):
        """Stop the worker (a job being handled is finished first, at most 5 s waited)."""
        with self._work:
            self._closing = True
            self._work.notify_all()
        self._worker.join(timeout=5.0)
