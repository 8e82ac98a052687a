"""Step 5 of the programme optimiser: exposures emptied into the idle arms of the others.

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
(:mod:`planner.consolidation`), and, when that empties none, :func:`thin_moves`: a target of
an exposure observing two goes, by the same test, to an exposure observing at least two that can take it (the
arm it leaves stays where it was, on blank sky), so that an exposure of few targets keeps only
targets no fuller exposure can take (issue 38's rule for such exposures).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from models import clock
from models.budget import Budget
from models.sky import sky_to_focal_mm
from models.types import AllocationResult, ArmAssignment, Configuration, Unallocated
from solvers.programme.fill import Field, FillOptions, Pointing, within
from solvers.programme.spare import FEW_TARGETS, IDLE_KINDS, placements

__all__ = ["PLACEMENT_PER_EXPOSURE_S", "PLACEMENT_S", "Arms", "LegCosts", "allocation_of", "arms_of", "consolidate",
           "empty_exposures", "thin_moves"]

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


@dataclass(frozen=True)
class LegCosts:
    """What each pointing's motion legs cost to plan again (``per_leg_s``: seconds per leg, by
    pointing key), against its exposures as the pass found them (``original``): a taker is then
    chosen by the legs it makes new before how full it is (:meth:`extra_s`). A leg is new when
    it starts or ends at an exposure the pass changed, or joins two exposures the plan did not
    make one after the other (one between them was emptied); the plan reuses every other leg
    (:mod:`planner.known_legs`)."""

    original: Mapping[int, Arms]
    per_leg_s: Mapping[int, float]

    @classmethod
    def of(cls, state: Mapping[int, Arms], per_leg_s: Mapping[int, float]) -> LegCosts:
        return cls({k: a.copy() for k, a in state.items()}, dict(per_leg_s))

    def extra_s(self, k: int, cur: Arms, x: int) -> float:
        """What taking a target into exposure ``x`` of pointing ``k`` (as it stands, ``cur``)
        adds: the legs into and out of it that are not new already, at the pointing's cost."""
        orig = self.original.get(k)
        if orig is None or self._changed(orig, cur, x):
            return 0.0
        alive = [int(e) for e in np.flatnonzero(cur.alive)]
        i = alive.index(x)
        prev = alive[i - 1] if i > 0 else None
        nxt = alive[i + 1] if i + 1 < len(alive) else None
        legs = sum(not self._new(orig, cur, a, b) for a, b in ((prev, x), (x, nxt)))
        return legs * self.per_leg_s.get(k, 0.0)

    @staticmethod
    def _changed(orig: Arms, cur: Arms, e: int) -> bool:
        return bool(np.any(orig.target[e] != cur.target[e]) or np.any(orig.q[e] != cur.q[e]))

    def _new(self, orig: Arms, cur: Arms, a: int | None, b: int | None) -> bool:
        """Whether the leg a -> b (None: park) is new (class docstring)."""
        ends = [e for e in (a, b) if e is not None]
        if any(self._changed(orig, cur, e) for e in ends):
            return True
        lo = -1 if a is None else a
        hi = len(orig.alive) if b is None else b
        return bool(np.any(orig.alive[lo + 1:hi]))  # an exposure between them was emptied


def consolidate(f: Field, pts: list[Pointing], opts: FillOptions, budget: Budget) -> int:
    """Step 5 (module docstring) on the allocated pointings ``pts``, in place: the pointings
    that give or take targets are replaced by ones with their new members and allocations.
    Returns the exposures given up."""
    state = {j: _arms_of(f, p) for j, p in enumerate(pts) if p.allocation is not None and p.exposures}
    saved, groups = empty_exposures(f, state, opts.park_move_limit_s, opts.arm_limits, budget)
    for j in set().union(*groups):
        pts[j] = _rebuilt(f, pts[j], state[j])
    return saved


def empty_exposures(f: Field, state: dict[int, Arms], park_move_limit_s: float | None,
                    arm_limits: tuple[int, ...] | None, budget: Budget,
                    legs: LegCosts | None = None) -> tuple[int, list[frozenset[int]]]:
    """The pass of the module docstring on the pointings' exposures ``state`` (any keys), in
    place; ``arm_limits``: per target of the programme, the bit mask of the arms it may use
    (None: any); ``legs``: each target goes to the exposure whose legs cost least to plan
    again, then the fullest (:class:`LegCosts`; None: the fullest). Returns the exposures
    given up (their ``alive`` turned False) and, for each, the keys of the pointings that gave
    or took its targets."""
    focal: dict[tuple[int, int], tuple[float, float] | None] = {}
    order = sorted(((int(np.count_nonzero(a.target[e] >= 0)), j, e) for j, a in state.items()
                    for e in np.flatnonzero(a.alive)))
    saved, groups = 0, []
    for _, j, e in order:
        if budget.expired():
            break
        trial = _emptied(f, state, j, int(e), park_move_limit_s, arm_limits, focal, legs)
        if trial is not None:
            state.update(trial)
            groups.append(frozenset(trial))
            saved += 1
    return saved, groups


