"""After the rounds: exposures of a programme's plan emptied into the idle arms of its other
exposures (segmentation mode "fewest-exposures"; docs/programme.md, *Emptied exposures*).

Each pointing is allocated and planned on its own, so a pointing's last exposures observe the
few targets it has left while exposures of the neighbouring pointings keep idle arms over the
same sky. Once every pointing is planned, :func:`regroup` runs the optimiser's pass
(:func:`solvers.programme.consolidate.empty_exposures`: an exposure is given up when each of
its targets fits, as the other exposures stand, on an idle arm of one of them) on the plan's
configurations. The pointings it changes are planned again with those configurations as their
allocation (:attr:`Regrouped.allocation`; the allocation is not searched again), each on a
share of what the rounds left (:func:`consolidation_tasks`), and the new plans replace the old
ones only when every one of them is executable, together they observe every target the old
ones did and take fewer exposures (:func:`accepted`). Otherwise the plan stays as it was.

The pass reads the plan's outcomes and runs on the plan's effort clock, so the result is the
same on one or many workers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from models.budget import Budget
from models.instrument import Instrument
from models.sky import sky_to_focal_mm
from models.types import AllocationResult, ArmAssignment, Configuration, Unallocated
from planner.programme import PointingOutcome, RoundTask, _by_need, usable_s
from planner.shares import SHARES, ProgrammeShares
from solvers.programme.consolidate import Arms, empty_exposures
from solvers.programme.fill import Field
from solvers.programme.spare import IDLE_KINDS

__all__ = ["PlannedPointing", "Regrouped", "accepted", "consolidation_tasks", "regroup"]


@dataclass(frozen=True)
class PlannedPointing:
    """A pointing as the plan observes it: centre (sky, deg), position angle, its
    configurations (each arm's ``target_index``: the target's index in the programme) and its
    members the plan does not observe, with the reason (programme index -> reason)."""

    centre: tuple[float, float]
    pa_deg: float
    configurations: tuple[Configuration, ...]
    unobserved: Mapping[int, str]


@dataclass(frozen=True)
class Regrouped:
    """A pointing the pass changed: its members (programme indices, ascending) and their
    allocation (``target_index`` into ``members``, ``target_id`` the ``str`` of the programme
    index: the form of :attr:`solvers.segmentation.field.Pointing.allocation`)."""

    index: int
    members: tuple[int, ...]
    allocation: AllocationResult


def regroup(inst: Instrument, ra_deg: np.ndarray, dec_deg: np.ndarray, priority: np.ndarray,
            pointings: Sequence[PlannedPointing], park_move_limit_s: float | None,
            arm_limits: tuple[int, ...] | None, budget: Budget) -> tuple[int, list[Regrouped]]:
    """The exposures the pass gives up and the pointings it changes (module docstring)."""
    f = Field(inst, np.asarray(ra_deg, float), np.asarray(dec_deg, float), np.asarray(priority, np.int64))
    state = {j: _arms(inst, p) for j, p in enumerate(pointings) if p.configurations}
    before = {j: a.copy() for j, a in state.items()}
    saved = empty_exposures(f, state, park_move_limit_s, arm_limits, budget)
    if saved == 0:
        return 0, []
    changed = [j for j, a in state.items()
               if not (np.array_equal(a.alive, before[j].alive) and np.array_equal(a.target, before[j].target))]
    return saved, [_regrouped(f, j, pointings[j], state[j]) for j in changed]


def _arms(inst: Instrument, p: PlannedPointing) -> Arms:
    n, e = inst.n_arms, len(p.configurations)
    q, idle, target = np.zeros((e, n, 2)), np.zeros((e, n), bool), np.full((e, n), -1, np.int64)
    for i, c in enumerate(p.configurations):
        for a in c.assignments:
            q[i, a.arm] = (a.theta1_rad, a.theta2_rad)
            idle[i, a.arm] = a.kind in IDLE_KINDS
            if a.target_index is not None:
                target[i, a.arm] = int(a.target_index)
    return Arms(p.centre, p.pa_deg, q, idle, target, np.ones(e, bool))


def _regrouped(f: Field, j: int, p: PlannedPointing, a: Arms) -> Regrouped:
    observed = {int(t) for t in a.target[a.alive].ravel() if t >= 0}
    members = tuple(sorted(observed | set(p.unobserved)))
    pos = {g: i for i, g in enumerate(members)}
    configs = []
    for e in np.flatnonzero(a.alive):
        arms = tuple(_assignment(f, p, asg, int(a.target[e, asg.arm]), a.q[e, asg.arm], pos)
                     for asg in p.configurations[e].assignments)
        configs.append(replace(p.configurations[e], index=len(configs), assignments=arms,
                               total_priority=sum(int(f.priority[int(members[x.target_index])]) for x in arms
                                                  if x.target_index is not None),
                               arm_yield=sum(x.kind == "target" for x in arms)))
    unallocated = tuple(Unallocated(pos[g], str(g), r) for g, r in sorted(p.unobserved.items()))
    stats = {"source": "consolidation", "n_targets": len(members), "n_configurations": len(configs),
             "n_allocated": len(observed), "field_completeness": len(observed) / len(members) if members else 1.0}
    return Regrouped(j, members, AllocationResult(tuple(configs), unallocated, stats))


def _assignment(f: Field, p: PlannedPointing, asg: ArmAssignment, t: int, q: np.ndarray,
                pos: Mapping[int, int]) -> ArmAssignment:
    """An arm's assignment in a regrouped exposure, its target relabelled to the members."""
    if t < 0:
        return asg
    if asg.target_index is not None and int(asg.target_index) == t:
        return replace(asg, target_index=pos[t], target_id=str(t))
    x, y = sky_to_focal_mm(f.ra_deg[[t]], f.dec_deg[[t]], p.centre[0], p.centre[1], f.scale, p.pa_deg)
    return ArmAssignment(asg.arm, "target", float(q[0]), float(q[1]), float(x[0]), float(y[0]), pos[t], str(t))


def consolidation_tasks(needs: Sequence[float], limit_s: float | None,
                        history: Sequence[Sequence[PointingOutcome]], changed: Sequence[int], *,
                        spent_s: float = 0.0, table: ProgrammeShares = SHARES) -> list[RoundTask]:
    """The tasks that plan the ``changed`` pointings again, in the round after ``history``:
    what the rounds left (counted as :func:`planner.programme.next_round` counts it) less
    ``spent_s`` (the pass itself), split by need; none when that leaves a pointing less than
    ``min_pointing_s`` (the plan then stays as it was)."""
    usable = usable_s(limit_s, table)
    spent = spent_s + sum(o.spent_s(table) for outcomes in history for o in outcomes)
    left = (1e9 if np.isinf(usable) else usable - spent)
    shares = _by_need(left, list(changed), needs, table) if left >= table.min_pointing_s else {}
    if sorted(shares) != sorted(changed):
        return []
    r = len(history) + 1
    return [RoundTask(i, r, shares[i]) for i in sorted(changed)]


def accepted(old_observed: Sequence[set[str]], new_observed: Sequence[set[str]], old_exposures: int,
             new_exposures: int, executable: Sequence[bool]) -> bool:
    """Whether the changed pointings' new plans replace their old ones: every one executable,
    together observing every target the old ones did, in fewer exposures."""
    old_all = set().union(*old_observed)
    new_all = set().union(*new_observed)
    return all(executable) and new_all >= old_all and new_exposures < old_exposures
