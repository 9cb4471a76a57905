"""Batch mode with the replay controller: every ego variant's whole run at once, then contacts and metrics.

With the replay controller the ego follows its reference blind to the agents, and in batch mode the
agents come from the world's recorded :class:`~deepcrashtest.sim.agents.AgentTimeline` (independent
of the ego). So the ego of every variant can be stepped through the whole time grid first (one
vectorised step per grid step, ~70 array operations for all variants together), and the per-step
tests of :mod:`deepcrashtest.sim.loop` become array operations over (steps, variants, agents):

* contacts: only where the bounding circles overlap can the boxes touch; the separating-axis gap
  there, the loop's rule for ignored overlaps (a pair that overlaps when it first co-exists is
  ignored until it has separated once) as runs of consecutive overlapping steps, and the first
  contact of each variant (its run ends there);
* minimum distance: the separating-axis gap is at least ``|d| / sqrt(2) - max half extent of the
  ego - circumradius of the agent`` (``d``: centre offset), and the minimum is at most the smallest
  centre distance, so exact distances are computed only where that bound can reach the minimum;
* time to collision: at the loop's evaluation steps; the swept test only where the distance over
  the closing speed can beat the variant's minimum.

Every number comes from the same functions on the same inputs as in the loop, element by element:
the outcomes equal :func:`deepcrashtest.sim.loop.run_loop`'s (checked on KITTI scenes in the tests).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepcrashtest.sim.agents import agent_timeline
from deepcrashtest.sim.boxes import (
    apart_distance,
    axis_gaps,
    contact_fraction,
    distance_lower_bound,
    gap_of_axes,
    sat_gap,
    time_to_collision,
)
from deepcrashtest.sim.loop import NEAR_M, TTC_EVERY, LoopOutput, PreContact, batch_delta_v
from deepcrashtest.sim.reference import PathSet
from deepcrashtest.sim.rollout import PackedPaths, rollout
from deepcrashtest.sim.vehicle import VehicleLimits, velocity_xy, yaw_rate
from deepcrashtest.sim.world import World

#: Variants whose (steps x agents) geometry is handled together (bounds the memory: ~10 arrays of
#: steps x ROWS x agents doubles).
ROWS = 256
_EPS = 1e-6  # metres / seconds of slack on the pruning bounds (they are exact up to rounding)
#: Slack (m) on the corner bound against a row's minimum: rounding makes a computed distance at most ~1e-15 m
#: below the bound's value, and an entry within this of the minimum is computed anyway.
_SLACK_M = 1e-9
#: Pairs (index, agent) farther than this from every row's ego (m) are left out of the distance
#: geometry (TTC evaluation indices excepted); the bound this gives (~5.5 m for cars) must exceed each
#: row's distance bound, else the rows are evaluated with every pair (see ``_Rows._prune_far_pairs``).
FAR_M = 15.0


def replay_batch_available(world: World, limits: VehicleLimits | None = None) -> bool:
    """True when the world's agent run is kept in memory (the fast path needs it whole)."""
    return agent_timeline(world, limits or VehicleLimits()).keep_all


