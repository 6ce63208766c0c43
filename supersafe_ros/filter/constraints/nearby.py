"""The detections that can matter to a robot, found without reading the others.

A detection constrains a robot only near it: a pair's V is +inf off the value function's grid
(the standard grid is +-8 m around its obstacle) and the holds the lookahead judges move the
robot at most 2 speed H; a cluster's union value is +inf beyond its grid (``reach`` beyond
its members), and its loiter fallback can act only within two turning radii, the inflated
radius and the clear margin of a member. ``judged_radius`` is the largest of these
distances: farther from the robot's state, a detection changes no constraint that can act.

Up to NEAR_QUERY_MIN detections a robot judges every one (as it always did). Beyond that
(``narrow``), a k-d tree built once per detections array (``DetectionIndex``; robots given
one array share it) finds those within each robot's radius, and their clusters are completed,
so that each is judged whole: with the same members, key and value as among all detections.
The robot then decides exactly as on those detections alone. That differs from judging all
of them only where no constraint can act: what a pass names (a far cluster on its fallback
has a finite clearance, which a pass would name as its smallest value) and the loiter turn of
a robot failing safe with such a far cluster as its nearest constraint (either turn keeps it
clear there).

A cluster of more than ``SOLVE_MEMBERS_MAX`` obstacles is never solved (its grid and
union grow with it), so its search stops there: such obstacles within a robot's radius are
judged one by one and together by the loiter fallback, as one group.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..clusters.geometry import canonical
from ..clusters.store import SOLVE_MEMBERS_MAX, default_cluster_store, settings_of
from .cluster_rows import ClusterFrames

NEAR_QUERY_MIN = 64      # up to this many detections a robot judges them all
UNSEEN, OVERSIZE = -1, -2


def judged_radius(grid, speed, horizon, clear_margin, settings):
    """How far from a robot's state a detection can still constrain it (see the module):
    ``grid`` the safe set's, per robot its ``speed``, lookahead ``horizon`` and clear margin
    (scalars or arrays), ``settings`` its clusters' ``ClusterSettings``."""
    hold = 2.0 * np.asarray(speed) * np.asarray(horizon) + 1.0    # as pairs.pair_reads: two holds, +1 m
    box = np.hypot(max(-grid.lo[0], grid.hi[0]) + hold, max(-grid.lo[1], grid.hi[1]) + hold)
    union = settings.reach + settings.cell + settings.key_resolution + hold     # a cell of rounding up
    loiter = 2.0 * settings.turning_radius + settings.radius + settings.margin + np.asarray(clear_margin) + hold
    return np.maximum(box, np.maximum(union, loiter))


class DetectionIndex:
    """One detections array's k-d tree, and the clusters found in it so far (by ``pick``;
    ``link``: the clusters' link distance, None: no clusters)."""

    def __init__(self, det, link):
        self.det, self.link = det, link
        self.tree = cKDTree(det)
        self.label = np.full(len(det), UNSEEN, dtype=np.intp)     # a cluster, OVERSIZE or UNSEEN
        self.members = []            # cluster label -> its members, ascending
        self._canon = {}             # (label, resolution) -> geometry.canonical of its members

    def within(self, xy, radius) -> list:
        """Per point of ``xy`` (k, 2): the detections within its ``radius``, ascending."""
        return [np.asarray(got, dtype=np.intp) for got in self.tree.query_ball_point(xy, radius, return_sorted=True)]

    def pick(self, near, resolution):
        """(the detections a robot judges: ``near`` and every member of their clusters,
        ascending; its clusters of more than one member, as positions in it, in the order of
        their first members; each one's canonical frame, for the members of clusters too large
        to solve (one group, of those in ``near``) the frame of ``cluster_rows.cluster_frame``)."""
        if self.link is None:
            return near, [], []
        for i in near[self.label[near] == UNSEEN].tolist():
            if self.label[i] == UNSEEN:
                self._search(i)
        label = self.label[near]
        small = np.unique(label[label >= 0]).tolist()
        picked = np.unique(np.concatenate([near] + [self.members[k] for k in small])) if small else near
        groups, canon = [], []
        for k in small:
            if len(self.members[k]) > 1:
                groups.append(np.searchsorted(picked, self.members[k]))
                canon.append(self._canonical(k, resolution))
        over = near[label == OVERSIZE]
        if len(over) > 1:          # never solved, so no canonical frame (cluster_rows.cluster_frame's)
            groups.append(np.searchsorted(picked, over))
            canon.append((None, self.det[over].mean(axis=0), 0.0, None))
        order = sorted(range(len(groups)), key=lambda g: groups[g][0])
        return picked, [groups[g] for g in order], [canon[g] for g in order]

    def _search(self, start):
        """Label the cluster of detection ``start`` (centres within ``link``, transitively, by
        np.hypot as ``geometry.components`` judges them), or OVERSIZE once it has more than
        SOLVE_MEMBERS_MAX members (what was found so far: the rest are found the same way)."""
        c, link = self.det, self.link
        found = np.array([start], dtype=np.intp)
        frontier = found
        while len(frontier):
            lists = self.tree.query_ball_point(c[frontier], link * (1.0 + 1e-9) + 1e-12)
            counts = np.fromiter(map(len, lists), dtype=np.intp, count=len(lists))
            j = np.concatenate([np.asarray(x, dtype=np.intp) for x in lists])
            i = np.repeat(frontier, counts)
            close = j[np.hypot(c[i, 0] - c[j, 0], c[i, 1] - c[j, 1]) <= link]
            frontier = np.setdiff1d(close, found)
            found = np.union1d(found, frontier)
            if len(found) > SOLVE_MEMBERS_MAX or np.any(self.label[frontier] == OVERSIZE):
                self.label[found] = OVERSIZE
                return
        self.label[found] = len(self.members)
        self.members.append(found)

    def _canonical(self, k, resolution):
        got = self._canon.get((k, resolution))
        if got is None:
            got = self._canon[(k, resolution)] = canonical(self.det[self.members[k]], resolution)
        return got


