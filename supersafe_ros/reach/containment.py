"""Does one sub-level set contain another?  {V_inner <= a_inner} ⊆ {V_outer <= a_outer}.

Used wherever a candidate safe set must be at least as conservative as a reference:
the learner's conservative prior (library entry against the true dynamics, both at
level 0) and the filter's check of a received learned set against its standard set
(each at its own level).

The check runs on the reference's grid nodes: every node x with
V_inner(x) <= a_inner must have V_outer(x) <= a_outer + tol. V_outer is interpolated
where the grids differ; an inner node outside the outer grid's rectangle cannot be
verified and counts as a violation. ``tol`` (value units) absorbs the discretisation
error between separately solved value functions: by default half the smallest (x, y)
spacing of the inner grid (0.125 m on the paper's 65 x 65 x 42 grid), i.e. half a cell,
since V changes by at most about one metre per metre of position.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .value_function import ValueFunction


@dataclass(frozen=True)
class Containment:
    """The outcome of ``contains``: ``ok``, how many inner nodes were checked, how
    many violate (outside the outer grid or above its level + tol), and the largest
    excess V_outer - a_outer among them (inf when a node lies outside the outer grid)."""

    ok: bool
    checked: int
    violations: int
    worst_excess: float
    tol: float

    def describe(self) -> str:
        if self.ok:
            return f'contains all {self.checked} nodes (tol {self.tol:.3g})'
        return (f'{self.violations} of {self.checked} nodes of the reference unsafe set are outside it '
                f'(worst by {self.worst_excess:.3g} > tol {self.tol:.3g})')


def default_tol(inner: ValueFunction) -> float:
    return 0.5 * float(min(inner.grid.spacing[:2]))


def contains(outer: ValueFunction, outer_level: float, inner: ValueFunction, inner_level: float,
             tol: float | None = None, _nodes_cache: dict | None = None) -> Containment:
    """Check {V_inner <= inner_level} ⊆ {V_outer <= outer_level} (+ tol) on inner's nodes."""
    if tol is None:
        tol = default_tol(inner)
    unsafe = inner.values <= inner_level
    checked = int(unsafe.sum())
    if checked == 0:
        return Containment(True, 0, 0, -np.inf, float(tol))
    if outer.grid == inner.grid:
        excess = outer.values[unsafe].astype(float) - outer_level
    else:
        nodes = None if _nodes_cache is None else _nodes_cache.get('nodes')
        if nodes is None:
            nodes = np.stack([m[unsafe] for m in inner.grid.mesh()], axis=1)
            if _nodes_cache is not None:
                _nodes_cache['nodes'] = nodes
        excess = np.where(outer.grid.contains(nodes), outer.value(nodes) - outer_level, np.inf)
    bad = excess > tol
    worst = float(excess.max())
    return Containment(not bool(bad.any()), checked, int(bad.sum()), worst, float(tol))
