"""Step 6 of the programme optimiser: exposures emptied into the idle arms of the others.

An exposure of the pointings' allocations (their witnesses, :mod:`.fill`) is given up when
every target it observes can be observed, as the other exposures stand, by one of their idle
arms: an arm at park or on blank sky that reaches the target within the park move limit
and, there, clears every other arm of that exposure by the collision buffer
(:func:`solvers.programme.spare.placements`, the exact test of :mod:`.spare`). The taker may
be another exposure of the same pointing or an exposure of any pointing whose FOV holds the
target (by :data:`solvers.programme.fill.RIM_MARGIN_MM`); the target then becomes a member of
that pointing. Nothing else of an exposure changes, so every exposure stays a valid
configuration, and the programme takes one exposure less for each one emptied.

Exposures are tried fewest targets first (then in the order of the pointings and of their
sequence); each target goes to the fullest exposure that can take it. Taking a target only
turns an idle arm into an observing one, so an exposure that cannot be emptied at one point
of the pass cannot be emptied later in it either: one pass tries every exposure once.

This is where the pointings' overlaps pay: the segmentation and the commits give each target
one pointing, and a pointing's last exposures observe the few targets left over, while
exposures of the neighbouring pointings keep idle arms over the same sky. The plan runs the
same pass (:func:`empty_exposures`) on its own configurations after its rounds
(:mod:`planner.consolidation`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from models import clock
from models.budget import Budget
from models.sky import sky_to_focal_mm
from models.types import AllocationResult, ArmAssignment, Unallocated
from solvers.programme.fill import Field, FillOptions, Pointing, within, witness
from solvers.programme.spare import IDLE_KINDS, placements

__all__ = ["PLACEMENT_PER_EXPOSURE_S", "PLACEMENT_S", "Arms", "consolidate", "empty_exposures"]

#: effort seconds charged per test of one target against one pointing's exposures: its reach
#: (per test) and the clearance to the other arms (per exposure tested); reference seconds
PLACEMENT_S = 0.8e-3
PLACEMENT_PER_EXPOSURE_S = 20e-6


@dataclass
class Arms:
    """One pointing's exposures as they stand: its centre (sky, deg) and position angle, the
    joint angles ``q`` (E, n_arms, 2), which arms are ``idle`` (E, n_arms), the target each
    arm observes (programme index, -1: none) and which exposures are still ``alive``."""

    centre: tuple[float, float]
    pa_deg: float
    q: np.ndarray
    idle: np.ndarray
    target: np.ndarray
    alive: np.ndarray

    def copy(self) -> Arms:
        return Arms(self.centre, self.pa_deg, self.q.copy(), self.idle.copy(), self.target.copy(),
                    self.alive.copy())


def consolidate(f: Field, pts: list[Pointing], opts: FillOptions, budget: Budget) -> int:
    """Step 6 (module docstring) on the allocated pointings ``pts``, in place: the pointings
    that give or take targets are replaced by ones with their new members and allocations.
    Returns the exposures given up."""
    state = {j: _arms_of(f, p) for j, p in enumerate(pts) if p.allocation is not None and p.exposures}
    saved = empty_exposures(f, state, opts.park_move_limit_s, opts.arm_limits, budget)
    if saved:
        for j, a in state.items():
            pts[j] = _rebuilt(f, pts[j], a)
    return saved


def empty_exposures(f: Field, state: dict[int, Arms], park_move_limit_s: float | None,
                    arm_limits: tuple[int, ...] | None, budget: Budget) -> int:
    """The pass of the module docstring on the pointings' exposures ``state`` (any keys), in
    place; ``arm_limits``: per target of the programme, the bit mask of the arms it may use
    (None: any). Returns the exposures given up (their ``alive`` turned False)."""
    focal: dict[tuple[int, int], tuple[float, float] | None] = {}
    order = sorted(((int(np.count_nonzero(a.target[e] >= 0)), j, e) for j, a in state.items()
                    for e in np.flatnonzero(a.alive)))
    saved = 0
    for _, j, e in order:
        if budget.expired():
            break
        trial = _emptied(f, state, j, int(e), park_move_limit_s, arm_limits, focal)
        if trial is not None:
            state.update(trial)
            saved += 1
    return saved


def _arms_of(f: Field, p: Pointing) -> Arms:
    configs = p.allocation.configurations[:p.exposures]
    n = f.inst.n_arms
    q = np.zeros((len(configs), n, 2))
    idle = np.zeros((len(configs), n), bool)
    target = np.full((len(configs), n), -1, np.int64)
    for e, c in enumerate(configs):
        for a in c.assignments:
            q[e, a.arm] = (a.theta1_rad, a.theta2_rad)
            idle[e, a.arm] = a.kind in IDLE_KINDS
            if a.target_index is not None:
                target[e, a.arm] = int(p.members[a.target_index])
    return Arms(p.centre, p.pa_deg, q, idle, target, np.ones(len(configs), bool))


def _emptied(f: Field, state: dict[int, Arms], j: int, e: int, park_move_limit_s: float | None,
             arm_limits: tuple[int, ...] | None, focal: dict) -> dict[int, Arms] | None:
    """The pointings' exposures with exposure ``e`` of pointing ``j`` given up and each of its
    targets on an idle arm of another exposure; None when one of its targets fits nowhere."""
    trial = {j: state[j].copy()}
    trial[j].alive[e] = False
    for arm in np.flatnonzero(state[j].target[e] >= 0):
        t = int(state[j].target[e, arm])
        best = None  # (targets observed, -pointing, -exposure), pointing, exposure, arm, pose
        for k, a in state.items():
            xy = _focal(f, a, t, k, focal)
            cur = trial.get(k, a)
            live = np.flatnonzero(cur.alive)
            if xy is None or live.size == 0:
                continue
            clock.charge(PLACEMENT_S + PLACEMENT_PER_EXPOSURE_S * live.size)
            allowed = None if arm_limits is None else int(arm_limits[t])
            arm_k, pose = placements(f.inst, cur.q[live], cur.idle[live], xy[0], xy[1], park_move_limit_s, allowed)
            for i in np.flatnonzero(arm_k >= 0):
                x = int(live[i])
                key = (int(np.count_nonzero(cur.target[x] >= 0)), -k, -x)
                if best is None or key > best[0]:
                    best = (key, k, x, int(arm_k[i]), pose[i])
        if best is None:
            return None
        _, k, x, arm_k, pose = best
        cur = trial.setdefault(k, state[k].copy())
        cur.q[x, arm_k], cur.idle[x, arm_k], cur.target[x, arm_k] = pose, False, t
    return trial


def _focal(f: Field, a: Arms, t: int, k: int, cache: dict) -> tuple[float, float] | None:
    """Target ``t`` on the focal plane of pointing ``a`` (key ``k``), or None when the
    pointing's FOV does not hold it."""
    if (t, k) not in cache:
        idx = np.array([t])
        if not within(f, idx, a.centre)[0]:
            cache[(t, k)] = None
        else:
            x, y = sky_to_focal_mm(f.ra_deg[idx], f.dec_deg[idx], a.centre[0], a.centre[1], f.scale, a.pa_deg)
            cache[(t, k)] = (float(x[0]), float(y[0]))
    return cache[(t, k)]


