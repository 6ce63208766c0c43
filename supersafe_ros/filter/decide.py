"""Where the decision is made: ``decide(columns, safe_set, clusters)``, a function of the
fleet's inputs read into columns, for any number of robots, a robot's own filter being the case
of one (``RobotFilter.step``). One direction, each step reading what the one before it made and
writing nothing back:

1. ``gather``: the inputs, read once into columns (``RobotColumns``, frozen): which robots are
   judged (``gather.problem``), their states now (``propagation``), commands (``commands``),
   holds, and whatever else a later step reads (no later step reads a filter: what a step reads of
   a few robots' inputs, it reads in their input records, in the columns); a lone robot's in
   Python floats (``gather_one_fast``);
2. ``constraints.table.constraint_rows``: each robot's constraints, rows of one
   ``law.ConstraintTable`` (per obstacle, ``pairs``; per cluster of close obstacles,
   ``cluster_rows``; of the detections within its reach when it has many, ``nearby``), data only;
3. ``law.choose``: the row each robot acts on or names (enter, ahead, stay);
   ``constraints.table.avoid_turns``: the avoid turns of the rows robots avoid by (read for those alone);
   ``law.command``: the rule's command;
   ``approach.limit``: for robots that can stop (``time_before_collision``), each speed cut
   so that the command's path enters no detected disc;
4. ``outputs.outputs``: the commands and each robot's explanation (``Decisions``);
5. ``sent.record_decisions``: what was sent, written into the filters, with the decision's updates
   of what it keeps for the next (``derived.Derived``: the clusters' frames, the detections'
   index; the only step that writes). ``step_many`` records every decision, ``decide_many`` none
   (its caller records what it sends: a lockstepped answer held is not sent).
"""
from __future__ import annotations

from .approach import limit
from .constraints.table import avoid_turns, constraint_rows
from .derived import Derived
from .gather import RobotColumns, gather, gather_one_fast
from .law import choose, command
from .outputs import Decisions, outputs
from .sent import record_decisions
from .types import SafeSet


def decide(columns: RobotColumns, safe_set: SafeSet, clusters=None):
    """(the ``Decisions`` of the robots of ``columns``, the decision's updates of what their filters
    keep: ``derived.Derived``), steps 2-4, with one vectorised evaluation of the law; reads nothing
    but its arguments and writes nothing (``clusters``, the ClusterStore for obstacles judged
    together, is asked for the union values it holds and told which to solve; None: the process's
    shared store for the robots' configuration, ``filter.clusters``)."""
    c = columns
    updates = Derived(c.detection_inputs, c.robot_index)
    table, solving = constraint_rows(c, safe_set, clusters, updates)
    choice = choose(table, c.overriding, c.clear_margin, c.failing, c.command_fresh, c.constant_speed)
    turns = avoid_turns(table, choice.row[choice.avoiding])
    ruling = command(table, choice, turns, c.failing, c.command_fresh, c.constant_speed, c.planned_turn, c.omega_max,
                     c.drive_speed, c.held_speed)
    limits = limit(c, ruling.omega, ruling.linear, ruling.code)
    return outputs(c, safe_set, table, ruling, solving, limits), updates


def decide_many(filters, safe_set: SafeSet, t, clusters=None) -> Decisions:
    """One decision per robot filter (``gather``, then ``decide``); nothing of it recorded as sent:
    a caller that may keep the commands back (a lockstepped answer held, ``runtime.lockstep``)
    records only those that go out (``sent.record_decisions``).

    Robots that can be judged use their current pose and detections; robots that
    fail safe use their last valid pose and detections if younger than
    ``hold_timeout``, else ``fail_safe_command``. ``clusters``: the ClusterStore
    for obstacles judged together (None: the process's shared store for the
    robots' configuration; see ``filter.clusters``). Returns ``Decisions``: the
    commands as lists, each robot's ``FilterOutput`` built when read, the updates in ``derived``.
    """
    columns = gather_one_fast(filters[0], t) if len(filters) == 1 else None
    if columns is None:
        columns = gather(filters, t)
    decisions, updates = decide(columns, safe_set, clusters)
    decisions.derived = updates
    return decisions


def step_many(filters, safe_set: SafeSet, t, clusters=None) -> Decisions:
    """``decide_many``, every command sent: the decisions recorded (step 5)."""
    decisions = decide_many(filters, safe_set, t, clusters)
    record_decisions(filters, decisions)
    return decisions