def arms_of(n_arms: int, centre: tuple[float, float], pa_deg: float, configs: Sequence[Configuration],
            target_of: Callable[[ArmAssignment], int]) -> Arms:
    """The exposures ``configs`` of a pointing as :class:`Arms`; ``target_of``: the programme
    index of an observing arm's target."""
    q = np.zeros((len(configs), n_arms, 2))
    idle = np.zeros((len(configs), n_arms), bool)
    target = np.full((len(configs), n_arms), -1, np.int64)
    for e, c in enumerate(configs):
        for a in c.assignments:
            q[e, a.arm] = (a.theta1_rad, a.theta2_rad)
            idle[e, a.arm] = a.kind in IDLE_KINDS
            if a.target_index is not None:
                target[e, a.arm] = target_of(a)
    return Arms(centre, pa_deg, q, idle, target, np.ones(len(configs), bool))


def allocation_of(f: Field, a: Arms, configs: Sequence[Configuration], target_of: Callable[[ArmAssignment], int],
                  unobserved: Mapping[int, str], source: str) -> tuple[tuple[int, ...], AllocationResult]:
    """The exposures of ``a`` still alive (``configs``: the ones :func:`arms_of` read, in
    order) as an allocation of the pointing's members: the targets they observe and
    ``unobserved`` (programme index -> reason), ascending. It has the form of the optimiser's
    witnesses (:func:`solvers.programme.fill.witness`: ``target_index`` into the members,
    ``target_id`` the ``str`` of the programme index); ``source`` names it in its stats."""
    observed = {int(t) for t in a.target[a.alive].ravel() if t >= 0}
    members = tuple(sorted(observed | set(unobserved)))
    pos = {g: i for i, g in enumerate(members)}
    out = []
    for e in np.flatnonzero(a.alive):
        arms = tuple(_assignment(f, a, asg, int(a.target[e, asg.arm]), a.q[e, asg.arm], target_of, pos)
                     for asg in configs[e].assignments)
        out.append(replace(configs[e], index=len(out), assignments=arms,
                           total_priority=sum(int(f.priority[members[x.target_index]]) for x in arms
                                              if x.target_index is not None),
                           arm_yield=sum(x.kind == "target" for x in arms)))
    unallocated = tuple(Unallocated(pos[g], str(g), r) for g, r in sorted(unobserved.items()))
    stats = {"source": source, "n_targets": len(members), "n_configurations": len(out),
             "n_allocated": len(observed), "field_completeness": len(observed) / len(members) if members else 1.0,
             "unallocated_by_reason": {r: sum(u.reason == r for u in unallocated)
                                       for r in sorted({u.reason for u in unallocated})}}
    return members, AllocationResult(tuple(out), unallocated, stats)


def _arms_of(f: Field, p: Pointing) -> Arms:
    return arms_of(f.inst.n_arms, p.centre, p.pa_deg, p.allocation.configurations[:p.exposures],
                   lambda asg: int(p.members[asg.target_index]))


def thin_moves(f: Field, state: dict[int, Arms], park_move_limit_s: float | None,
               arm_limits: tuple[int, ...] | None, budget: Budget, few: int = FEW_TARGETS,
               legs: LegCosts | None = None) -> tuple[int, int, list[frozenset[int]]]:
    """The exposures observing at most ``few`` targets (but more than one: an exposure of one
    target is emptied or stays), in place: each of their targets that fits on an idle arm of an
    exposure observing at least ``few`` goes there (the fullest first, as
    :func:`empty_exposures` places), so that such an exposure keeps only targets no fuller
    exposure can take. Returns the exposures emptied that way, the targets moved and, for each
    exposure that gave a target, the keys of the pointings that gave or took its targets
    (``legs``: as :func:`empty_exposures` chooses)."""
    focal: dict[tuple[int, int], tuple[float, float] | None] = {}
    order = sorted((n, j, int(e)) for j, a in state.items() for e in np.flatnonzero(a.alive)
                   if 1 < (n := int(np.count_nonzero(a.target[e] >= 0))) <= few)
    emptied, moved, groups = 0, 0, []
    for _, j, e in order:
        if budget.expired():
            break
        trial: dict[int, Arms] = {}
        for arm in np.flatnonzero(state[j].target[e] >= 0):
            t = int(state[j].target[e, arm])
            best = _taker(f, state, trial, t, park_move_limit_s, arm_limits, focal, skip=(j, e), min_targets=few,
                          legs=legs)
            if best is not None:
                _place(state, trial, best, t)
                mine = trial.setdefault(j, state[j].copy())
                mine.idle[e, arm], mine.target[e, arm] = True, -1
                moved += 1
        if trial:
            state.update(trial)
            groups.append(frozenset(trial))
            if not (state[j].target[e] >= 0).any():
                state[j].alive[e] = False
                emptied += 1
    return emptied, moved, groups


