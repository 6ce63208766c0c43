"""Where the decision is made: ``step_many(filters, safe_set, t)`` decides for any number of
robots, a robot's own filter being the case of one (``RobotFilter.step``). One direction,
each step reading what the one before it made and writing nothing back:

1. ``gather``: the inputs, read once into columns (``RobotColumns``): which robots are judged
   (``gather.problem``), their states now (``propagation``), commands (``commands``), holds;
   a lone robot's in Python floats (``gather_one_fast``);
2. ``constraints.constraint_rows``: each robot's constraints, rows of one
   ``law.ConstraintTable`` (per obstacle, ``pairs``; per cluster of close obstacles,
   ``cluster_rows``; of the detections within its reach when it has many, ``nearby``);
3. ``law.decide_rows``: the rule over the table;
   ``approach.limit``: for robots that can stop (``time_before_collision``), each speed cut
   so that the command's path enters no detected disc;
4. ``outputs.outputs``: the commands and each robot's explanation (``Decisions``);
5. ``sent.record``: what was sent, written into the filters, with what the decision keeps for the
   next (``derived.Derived``: the clusters' frames, the detections' index; the only step that writes);
   ``step_many`` records every decision, ``decide_many`` none (its caller records what it
   sends: a lockstepped answer held is not sent).
"""
from __future__ import annotations

from .approach import limit
from .constraints import constraint_rows
from .derived import Derived
from .gather import gather, gather_one_fast
from .law import decide_rows
from .outputs import Decisions, outputs
from .sent import record_decisions
from .types import SafeSet


def decide_many(filters, safe_set: SafeSet, t, clusters=None) -> Decisions:
    """One decision per robot filter, with one vectorised evaluation of the law; nothing of it
    recorded as sent (steps 1-4): a caller that may keep the commands back (a lockstepped
    answer held, ``runtime.lockstep``) records only those that go out (``sent.record_decisions``).

    Robots that can be judged use their current pose and detections; robots that
    fail safe use their last valid pose and detections if younger than
    ``hold_timeout``, else ``fail_safe_command``. ``clusters``: the ClusterStore
    for obstacles judged together (None: the process's shared store for the
    robots' configuration; see ``filter.cluster``). Returns ``Decisions``: the
    commands as lists, each robot's ``FilterOutput`` built when read.
    """
    cols = gather_one_fast(filters[0], t) if len(filters) == 1 else None
    if cols is None:
        cols = gather(filters, t)
    derived = Derived()
    table, n_groups, solving = constraint_rows(cols, safe_set, clusters, derived)
    decided = decide_rows(table, len(cols.use), n_groups, cols.overriding, cols.margin, cols.failing, cols.fresh,
                          cols.planned, cols.bang, cols.drive, cols.held, cols.constant)
    limits = limit(cols, *decided[:3])
    decisions = outputs(filters, cols, safe_set, table, decided, solving, limits, t)
    decisions.derived = derived
    return decisions


def step_many(filters, safe_set: SafeSet, t, clusters=None) -> Decisions:
    """``decide_many``, every command sent: the decisions recorded (step 5)."""
    decisions = decide_many(filters, safe_set, t, clusters)
    record_decisions(filters, decisions)
    return decisions