class Narrowed:
    """What ``narrow`` gives ``decide``: per robot the detections it judges (``dets``) and, for
    those narrowed, their ``ClusterFrames`` (``frames``, None: its array's own); per pair row
    its position in its robot's detections (``position``) and its index in the message
    (``names``: the state's obstacle_index); per robot its detections' count (``counts``)."""

    __slots__ = ('dets', 'frames', 'position', 'names', 'counts')

    def rename(self, table, start, clusters_found) -> None:
        """The table's obstacles as indices in each robot's message."""
        names = self.names
        found = clusters_found
        table.obstacle = (np.concatenate([names, names[start[found['robot']] + found['obstacle']]])
                          if len(found['robot']) else names.copy())


def narrow(configs, dets, inputs, states, horizon, speed, margin, safe_set, store_arg, derived):
    """The detections each robot judges (see the module), or None if every robot judges all of
    its own (none has more than NEAR_QUERY_MIN). Per robot row: ``configs``, ``dets``, ``inputs``
    (their input record: ``kept``, their rows in the message, None: row i is row i;
    ``solve_clusters``), ``states`` (propagated), ``horizon``, ``speed``, ``margin``
    (``gather.RobotColumns``'); ``store_arg``: as
    ``decide.step_many``'s; ``derived``: the decision's ``filter.derived.Derived``, through which
    each robot's index and last pick are read and kept."""
    counts = np.fromiter(map(len, dets), dtype=np.intp, count=len(dets))
    big = np.flatnonzero(counts > NEAR_QUERY_MIN)
    if len(big) == 0:
        return None
    out = Narrowed()
    out.dets, out.frames, out.counts = list(dets), [None] * len(dets), counts
    position = [None if n > NEAR_QUERY_MIN else np.arange(n) for n in counts.tolist()]      # (big: below)
    kept = [inp.kept for inp in inputs]
    names = [p if p is None or k is None else k for p, k in zip(position, kept)]    # (a robot's discs split into
    #                                                                                  rings: filter.constraints.discs)
    shared, radii, found = {}, {}, {}
    for i in big.tolist():       # each robot's index, store and radius (robots of a fleet share them)
        cfg, det = configs[i], dets[i]
        store = (store_arg if store_arg is not None else default_cluster_store(cfg)) if cfg.clusters else None
        if store is not None and not inputs[i].solve_clusters:     # (as cluster_rows._entries)
            store = store.fallback_twin()
        st = store.settings if store is not None else settings_of(cfg)
        index = _index(i, det, st.link_distance if store is not None else None, shared, derived)
        key = (st, float(speed[i]), float(horizon[i]), float(margin[i]))
        radius = radii.get(key)
        if radius is None:
            radius = radii[key] = float(judged_radius(safe_set.vf.grid, *key[1:], st))
        found.setdefault(id(index), (index, []))[1].append((i, store, st, radius))
    for index, robots in found.values():      # one query of the tree for its robots
        rows = [i for i, _, _, _ in robots]
        near_all = index.within(states[rows, :2], np.array([r for _, _, _, r in robots]))
        for (i, store, st, _), near in zip(robots, near_all):
            det = dets[i]
            picked, groups, canon = index.pick(near, st.key_resolution)
            memo = derived.get(i, 'near_pick')      # the last decision's, kept while the same are picked
            if (memo is None or memo[0] is not det or memo[1] is not store or len(memo[2]) != len(picked)
                    or not np.array_equal(memo[2], picked)):
                sub = det[picked]
                frames = ClusterFrames(sub, store, groups, canon) if store is not None else None
                memo = derived.put(i, 'near_pick', (det, store, picked, sub, frames))
            out.dets[i], out.frames[i] = memo[3], memo[4]
            position[i] = picked
            names[i] = kept[i][picked] if kept[i] is not None else picked
    out.position, out.names = np.concatenate(position), np.concatenate(names)
    return out