def run_replay_batch(
    world: World,
    ego_paths: PathSet | PackedPaths,
    ego_q: np.ndarray,
    ego_offset: np.ndarray,
    ego_init: np.ndarray,
    limits: VehicleLimits | None = None,
    release: bool = False,
) -> LoopOutput:
    """The outcomes of ``run_loop(..., ReplayController(), physics_mode=False)`` for ``B`` ego variants.

    ``release``: ``ego_paths`` (packed) serves no other batch; their memory is released once the egos have run."""
    lim = limits or VehicleLimits()
    seg = agent_timeline(world, lim).whole()
    if seg is None:
        raise ValueError("the agents' run is not kept in memory (replay_batch_available is False)")
    B = len(ego_init)
    out = LoopOutput.empty(B)
    ego, steer, cos_sin = _rollout(world, ego_paths, ego_q, ego_offset, ego_init, lim, release)
    # agents at each evaluation index i: i = 0 the start, i = k + 1 the candidate states of step k
    ag = np.concatenate([seg.state[:1], seg.new])
    pres = np.concatenate([seg.pres[:1], seg.pres_next]).astype(bool)
    ag_vel = np.concatenate([seg.vel[:1], seg.new_vel])
    pre_contact: dict[int, PreContact] = {}
    # pairs far from every row left out, unless that could change a minimum (then the rows again with every pair);
    # once that happened the next blocks take every pair at once (the same outcomes: leaving pairs out is exact)
    attempts: tuple[bool, ...] = (True, False)
    for lo in range(0, B, ROWS):
        rows = slice(lo, min(lo + ROWS, B))
        for prune in attempts:
            if _Rows(
                world, ego[:, rows], steer[:, rows], ag, pres, ag_vel, prune, (cos_sin[0][:, rows], cos_sin[1][:, rows])
            ).evaluate(seg, out, rows, pre_contact):
                break
            attempts = (False,)
    batch_delta_v(world, pre_contact, out)
    return out


