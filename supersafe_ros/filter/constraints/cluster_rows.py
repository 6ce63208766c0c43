"""The cluster constraints: obstacles closer than the link distance judged by their union.

Two discs closer than 2 radius + a turning diameter can trap a robot that avoids each
alone (filter.clusters). For every robot with more than one detection, per cluster of its
detections: one constraint row (``filter.law.ConstraintTable``) with

* the union's value, solved in the background by the ``ClusterStore`` and read in the
  cluster's canonical frame, when it is in force;
* else the loiter-circle fallback (``geometry.orbit_value``) from a state with a clear circle.

Robots given one detections array (the fleet node's batched topic) share its cluster
frames; robots sent equal arrays share them by content (``cluster_frames``).

Detections that change every message (discs from a laser scan or a point cloud, taken with
``solve_clusters=False``) are judged with the store's ``fallback_twin``: their clusters by
the loiter fallback alone, which is sound for any layout, and no union solve is queued (a
new geometry each message would queue one per message, none in force in time): the work per
message stays bounded (clusters of at most ``store.SOLVE_MEMBERS_MAX`` get a canonical
frame, larger ones none).
"""
from __future__ import annotations

from collections import OrderedDict
import itertools
import math
from typing import NamedTuple

import numpy as np

from ..clusters.geometry import canonical, components
from ..clusters.store import SOLVE_MEMBERS_MAX, default_cluster_store
from ..elementwise import py_max, py_min
from ..law import better_bang, first_min, first_min_of_runs
from ..propagation import arc_flow, bang_ends


class ClusterFrames:
    """The clusters (>1 member) of one detections array and their canonical frames, as arrays
    (computed once per detections array and store settings; robots given the same array, as
    the fleet node's batched detections, share them). ``groups`` and their ``canon``
    (``cluster_frame``'s, None: compute it), if given, are the clusters (a robot's detections
    within reach, ``filter.constraints.nearby``). A cluster of more than ``store.SOLVE_MEMBERS_MAX``
    has no key (never solved) and no canonical frame: its fallback is read in the map frame."""

    def __init__(self, det, store, groups=None, canon=None):
        st = store.settings
        if groups is None:
            groups = [g for g in components(det, st.link_distance) if len(g) > 1]
        self.n = len(groups)
        self.keys, self.centres = [], []
        origin, angle, cs, sn = [], [], [], []
        for gi, g in enumerate(groups):
            given = canon[gi] if canon is not None else None
            key, o, a, c = given if given is not None else cluster_frame(det[g], st)
            self.keys.append(key)
            self.centres.append(c)
            origin.append(o)
            angle.append(a)
            cs.append(math.cos(a))      # as geometry.to_frame computes them
            sn.append(math.sin(a))
        size = [len(g) for g in groups]
        # per cluster: origin x, y, angle, cos, sin, members; per member (in its cluster's order): index, x, y
        self.frames = np.column_stack([np.array(origin, dtype=float).reshape(-1, 2), angle, cs, sn, size])
        member = np.concatenate(groups) if groups else np.zeros(0, np.intp)
        self.members = np.column_stack([member, det[member]])


def cluster_frame(centres, settings):
    """``geometry.canonical`` of a cluster's centres, or for a cluster too large to be solved
    (more than ``store.SOLVE_MEMBERS_MAX``) (None, its centroid, 0, None), without the
    all-pairs search of its farthest pair."""
    if len(centres) > SOLVE_MEMBERS_MAX:
        return None, centres.mean(axis=0), 0.0, None
    return canonical(centres, settings.key_resolution)


_FRAMES_BY_CONTENT: OrderedDict = OrderedDict()      # (link, resolution, shape, bytes) -> _ClusterFrames
_FRAMES_KEPT = 4096
_FRAMES_BYTES_KEPT = 32 * 1024 * 1024     # and at most this many bytes of detections in the keys
_frames_bytes = 0


