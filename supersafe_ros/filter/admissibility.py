"""Is a learned safe set admissible?  Its unsafe region must contain the standard one.

A learned set (V_L at level alpha_L) may only replace the standard set (V_S at
standard_alpha) if it is no less conservative there:

    V_S(x) <= standard_alpha   =>   V_L(x) <= alpha_L (+ tol)     for every node x of V_S's grid

so that every state where the standard filter would act, the learned filter acts too,
and the filter's promise (no collision with a detected obstacle from a state above its
level) carries over. ``tol`` is half a grid cell in value units by default
(``reach.containment``). Both the filter (on receipt) and the learner (before it
publishes) apply this check.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..reach.containment import Containment, contains
from ..reach.value_function import ValueFunction


@dataclass(frozen=True)
class Admission:
    """Whether a learned set may be used (``ok``), why, and the containment check behind it."""

    ok: bool
    reason: str
    containment: Containment | None = None


def check_learned_set(standard: ValueFunction, standard_alpha: float,
                      learned: ValueFunction, learned_alpha: float, tol: float | None = None) -> Admission:
    """Accept ``learned`` at ``learned_alpha`` only if its unsafe set contains the standard one."""
    c = contains(learned, learned_alpha, standard, standard_alpha, tol=tol)
    if c.ok:
        return Admission(True, f'admissible: {c.describe()}', c)
    return Admission(False, f'less conservative than the standard set at alpha {standard_alpha:.3g}: '
                            f'{c.describe()}', c)