def _rollout(
    world: World,
    paths: PathSet | PackedPaths,
    q: np.ndarray,
    offset: np.ndarray,
    init: np.ndarray,
    lim: VehicleLimits,
    release: bool = False,
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Ego states (T, B, 4: x, y, yaw, speed), steering angles (T, B) and the cosine and sine of the yaw (T, B)
    over the whole grid."""
    run = rollout(paths, q, offset, init, float(world.wheelbase[0]), world.dt, len(world.times) - 1, lim)
    if release and isinstance(paths, PackedPaths):
        paths.release()  # before the states are stacked: their copy takes the tables' memory
    return np.stack([run.x, run.y, run.yaw, run.v], axis=-1), run.steer, (run.cos_yaw, run.sin_yaw)


def _new_boxes(boxes: np.ndarray) -> np.ndarray:
    """(K,) True where a row of ``boxes`` (K, C) differs from the row before it in any bit (the first row: True).

    A stopped ego beside a parked car gives the same pair of boxes at step after step (dad_000512: ~13,000 entries
    of a row block, ~200 distinct); their distance is computed once (the same inputs give the same bits)."""
    bits = np.ascontiguousarray(boxes).view(np.uint64)
    new = np.ones(len(bits), bool)
    np.any(bits[1:] != bits[:-1], axis=1, out=new[1:])
    return new


def apart_distances(boxes: np.ndarray, half: np.ndarray) -> np.ndarray:
    """:func:`~deepcrashtest.sim.boxes.signed_distance` of ego boxes of half extents ``half`` (2,) and agent boxes,
    ``boxes`` (K, 8: the ego's x, y, yaw, the agent's x, y, yaw, half length, half width), all apart (their
    separating-axis gaps positive): computed once for each run of identical rows (:func:`_new_boxes`)."""
    new = _new_boxes(boxes)
    b = boxes[new]
    d = apart_distance(b[:, :3], b[:, 3:6], half[None, :], b[:, 6:], np.ones(len(b), bool))
    return d[np.cumsum(new) - 1]


class _Rows:
    """The contacts and metrics of ``R`` variants over the present (index, agent) pairs ``N`` (arrays (N, R))."""

    def __init__(
        self,
        world: World,
        ego: np.ndarray,
        steer: np.ndarray,
        ag: np.ndarray,
        pres: np.ndarray,
        ag_vel: np.ndarray,
        prune: bool = False,
        cos_sin: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        self.world, self.ego, self.steer, self.ag, self.pres, self.ag_vel = world, ego, steer, ag, pres, ag_vel
        self.eh, self.ah = world.half[0], world.half[1:]
        self.pi, self.pj = np.nonzero(pres)  # the present pairs: evaluation index, agent
        self.far_bound = np.inf  # every pair left out has ``lower`` above this (m)
        if prune and len(self.pi):
            self._prune_far_pairs()
        a = ag[self.pi, self.pj]  # (N, 4)
        # centre offsets (N, R), kept for the time to collision; the rest in place (arrays of N x R, a few MB each)
        self.dx = dx = np.subtract(a[:, None, 0], ego[:, :, 0][self.pi])
        self.dy = dy = np.subtract(a[:, None, 1], ego[:, :, 1][self.pi])
        t1, t2 = dx * dx, dy * dy
        self.dist = np.sqrt(np.add(t1, t2, out=t1), out=t1)  # centre distances (N, R)
        self.r_a = np.hypot(self.ah[self.pj, 0], self.ah[self.pj, 1])[:, None]  # (N, 1) agents' circumradii
        if cos_sin is None:
            cos_sin = np.cos(ego[:, :, 2]), np.sin(ego[:, :, 2])
        c, s = cos_sin[0][self.pi], cos_sin[1][self.pi]  # per (index, row) (the roll-out's), then gathered
        along = np.multiply(dx, c)  # |dx * c + dy * s| - half length
        along += np.multiply(dy, s, out=t2)
        np.abs(along, out=along)
        along -= self.eh[0]
        across = np.multiply(dy, c, out=c)  # |dy * c - dx * s| - half width
        across -= np.multiply(dx, s, out=s)
        np.abs(across, out=across)
        across -= self.eh[1]
        # the separating-axis gap is the largest of four, two of them on the ego's axes, each at least this
        self.lower = np.maximum(along, across, out=along)
        self.lower -= self.r_a
        self.lower -= _EPS

    def _prune_far_pairs(self) -> None:
        """Leave out pairs (index, agent) whose agent is over ``FAR_M`` from every row's ego centre (the rows'
        bounding box at that index), except at the TTC evaluation indices (a far pair may still close fast).

        They cannot touch (``FAR_M`` exceeds any two circumradii), and their separating-axis lower bound
        exceeds ``far_bound``: :meth:`evaluate` checks that every row's distance bound is below it, else the
        rows are evaluated again with every pair.
        """
        x, y = self.ego[:, :, 0], self.ego[:, :, 1]
        a = self.ag[self.pi, self.pj]
        lo_x, hi_x, lo_y, hi_y = (
            x.min(axis=1)[self.pi],
            x.max(axis=1)[self.pi],
            y.min(axis=1)[self.pi],
            y.max(axis=1)[self.pi],
        )
        gx = np.maximum(np.maximum(lo_x - a[:, 0], a[:, 0] - hi_x), 0.0)
        gy = np.maximum(np.maximum(lo_y - a[:, 1], a[:, 1] - hi_y), 0.0)
        r_max = float(np.hypot(self.ah[:, 0], self.ah[:, 1]).max())
        far_m = max(FAR_M, 2.0 * (float(np.hypot(*self.eh)) + r_max))
        keep = (self.pi % TTC_EVERY == 0) | (np.hypot(gx, gy) <= far_m)
        self.pi, self.pj = self.pi[keep], self.pj[keep]
        # lower = max(along, across) - r_a - eps >= |centre offset| / sqrt(2) - max half extent - r_a - eps
        self.far_bound = far_m / np.sqrt(2.0) - float(self.eh.max()) - r_max - 1e-3

    def _boxes(self, n: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, ...]:
        """The ego's and the agents' boxes of the entries (pair n, row r), as :func:`sat_gap`'s arguments."""
        e, a, eh, ah = self.ego[self.pi[n], r], self.ag[self.pi[n], self.pj[n]], self.eh, self.ah[self.pj[n]]
        return e[:, 0], e[:, 1], e[:, 2], eh[0], eh[1], a[:, 0], a[:, 1], a[:, 2], ah[:, 0], ah[:, 1]

    def gap(self, n: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Separating-axis gaps of the entries (pair n, row r), as the loop computes them."""
        return sat_gap(*self._boxes(n, r))

    def lower_bound(self, n: np.ndarray, r: np.ndarray) -> np.ndarray:
        """:func:`~deepcrashtest.sim.boxes.distance_lower_bound` of the entries (pair n, row r), metres."""
        return distance_lower_bound(*axis_gaps(*self._boxes(n, r)))

    def evaluate(self, seg: Any, out: LoopOutput, rows: slice, pre_contact: dict[int, PreContact]) -> bool:
        """Write the rows' outcomes; False when pairs left out could hold a row's minimum (evaluate again
        with every pair)."""
        T, R = self.ego.shape[:2]
        # ---- contacts: boxes can touch only where their circumcircles do
        cn, cr = np.nonzero(self.dist <= np.hypot(*self.eh) + self.r_a + _EPS)
        cg = self.gap(cn, cr)
        last = np.full(R, T - 1)  # last evaluation index of each row (its first contact, or the end)
        hit_i, hit_r, hit_j = self._first_contacts(cn, cr, cg)
        last[hit_r] = hit_i
        if len(hit_r):
            self._record_contacts(seg, out, rows, hit_i, hit_r, hit_j, pre_contact)
        valid = self.pi[:, None] <= last[None, :]  # (N, R) the row still drives at the pair's index
        gap_known = np.full(self.dist.shape, np.nan)
        gap_known[cn, cr] = cg
        if not self._min_distance(out, rows, valid, gap_known):
            return False
        self._min_ttc(out, rows, valid, gap_known)
        return True

    def _first_contacts(
        self, cn: np.ndarray, cr: np.ndarray, cg: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Index, row and agent of each row's first contact (rows without one are left out).

        A run of consecutive overlapping indices of one pair is ignored when it starts at index 0 or
        where the agent appears (the loop's rule); the first index of any other run is a contact.
        """
        o = cg <= 0
        i, j, r, g = self.pi[cn[o]], self.pj[cn[o]], cr[o], cg[o]
        if not len(i):
            return i, r, j
        order = np.lexsort((i, j, r))
        i, r, j, g = i[order], r[order], j[order], g[order]
        start = np.ones(len(i), bool)
        start[1:] = (r[1:] != r[:-1]) | (j[1:] != j[:-1]) | (i[1:] != i[:-1] + 1)
        run = np.cumsum(start) - 1
        si, sj = i[start], j[start]
        appears = (si > 0) & ~self.pres[np.maximum(si - 1, 0), sj]
        hit = ~((si == 0) | appears)[run]
        i, r, j, g = i[hit], r[hit], j[hit], g[hit]
        if not len(i):
            return i, r, j
        # per row: the earliest index, then the smallest gap, then the lowest agent (np.argmin's tie rule)
        order = np.lexsort((j, g, i, r))
        first = order[np.r_[True, r[order][1:] != r[order][:-1]]]
        return i[first], r[first], j[first]

    def _record_contacts(
        self,
        seg: Any,
        out: LoopOutput,
        rows: slice,
        hit_i: np.ndarray,
        hit_r: np.ndarray,
        hit_j: np.ndarray,
        pre_contact: dict[int, PreContact],
    ) -> None:
        """Time (bisection inside the step), agent, relative speed and pre-contact states of first contacts."""
        k = hit_i - 1  # the step in which the contact happens
        world, eh, ah = self.world, self.eh, self.ah
        e0, e1 = self.ego[k, hit_r], self.ego[hit_i, hit_r]
        a0, a1 = seg.state[k, hit_j], seg.new[k, hit_j]
        frac = contact_fraction(e0[:, :3], e1[:, :3], a0[:, :3], a1[:, :3], np.tile(eh, (len(k), 1)), ah[hit_j])
        st = self.steer[k, hit_r]
        ev = velocity_xy(e0[:, 2], e0[:, 3], st)
        av, aw = seg.hit_vel[k, hit_j], seg.hit_omega[k, hit_j]
        o = rows.start + hit_r
        out.collided[o] = True
        out.collision_time[o] = world.times[k] + frac * world.dt
        out.collision_agent[o] = hit_j + 1
        out.relative_speed[o] = np.hypot(*(ev - av).T)
        wb = world.wheelbase[:1]
        for n in range(len(k)):
            ew = float(yaw_rate(e0[n : n + 1, 3], st[n : n + 1], wb)[0])
            pre_contact[int(o[n])] = (e0[n].copy(), ev[n], ew, int(hit_j[n]), a0[n].copy(), av[n].copy(), float(aw[n]))

    def _gap(self, n: np.ndarray, r: np.ndarray, gap_known: np.ndarray) -> np.ndarray:
        """Separating-axis gaps of entries (n, r), computed where not known yet."""
        g = gap_known[n, r]
        unknown = np.isnan(g)
        g[unknown] = self.gap(n[unknown], r[unknown])
        return g

    def _distance(self, n: np.ndarray, r: np.ndarray, g: np.ndarray) -> np.ndarray:
        """The loop's distance of entries (n, r) with gaps ``g``: the exact box distance where the gap is in
        (0, NEAR_M), else the gap."""
        g = g.copy()
        refine = (g > 0) & (g < NEAR_M)
        e, a = self.ego[self.pi[n[refine]], r[refine]], self.ag[self.pi[n[refine]], self.pj[n[refine]]]
        # their gaps are positive (``g``, sat_gap of these very boxes): signed_distance's value without its gaps
        g[refine] = apart_distances(np.column_stack([e[:, :3], a[:, :3], self.ah[self.pj[n[refine]]]]), self.eh)
        return g

    def _min_distance(self, out: LoopOutput, rows: slice, valid: np.ndarray, gap_known: np.ndarray) -> bool:
        """Minimum over driven indices of the loop's distance.

        Bounds first: the exact distance at each row's closest centres (no box distance exceeds the
        centre distance), then at its smallest gap among the entries whose lower bound can reach that;
        exact distances only where the gap (a lower bound of the distance) is below the bound.
        """
        R = valid.shape[1]
        dist = np.where(valid, self.dist, np.inf)
        upper = np.full(R, np.inf)
        has = np.isfinite(dist).any(axis=0)
        if np.isfinite(self.far_bound) and not has.all():
            return False
        if not has.any():
            out.min_distance[rows] = upper
            return True
        r0 = np.nonzero(has)[0]
        n0 = np.argmin(dist if len(r0) == R else dist[:, r0], axis=0)
        upper[r0] = self._distance(n0, r0, self._gap(n0, r0, gap_known))
        if (upper >= self.far_bound).any():
            return False
        n, r = np.nonzero(valid & (self.lower <= upper[None, :]))
        g = gap_known[n, r]
        unknown = np.flatnonzero(np.isnan(g))
        axes = axis_gaps(*self._boxes(n[unknown], r[unknown]))  # kept for the corner bounds below
        g[unknown] = gap_of_axes(*axes)
        # entries whose gap is above their row's bound are never computed (the bound only falls): left out (~3/4)
        keep = g <= upper[r]
        slot = np.full(len(n), -1)  # an entry's position in ``axes`` (-1: its gap was known)
        slot[unknown] = np.arange(len(unknown))
        n, r, g, slot = n[keep], r[keep], g[keep], slot[keep]
        # a tighter lower bound of the distance than the gap (corner to corner) where the distance is exact (apart,
        # below NEAR_M; elsewhere it is the gap itself): an entry whose bound exceeds its row's cannot hold the minimum
        bound = g.copy()
        exact = (g > 0) & (g < NEAR_M)
        have = exact & (slot >= 0)
        bound[have] = distance_lower_bound(*(a[slot[have]] for a in axes))
        rest = exact & (slot < 0)
        bound[rest] = self.lower_bound(n[rest], r[rest])
        order = np.lexsort((bound, r))  # by row, smallest bound first
        n, r, g, bound = n[order], r[order], g[order], bound[order]
        rank = np.arange(len(r)) - np.searchsorted(r, r)  # position within the row
        for lo, hi in ((0, 1), (1, 8), (8, 64), (64, len(r) + 1)):  # the bound tightens round by round
            sel = (rank >= lo) & (rank < hi) & (bound <= upper[r] + _SLACK_M)
            np.minimum.at(upper, r[sel], self._distance(n[sel], r[sel], g[sel]))
        out.min_distance[rows] = upper
        return True

    def _never_close(self, sel: np.ndarray, wx: np.ndarray, wy: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """(n, R) True where the boxes of pairs ``sel`` can never touch moving at their relative velocity (``wx``,
        ``wy``) (m/s): their circumcircles stay apart for all t >= 0, so the swept test gives infinity."""
        dx, dy = self.dx[sel], self.dy[sel]
        reach = np.hypot(*self.eh) + self.r_a[sel] + _EPS  # (n, 1)
        t1, t2 = dx * wx, dy * wy
        closing = np.add(t1, t2, out=t1) < 0.0  # dx * wx + dy * wy
        miss = np.subtract(np.multiply(dx, wy, out=dx), np.multiply(dy, wx, out=dy), out=t1)
        np.abs(miss, out=miss)  # closest approach of the centres times the speed
        return np.where(closing, miss > reach * speed, self.dist[sel] > reach)

    def _min_ttc(self, out: LoopOutput, rows: slice, valid: np.ndarray, gap_known: np.ndarray) -> None:
        """Minimum time to collision at the loop's evaluation indices (0, TTC_EVERY, ...), apart pairs only."""
        R = valid.shape[1]
        sel = np.nonzero(self.pi % TTC_EVERY == 0)[0]  # pairs at evaluation indices
        gk = gap_known[sel]
        ok = valid[sel] & (np.isnan(gk) | (gk > 0))  # unknown gaps are positive (the circles do not touch)
        pi, pj = self.pi[sel], self.pj[sel]
        at, inv = np.unique(pi, return_inverse=True)  # each evaluation index once (several agents share it)
        ev = velocity_xy(self.ego[at, :, 2], self.ego[at, :, 3], self.steer[at])  # (indices, R, 2)
        evx, evy = ev[..., 0][inv], ev[..., 1][inv]  # (n, R) each, contiguous: the passes below read them whole
        agv = self.ag_vel[pi, pj]
        wx, wy = np.subtract(agv[:, :1], evx), np.subtract(agv[:, 1:], evy)  # relative velocity (m/s)
        # relative speeds for the pruning bounds only (they carry _EPS of slack; hypot would be ~3x the CPU)
        speed = wx * wx
        speed += np.multiply(wy, wy)
        np.sqrt(speed, out=speed)
        ok &= ~self._never_close(sel, wx, wy, speed)
        with np.errstate(divide="ignore", invalid="ignore"):
            # no contact before the gap closes at the closing speed
            t_lower = np.maximum(self.lower[sel], 0.0)
            t_lower /= speed
        t_lower[~ok] = np.inf
        np.nan_to_num(t_lower, copy=False, nan=0.0)
        best = np.full(R, np.inf)
        for cap in (4.0, np.inf):  # the likely minima first, then whatever can still beat them
            n, r = np.nonzero(ok & (t_lower <= np.minimum(cap, best)[None, :] + _EPS))
            ok[n, r] = False
            if not len(n):
                continue
            ee, ah = self.ego[pi[n], r], self.ah[pj[n]]
            a, av = self.ag[pi[n], pj[n]], self.ag_vel[pi[n], pj[n]]
            ttc = time_to_collision(
                a[:, 0] - ee[:, 0], a[:, 1] - ee[:, 1], av[:, 0] - evx[n, r], av[:, 1] - evy[n, r],
                ee[:, 2], self.eh[0], self.eh[1], a[:, 2], ah[:, 0], ah[:, 1],
            )  # fmt: skip
            np.minimum.at(best, r, ttc)
        out.min_ttc[rows] = best