def cluster_frames(det, store) -> ClusterFrames:
    """The cluster frames of a detections array, shared by content: robots sent equal
    detections in separate messages (per-robot topics) compute them once. Bounded: the
    oldest entries go first."""
    global _frames_bytes
    st = store.settings
    key = (st.link_distance, st.key_resolution, det.shape, det.tobytes())
    got = _FRAMES_BY_CONTENT.get(key)
    if got is None:
        if not _FRAMES_BY_CONTENT:
            _frames_bytes = 0
        if len(_FRAMES_BY_CONTENT) >= _FRAMES_KEPT:
            for old in list(_FRAMES_BY_CONTENT)[:_FRAMES_KEPT // 4]:
                _frames_bytes -= len(old[3])
                del _FRAMES_BY_CONTENT[old]
        while _FRAMES_BY_CONTENT and _frames_bytes + len(key[3]) > _FRAMES_BYTES_KEPT:
            _frames_bytes -= len(_FRAMES_BY_CONTENT.popitem(last=False)[0][3])
        got = _FRAMES_BY_CONTENT[key] = ClusterFrames(det, store)
        _frames_bytes += len(key[3])
        got.frames.flags.writeable = got.members.flags.writeable = False
    return got


FEW_FALLBACKS = 64     # up to this many instances on the loiter fallback (or two a robot), all are read

_NONE_I, _NONE_F, _NONE_B = np.zeros(0, np.intp), np.zeros(0), np.zeros(0, bool)
_NONE_I.flags.writeable = _NONE_F.flags.writeable = _NONE_B.flags.writeable = False
_NO_CLUSTERS = dict(robot=_NONE_I, index=_NONE_I, value=_NONE_F, level=_NONE_F, turns=None, value_next=_NONE_F,
                    obstacle=_NONE_I, xy=_NONE_F.reshape(0, 2), group=_NONE_I, members=_NONE_I, fallback=_NONE_B,
                    member_pairs=_NONE_I, member_groups=_NONE_I, n_groups=0)


def cluster_rows(configs, inputs, states, planned, horizon, speed, bang, cluster_alpha, margin, dets, start,
                 pairs, store_arg, frames, derived) -> dict:
    """The cluster constraints of every robot, as table columns (see ``law.ConstraintTable``).

    A robot with clusters enabled and more than one detection gets, per cluster of its
    detections (obstacles within the link distance, see ``filter.clusters``), one row:

    * the union's value if solved, read at its state now; its turn is the bang
      (+-w_max) with the larger V at the end of its hold (ties left), and the planner's
      command is judged by V where its hold ends and after the better bang held one
      more period from there (the smaller): a pass never leaves the robot where no
      held turn keeps V above the level;
    * else the loiter-circle fallback (``geometry.orbit_value``) if the robot's state now
      has a clear circle (its invariant holds only from such a state; from any other,
      the per-obstacle rows, always in the table, are the best known until the
      union's value is in force).

    Either way the cluster's members' own rows join the cluster's group. All (robot,
    cluster) instances are evaluated together: one arc_flow for the holds, one value
    read per distinct cluster value, one fallback evaluation per store (two: the fallback
    is read only where it can act or be the robot's smallest row; 1,000 robots among 30
    obstacles over 80 x 80 m: 820 of its 6,000 instances). The rows' turns are read on demand
    from ``turns`` (``UnionTurns``: ``union_turns``, for the rows robots avoid by). Per robot row:
    ``configs``, ``inputs`` (its detections' input record: whether their clusters' union values
    may be solved), ``states`` and the rest (``gather.RobotColumns``'); ``start``: its first pair's
    index among all robots' pairs; ``pairs``: (robot row, V, level) of the pair rows. A fallback
    row that can neither act nor be its robot's smallest V - level is left out
    (``_fallback_bound``). ``frames``: per robot row, its
    ``ClusterFrames`` when given (a robot's detections within reach, ``filter.constraints.nearby``; None: those
    of its detections array). ``derived``: the decision's ``filter.derived.Derived``, through which
    the frames are read and kept.
    """
    m = len(configs)
    solving = np.zeros(m, dtype=np.intp)
    entries = _entries(configs, inputs, dets, store_arg, frames, derived)
    if not entries:
        return dict(_NO_CLUSTERS, solving=solving)
    fc = _FrameColumns(entries)
    inst_row, inst_gi, frame, val, busy = _instances(entries, fc, states, speed, horizon)
    n_inst = len(inst_row)
    size = fc.size[frame]
    member_inst = np.repeat(np.arange(n_inst), size)
    mg = fc.mstart[frame][member_inst] + (np.arange(int(size.sum())) - np.repeat(np.cumsum(size) - size, size))
    members, member_xy = fc.member[mg], fc.member_xy[mg]
    np.add.at(solving, inst_row, busy.astype(np.intp))
    member_pairs = start[inst_row][member_inst] + members     # the members' own rows join the cluster
    union = UnionFrames(fc.values, val, fc.origin[frame], fc.angle[frame], fc.cos[frame], fc.sin[frame])

    # holds from the state now: the planner's command, then both bangs from its end (the bangs
    # from the state now give the avoid turn, read only for the rows a robot names: union_turns)
    rows = np.flatnonzero(np.bincount(inst_row, minlength=m))     # np.unique's, without a sort
    s0 = states[rows]
    ahead_r = arc_flow(s0, speed[rows], planned[rows], horizon[rows])
    pts = bang_ends(ahead_r, speed[rows], bang[rows], horizon[rows])
    where = np.searchsorted(rows, inst_row)
    nr = len(rows)
    state, ahead = s0[where], ahead_r[where]

    # the member nearest to the robot (the first on ties) names the cluster: an instance's members
    # are one run of member_inst, in their cluster's order (distances are finite: states are)
    d = np.hypot(*(member_xy - states[inst_row[member_inst], :2]).T)
    nearest_m = first_min_of_runs(d, member_inst, np.cumsum(size) - size)
    nearest, nearest_xy = members[nearest_m], member_xy[nearest_m]

    # the union's value where it is in force: now, after the hold and each bang after it
    ok = val >= 0
    v4 = np.full((4, n_inst), np.inf)
    if np.any(ok):
        idx = np.flatnonzero(ok)
        w_ = where[idx]
        v4[:, idx] = union.read(idx, np.stack([state[idx], pts[w_], pts[nr + w_], ahead[idx]]))[0]
    u_next = py_min(v4[3], py_max(v4[1], v4[2]))

    # the loiter fallback where no union value is in force; of many instances (more than two a robot:
    # robots among many clusters), read only where it can act or be its robot's smallest row (a
    # fallback row's level is 0; _fallback_bound):
    # first the rows that could act and each robot's row of the smallest bound not above its
    # smallest row read so far, then the rows whose bound is not above the smallest row read then;
    # the others are no row
    f_value = np.full((2, n_inst), -np.inf)
    f_turn = np.zeros(n_inst)
    inst_store = fc.store[frame]
    level = cluster_alpha[inst_row]
    fallback = ~ok
    if np.count_nonzero(fallback) <= max(FEW_FALLBACKS, 2 * m):      # (a lone robot's few: all read, at once)
        _read_fallback(fallback, f_value, f_turn, state, ahead, member_xy, member_inst, inst_store, fc.stores)
    else:
        bound = _fallback_bound(d[nearest_m], inst_store, fc.stores, speed[inst_row] * horizon[inst_row])
        low = np.full(m, np.inf)        # per robot row, the smallest V - level read so far
        np.minimum.at(low, pairs[0], pairs[1] - pairs[2])
        np.minimum.at(low, inst_row[ok], v4[0][ok] - level[ok])
        first = fallback & ~((bound[0] > margin[inst_row]) & (bound[1] > 0.0))    # could enter, stay or look ahead
        least = first_min(inst_row, inst_gi, bound[0], fallback & (bound[0] <= low[inst_row]), m)
        first[least[least >= 0]] = True
        _read_fallback(first, f_value, f_turn, state, ahead, member_xy, member_inst, inst_store, fc.stores)
        kept_value = f_value[0][first]
        np.minimum.at(low, inst_row[first], np.where(kept_value > 0.0, kept_value, np.inf))
        _read_fallback(fallback & ~first & (bound[0] <= low[inst_row]), f_value, f_turn, state, ahead, member_xy,
                       member_inst, inst_store, fc.stores)
    keep = ok | (f_value[0] > 0.0)
    kept = np.flatnonzero(keep)
    turn_hold = np.array([store.settings.turn_hold for store in fc.stores])[inst_store]
    turns = UnionTurns(kept, ok, f_turn, inst_row, state, turn_hold, union, horizon, speed, bang)
    return dict(robot=inst_row[keep], index=inst_gi[keep], value=np.where(ok, v4[0], f_value[0])[keep],
                level=np.where(ok, level, 0.0)[keep], turns=turns,
                value_next=np.where(ok, u_next, f_value[1])[keep], obstacle=nearest[keep],
                xy=nearest_xy[keep], group=np.arange(n_inst)[keep], members=size[keep], fallback=~ok[keep],
                member_pairs=member_pairs, member_groups=member_inst, n_groups=n_inst, solving=solving)


def _entries(configs, inputs, dets, store_arg, frames, derived) -> list:
    """[(ClusterFrames, store, robot rows)] of the robots with clusters: robots with one
    detections array and configuration share an entry (a batched fleet: one); each robot
    keeps its frames (its ``'clusters'``, ``derived``) while its detections array is the same."""
    entries = {}      # (frames, store) -> rows of the robots that use them, in order
    shared = {}
    stores = {}       # id(config) -> its default store (robots of a fleet share one config)
    joins = {}        # (id(detections), id(config)) -> the entry its robots join (None: no clusters)
    # runs of robots with the same detections array and configuration (a batched fleet: one run)
    # join their entry at once (found in C: no numpy on a lone robot's path)
    end = 0
    for _, run in itertools.groupby(zip(map(id, dets), map(id, configs))):
        row, end = end, end + len(list(run))
        det, cfg = dets[row], configs[row]
        key = (id(det), id(cfg))
        if key in joins:            # robots given one detections array (the batched fleet)
            entry = joins[key]
            if entry is not None:
                entry[2].extend(range(row, end))
            continue
        joins[key] = None
        if not cfg.clusters or len(det) <= 1:
            continue
        store = store_arg
        if store is None:
            store = stores.get(id(cfg))
            if store is None:
                store = stores[id(cfg)] = default_cluster_store(cfg)
        if not inputs[row].solve_clusters:      # input that changes every message: the fallback only
            store = store.fallback_twin()
        fr = frames[row] if frames is not None else None
        if fr is None:
            cache = derived.get(row, 'clusters')
            if cache is None or cache[0] is not det:
                got = shared.get((id(det), id(store)))
                if got is None:
                    got = shared[(id(det), id(store))] = cluster_frames(det, store)
                cache = derived.put(row, 'clusters', (det, got))
            fr = cache[1]
        if fr.n:
            entry = entries.get((id(fr), id(store)))
            if entry is None:
                entry = entries[(id(fr), id(store))] = (fr, store, [])
            entry[2].extend(range(row, end))
            joins[key] = entry
    return list(entries.values())


def _lookups(entries) -> dict:
    """The union's value of each cluster geometry, looked up (and requested) in the order the
    robots meet them: the first (robot, cluster) of a geometry sees the store before its
    request, every later one after it (as robot-by-robot lookups would: an inline store
    solves at the request). (store, key) -> [value before, busy before, value after, busy
    after, (entry, cluster) that met it first]."""
    firsts = sorted((rows[0], gi, e) for e, (fr, _, rows) in enumerate(entries) for gi in range(fr.n))
    known = {}
    for _, gi, e in firsts:
        fr, store, _ = entries[e]
        sk = _known_key(store, fr.keys[gi], e, gi)
        if sk in known:
            continue
        if fr.keys[gi] is None:      # too large to be solved: never requested, the fallback judges it
            known[sk] = [None, False, None, False, (e, gi)]
            continue
        before = store.get(fr.keys[gi])
        if before is None:
            store.request(fr.keys[gi], fr.centres[gi])
            busy = store.solving(fr.keys[gi])
            after = store.get(fr.keys[gi])
            known[sk] = [before, busy, after, store.solving(fr.keys[gi]) if after is None else False, (e, gi)]
        else:
            known[sk] = [before, False, before, False, (e, gi)]
    return known


def _known_key(store, key, e, gi):
    """``_lookups``' key of entry e's cluster gi: its store and geometry (a cluster without a key,
    too large to be solved, is its own)."""
    return (id(store), key) if key is not None else (id(store), None, e, gi)


class _FrameColumns:
    """Every entry's clusters ("frames") in one table: per frame its canonical frame
    (origin, angle, cos, sin), members (size, first member ``mstart`` into ``member`` and
    ``member_xy``), store (index into ``stores``) and the union value in force (``val``, an
    index into ``values``, -1: none) and whether it is being solved (``busy``), after its
    request; ``first_inst``: the instances that met a geometry first, with what they saw
    before the request. Entry e's frames start at ``frame0[e]``, its instances at ``inst0[e]``."""

    def __init__(self, entries):
        known = _lookups(entries)
        self.values, index_of = [], {}     # distinct union values in force, by index

        def value_index(v):
            if v is None:
                return -1
            j = index_of.get(id(v))
            if j is None:
                j = index_of[id(v)] = len(self.values)
                self.values.append(v)
            return j

        self.n_frames = np.array([fr.n for fr, _, _ in entries], dtype=np.intp)
        self.n_rows = np.array([len(rows) for _, _, rows in entries], dtype=np.intp)
        self.frame0 = np.cumsum(self.n_frames) - self.n_frames
        self.inst0 = np.cumsum(self.n_rows * self.n_frames) - self.n_rows * self.n_frames
        val, busy, self.first_inst = [], [], []
        for e, (fr, store, _) in enumerate(entries):
            for gi, key in enumerate(fr.keys):
                b, bb, a, ab, first = known[_known_key(store, key, e, gi)]
                val.append(value_index(a))
                busy.append(ab)
                if first == (e, gi):      # the first robot of this entry is the first to meet the key
                    self.first_inst.append((int(self.inst0[e]) + gi, value_index(b), bb))
        self.val = np.array(val, dtype=np.intp)
        self.busy = np.array(busy, dtype=bool)
        frames = np.concatenate([fr.frames for fr, _, _ in entries])
        self.origin, self.angle, self.cos, self.sin = frames[:, 0:2], frames[:, 2], frames[:, 3], frames[:, 4]
        self.size = frames[:, 5].astype(np.intp)
        self.stores, store_index = [], {}
        for _, store, _ in entries:
            if id(store) not in store_index:
                store_index[id(store)] = len(self.stores)
                self.stores.append(store)
        self.store = np.repeat(np.array([store_index[id(st)] for _, st, _ in entries], dtype=np.intp),
                               self.n_frames)
        member_table = np.concatenate([fr.members for fr, _, _ in entries])
        self.member, self.member_xy = member_table[:, 0].astype(np.intp), member_table[:, 1:3]
        self.mstart = np.cumsum(self.size) - self.size


def _instances(entries, fc: _FrameColumns, states, speed, horizon):
    """One instance per (robot, cluster), entry by entry, robot-major within an entry: (robot
    row, cluster index in its frames, frame, union value index, busy). An instance whose union
    value is in force but whose grid no hold can reach reads V = +inf at every state the rows
    read: it never acts nor names the smallest V, so it is left out (most of a wide fleet's
    instances; requests and solving counts come from the instances not in force)."""
    n_rows, n_frames = fc.n_rows, fc.n_frames
    n_inst = int(np.sum(n_rows * n_frames))
    inst_entry = np.repeat(np.arange(len(entries)), n_rows * n_frames)
    q = np.arange(n_inst) - fc.inst0[inst_entry]
    g_e = n_frames[inst_entry]
    all_rows = np.fromiter(itertools.chain.from_iterable(rows for _, _, rows in entries), dtype=np.intp,
                           count=int(n_rows.sum()))
    inst_row = all_rows[(np.cumsum(n_rows) - n_rows)[inst_entry] + q // g_e]
    inst_gi = q % g_e
    frame = fc.frame0[inst_entry] + inst_gi
    val, busy = fc.val[frame], fc.busy[frame]
    for k, b, bb in fc.first_inst:
        val[k], busy[k] = b, bb
    far = _beyond_grid(fc.values, val, states[inst_row, :2] - fc.origin[frame],
                       2.0 * speed[inst_row] * horizon[inst_row] + 1.0)
    if far.any():
        near = ~far
        return inst_row[near], inst_gi[near], frame[near], val[near], busy[near]
    return inst_row, inst_gi, frame, val, busy


class UnionFrames(NamedTuple):
    """The union values in force at cluster instances: ``values`` (the distinct ``ClusterValue``s),
    per instance ``val`` (its index in ``values``, -1: none in force) and its canonical frame
    (``origin`` (k, 2), ``angle``, ``cos``, ``sin``)."""

    values: list
    val: np.ndarray
    origin: np.ndarray
    angle: np.ndarray
    cos: np.ndarray
    sin: np.ndarray

    def read(self, idx, s):
        """(V (+inf off the grid), each instance's tie tolerance) of instances ``idx`` at their states
        ``s`` (k, len(idx), 3) in the map frame, each read in its cluster's canonical frame
        (``geometry.to_frame``)."""
        v = np.full(s.shape[:2], np.inf)
        tie = np.zeros(len(idx))
        origin, angle, cs, sn = self.origin[idx], self.angle[idx], self.cos[idx], self.sin[idx]
        dx, dy = s[..., 0] - origin[:, 0], s[..., 1] - origin[:, 1]      # geometry.to_frame
        in_frame = np.stack([cs * dx + sn * dy, -sn * dx + cs * dy, s[..., 2] - angle], axis=-1)
        for j, cv in enumerate(self.values):
            sel = np.flatnonzero(self.val[idx] == j)
            if len(sel):
                v[:, sel] = cv.value(in_frame[:, sel].reshape(-1, 3)).reshape(len(s), len(sel))
                tie[sel] = cv.tie
        return v, tie


class UnionTurns(NamedTuple):
    """What the unit avoid turns of cluster rows are read from (``union_turns``): per cluster row its
    instance (``instance``); per instance whether a union value is in force (``in_force``), the
    loiter fallback's turn (``fallback_turn``), its robot row, that robot's state now (``state``,
    (k, 3)), the store's ``turn_hold``, its union value and frame (``frames``); per robot row its
    lookahead, speed and turn bound."""

    instance: np.ndarray
    in_force: np.ndarray
    fallback_turn: np.ndarray
    robot: np.ndarray
    state: np.ndarray
    turn_hold: np.ndarray
    frames: UnionFrames
    lookahead: np.ndarray
    speed: np.ndarray
    omega_max: np.ndarray


def union_turns(u: UnionTurns, rows) -> np.ndarray:
    """The unit avoid turn of cluster rows ``rows`` (0: the first cluster row): with a union value in
    force, the bang (+-w_max) whose hold from the state now ends at the larger V (ties left, within
    the value's tie tolerance), held at least the store's ``turn_hold`` (a shorter hold's ends are
    closer than the grid resolves); with the fallback, its loiter circle's turn."""
    i = u.instance[np.asarray(rows, dtype=np.intp)]
    out = u.fallback_turn[i]
    ok = u.in_force[i]
    j = i[ok]
    if len(j):
        robot = u.robot[j]
        hold = py_max(u.lookahead[robot], u.turn_hold[j])
        ends = bang_ends(u.state[j], u.speed[robot], u.omega_max[robot], hold).reshape(2, len(j), 3)
        (left, right), tie = u.frames.read(j, ends)
        out[ok] = better_bang(left, right, tie)
    return out


def _beyond_grid(values, val, offset, reach) -> np.ndarray:
    """Per instance: its union value is in force (``val`` indexes ``values``) and its robot,
    ``offset`` (k, 2) from the cluster frame's origin, is farther than ``reach`` beyond every
    corner of that value's grid (frames only rotate about the origin, so a distance bound needs
    no rotation): every state within ``reach`` of the robot is off the grid."""
    if not values:
        return np.zeros(len(val), bool)
    corner = np.array([max(math.hypot(x, y) for x in (g.lo[0], g.hi[0]) for y in (g.lo[1], g.hi[1]))
                       for g in (cv.vf.grid for cv in values)] + [math.inf])
    return np.hypot(offset[:, 0], offset[:, 1]) > corner[val] + reach    # val -1 -> inf: never far


def _read_fallback(sel, value, turn, state, ahead, member_xy, member_inst, inst_store, stores) -> None:
    """The loiter fallback (``_orbit_values``) of the instances ``sel``, now and after the hold, into
    ``value`` (2, k) and ``turn`` (k,): their robots' states ``state`` and ``ahead``, their clusters'
    members, each with its store's radius and turning radius."""
    for k, store in enumerate(stores):
        mine = sel & (inst_store == k)
        if np.any(mine):
            st = store.settings
            v, u = _orbit_values(np.stack([state[mine], ahead[mine]]), member_xy, member_inst, mine,
                                 st.radius + st.margin, st.turning_radius)
            value[:, mine] = v
            turn[mine] = u[0]


def _fallback_bound(nearest, inst_store, stores, travel):
    """Per instance, lower bounds of its loiter fallback's clearance now and after the planner's hold
    ((2, k)): each loiter circle's centre is a turning radius r from the robot, so a disc (c, R)
    whose centre is d from the robot clears it by at least d - 2 r - R, and the hold moves the robot
    at most ``travel`` (speed H); ``nearest``: the distance to the instance's nearest member. Less a
    nanometre for the round-off of both. A fallback row whose bound now is above the clear margin
    and after the hold above 0 cannot act; above its robot's smallest V - level it cannot be the
    row a pass names or a fail safe avoids: no row (``cluster_rows``)."""
    r = np.array([st.settings.turning_radius for st in stores])[inst_store]
    radius = np.array([st.settings.radius + st.settings.margin for st in stores])[inst_store]
    now = nearest - 2.0 * r - radius - 1e-9
    return np.stack([now, now - travel])


def _orbit_values(states, member_xy, member_inst, sel, radius, turning_radius):
    """``geometry.orbit_value`` for many (state, cluster) pairs at once.

    ``states`` (2, k, 3): the state now and after the planner's hold of each selected
    cluster instance; its discs are the rows of ``member_xy`` whose ``member_inst`` is
    selected by ``sel``. Returns (clearance (2, k), turn (2, k)).
    """
    inst = np.flatnonzero(sel)
    col = np.full(len(sel), -1, np.intp)
    col[inst] = np.arange(len(inst))
    take = sel[member_inst]
    c = member_xy[take]
    seg = col[member_inst[take]]                     # members are grouped by instance, in order
    starts = np.flatnonzero(np.concatenate(([True], seg[1:] != seg[:-1])))
    out = []
    for side in (1.0, -1.0):
        mx = states[..., 0] - side * turning_radius * np.sin(states[..., 2])
        my = states[..., 1] + side * turning_radius * np.cos(states[..., 2])
        dist = np.hypot(mx[:, seg] - c[:, 0], my[:, seg] - c[:, 1])
        out.append(np.minimum.reduceat(np.abs(dist - turning_radius) - radius, starts, axis=1))
    left, right = out
    return np.maximum(left, right), np.where(left >= right, 1.0, -1.0)