def _index(row, det, link, shared, derived) -> DetectionIndex:
    """Robot row ``row``'s index of ``det``: kept while its detections are that array (``derived``),
    shared by the robots given the same one (``shared``, for one decision)."""
    cache = derived.get(row, 'near_index')
    if cache is not None and cache.det is det and cache.link == link:
        return cache
    got = shared.get((id(det), link))
    if got is None:
        got = shared[(id(det), link)] = DetectionIndex(det, link)
    return derived.put(row, 'near_index', got)


def within_limit(centres, origins, limit):
    """(the indices of the ``limit`` detections nearest to any of ``origins`` (k, 2), ascending;
    the distance from which the others were dropped): what a detections message may hold
    (``max_detections``). With no origin (no pose yet) the first ``limit`` are kept (distance
    nan)."""
    n = len(centres)
    if n <= limit:
        return np.arange(n), math.inf
    if origins is None or len(origins) == 0:
        return np.arange(limit), math.nan
    origins = np.asarray(origins, dtype=float).reshape(-1, 2)
    if len(origins) == 1:
        d = np.hypot(centres[:, 0] - origins[0, 0], centres[:, 1] - origins[0, 1])
    else:
        d = cKDTree(origins).query(centres, k=1)[0]
    part = np.argpartition(d, limit)
    kept = np.sort(part[:limit])
    return kept, float(d[part[limit:]].min())


def message_reach(cfg, grid, horizon, pose_age) -> float:
    """How far from a robot's pose (``pose_age`` old) a detection can constrain it while a
    detections message arriving now is judged: its judged radius, plus the way it travels
    meanwhile (the pose's age, then until the detections are stale or their hold is over)."""
    radius = float(judged_radius(grid, cfg.speed, horizon, cfg.clear_margin, settings_of(cfg)))
    return radius + cfg.speed * (pose_age + max(cfg.detections_timeout, cfg.hold_timeout))


def drop_note(total, limit, dropped_from, reach, robots=1):
    """(why ``total - limit`` detections of a message were dropped, whether that is safe):
    the farthest, from ``dropped_from`` m of the nearest of ``robots`` robots (nan: no pose
    to measure from, the first kept), against ``reach`` (``message_reach``; None: unknown)."""
    head = f'{total - limit} of {total} detections dropped (max_detections {limit})'
    whom = 'the robot' if robots == 1 else 'every robot'
    if math.isnan(dropped_from):
        return f'{head}: no pose yet to tell near from far, the first {limit} kept', False
    if reach is None:
        return f'{head}: the farthest from {whom}, from {dropped_from:.1f} m (its reach is not known)', False
    if dropped_from > reach:
        return (f'{head}: the farthest from {whom}, {dropped_from:.1f} m and more away, beyond the '
                f'{reach:.1f} m within which a detection can constrain it while these are judged (the value '
                f'function\'s grid, the lookahead\'s holds, clusters, travel until stale): safe to drop'), True
    return (f'{head}: the farthest from {whom}, from {dropped_from:.1f} m, WITHIN the {reach:.1f} m where a '
            f'detection can constrain it: those obstacles are not judged; raise max_detections'), False