def _emptied(f: Field, state: dict[int, Arms], j: int, e: int, park_move_limit_s: float | None,
             arm_limits: tuple[int, ...] | None, focal: dict, legs: LegCosts | None = None) -> dict[int, Arms] | None:
    """The pointings' exposures with exposure ``e`` of pointing ``j`` given up and each of its
    targets on an idle arm of another exposure; None when one of its targets fits nowhere."""
    trial = {j: state[j].copy()}
    trial[j].alive[e] = False
    for arm in np.flatnonzero(state[j].target[e] >= 0):
        t = int(state[j].target[e, arm])
        best = _taker(f, state, trial, t, park_move_limit_s, arm_limits, focal, legs=legs)
        if best is None:
            return None
        _place(state, trial, best, t)
    return trial


def _taker(f: Field, state: dict[int, Arms], trial: dict[int, Arms], t: int, park_move_limit_s: float | None,
           arm_limits: tuple[int, ...] | None, focal: dict, skip: tuple[int, int] | None = None,
           min_targets: int = 0, legs: LegCosts | None = None) -> tuple | None:
    """The exposure alive in ``trial`` (else ``state``) that takes target ``t`` on an idle arm,
    the one whose legs cost least to plan again first (``legs``, :class:`LegCosts`; None: all
    the same), then the fullest (then the last pointing and exposure): ((-legs' cost, targets
    observed, -pointing, -exposure), pointing, exposure, arm, pose), or None; ``skip``: a
    (pointing, exposure) left out; ``min_targets``: only exposures observing at least that
    many."""
    best = None
    for k, a in state.items():
        xy = _focal(f, a, t, k, focal)
        cur = trial.get(k, a)
        live = np.flatnonzero(cur.alive & (np.count_nonzero(cur.target >= 0, axis=1) >= min_targets))
        if skip is not None and skip[0] == k:
            live = live[live != skip[1]]
        if xy is None or live.size == 0:
            continue
        clock.charge(PLACEMENT_S + PLACEMENT_PER_EXPOSURE_S * live.size)
        allowed = None if arm_limits is None else int(arm_limits[t])
        arm_k, pose = placements(f.inst, cur.q[live], cur.idle[live], xy[0], xy[1], park_move_limit_s, allowed)
        for i in np.flatnonzero(arm_k >= 0):
            x = int(live[i])
            extra_s = 0.0 if legs is None else legs.extra_s(k, cur, x)
            key = (-extra_s, int(np.count_nonzero(cur.target[x] >= 0)), -k, -x)
            if best is None or key > best[0]:
                best = (key, k, x, int(arm_k[i]), pose[i])
    return best


def _place(state: dict[int, Arms], trial: dict[int, Arms], best: tuple, t: int) -> None:
    """Target ``t`` on the arm :func:`_taker` chose, in ``trial``."""
    _, k, x, arm_k, pose = best
    cur = trial.setdefault(k, state[k].copy())
    cur.q[x, arm_k], cur.idle[x, arm_k], cur.target[x, arm_k] = pose, False, t


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
    members, allocation = allocation_of(f, a, old.configurations, lambda asg: int(p.members[asg.target_index]),
                                        {int(p.members[u.target_index]): u.reason for u in old.unallocated},
                                        "programme optimiser")
    if not members:
        return Pointing(p.centre, p.pa_deg, np.zeros(0, np.int64), 0, pa_search=p.pa_search)
    return Pointing(p.centre, p.pa_deg, np.array(members, np.int64), len(allocation.configurations),
                    allocation=allocation, pa_search=p.pa_search, allocation_s=p.allocation_s)


def _assignment(f: Field, a: Arms, asg: ArmAssignment, t: int, pose: np.ndarray,
                target_of: Callable[[ArmAssignment], int], pos: Mapping[int, int]) -> ArmAssignment:
    """An arm's assignment in a rebuilt exposure: as it was (its target relabelled to the
    members), or observing ``t`` (programme index) at ``pose`` when it took that target."""
    if t < 0:  # idle; an arm whose target went to another exposure stays where it was, on blank sky
        return asg if asg.target_index is None else replace(asg, kind="blank", target_index=None, target_id=None)
    if asg.target_index is not None and target_of(asg) == t:
        return replace(asg, target_index=pos[t], target_id=str(t))
    x, y = sky_to_focal_mm(f.ra_deg[[t]], f.dec_deg[[t]], a.centre[0], a.centre[1], f.scale, a.pa_deg)
    return ArmAssignment(asg.arm, "target", float(pose[0]), float(pose[1]), float(x[0]), float(y[0]), pos[t], str(t))