def _rebuilt(f: Field, p: Pointing, a: Arms) -> Pointing:
    """``p`` with the exposures of ``a`` still alive, its members those they observe and the
    members its allocation left unobserved (for a reason of the geometry)."""
    old = p.allocation
    observed = {int(t) for t in a.target[a.alive].ravel() if t >= 0}
    unobserved = {int(p.members[u.target_index]) for u in old.unallocated}
    keep = np.array(sorted(observed | unobserved), dtype=np.int64)
    if keep.size == 0:
        return Pointing(p.centre, p.pa_deg, keep, 0, pa_search=p.pa_search)
    ext = np.array(sorted(observed | {int(t) for t in p.members}), dtype=np.int64)
    pos = {int(g): i for i, g in enumerate(ext)}
    configs = []
    for e in np.flatnonzero(a.alive):
        c = old.configurations[e]
        arms = tuple(_assignment(f, p, asg, int(a.target[e, asg.arm]), a.q[e, asg.arm], pos)
                     for asg in c.assignments)
        configs.append(replace(c, assignments=arms, arm_yield=sum(x.kind == "target" for x in arms)))
    unallocated = tuple(Unallocated(pos[int(p.members[u.target_index])], u.target_id, u.reason)
                        for u in old.unallocated)
    result = AllocationResult(tuple(configs), unallocated, old.stats)
    return Pointing(p.centre, p.pa_deg, keep, len(configs), allocation=witness(result, ext, keep, len(configs),
                                                                                 f.priority),
                    pa_search=p.pa_search)


def _assignment(f: Field, p: Pointing, asg: ArmAssignment, t: int, q: np.ndarray, pos: dict) -> ArmAssignment:
    """An arm's assignment in a rebuilt exposure: as it was, or observing ``t`` (programme
    index) at the pose ``q`` when it took that target."""
    if t < 0 or (asg.target_index is not None and int(p.members[asg.target_index]) == t):
        return asg if asg.target_index is None else replace(asg, target_index=pos[t])
    x, y = sky_to_focal_mm(f.ra_deg[[t]], f.dec_deg[[t]], p.centre[0], p.centre[1], f.scale, p.pa_deg)
    return ArmAssignment(asg.arm, "target", float(q[0]), float(q[1]), float(x[0]), float(y[0]), pos[t], str(t))
