"""Whole-field motion plans that the instrument can execute: park -> c1 -> ... -> park.

:func:`plan_sequence` plans every leg of an allocation's sequence of configurations and,
when a leg cannot be planned, changes the plan instead of handing the failure over
(thesis 2.2.1.1, "Off-line operations": problematic targets are temporarily discarded and a
new assignment plan computed):

1. the leg goes through park: c_i -> park is the time reversal of a verified park -> c_i
   plan (collisions, the zone of avoidance and speed limits are symmetric in time), then
   park -> c_(i+1);
2. idle arms among those the planner could not plan rest at park instead of on blank sky,
   where park fits; then a blocking arm (the lowest-priority target among them) reaches its
   target through another IK branch, if one fits;
3. otherwise it stays at park in that configuration and its target moves to a later
   configuration that can take it on an idle arm (another arm first), or to a new
   configuration at the end of the sequence (while ``SequenceOptions.max_configurations``
   allows one more); a configuration left empty is removed;
4. the changed legs are re-planned (through park if need be) and verified.

A leg back to park that cannot be planned is the reversal of park -> c_n; if that fails too,
the last configuration loses a blocking target in the same way. At most
``SequenceOptions.max_changes`` changes are tried.

Only when every option is exhausted does a leg stay failed; the plan then says
``executable = False`` with the reasons. Every leg in the result is a
:class:`~models.types.MotionPlan` from :func:`planner.plan_motion` (verified there) or a
time reversal / concatenation of verified plans, verified again as a whole.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from models.budget import Budget
from models.errors import InputError
from models.instrument import Instrument
from models.types import ArmTrajectory, Configuration, MotionPlan, PlaneTargets, Unallocated
from planner.commands import arm_trajectory
from planner.driver import plan_motion, verified_plan
from planner.known_legs import KnownLegs, goal_key
from planner.options import MIN_LEG_S
from planner.reassign import (
    Placed,
    new_configuration,
    other_branches,
    rest_at_park,
    take_out,
    try_place,
)
from planner.strategies.reversed import reverse_trajectories

ChangeKind = Literal["via_park", "rest_to_park", "other_branch", "moved_target", "new_configuration",
                     "dropped_target"]


@dataclass(frozen=True)
class PlanChange:
    """One change to the allocation's plan made so that every leg can be executed.

    ``leg`` indexes the legs of the final plan (leg i goes to configuration i + 1; leg 0 starts
    at park, the last leg ends there); ``configuration`` indexes the final configurations.
    """

    kind: ChangeKind
    leg: int
    configuration: int | None
    arms: tuple[int, ...]
    target_ids: tuple[str, ...]
    reason: str


@dataclass(frozen=True)
class SequencePlan:
    """The executable plan of one pointing: (possibly changed) configurations and their legs."""

    configurations: tuple[Configuration, ...]
    legs: tuple[MotionPlan, ...]  # len(configurations) + 1: park -> c1, ..., c_n -> park
    changes: tuple[PlanChange, ...] = ()
    dropped: tuple[Unallocated, ...] = ()  # targets no configuration could take without a failed leg
    stats: dict = field(default_factory=dict)

    @property
    def failed_legs(self) -> tuple[int, ...]:
        return tuple(i for i, leg in enumerate(self.legs) if leg.status != "ok")

    @property
    def executable(self) -> bool:
        return not self.failed_legs

    @property
    def reasons(self) -> tuple[str, ...]:
        """One line per failed leg: which leg (counted from 1, like the configurations: leg 1
        goes park -> c1), which arms, why."""
        out = []
        n = len(self.legs)
        for i in self.failed_legs:
            leg = self.legs[i]
            src = "park" if i == 0 else f"c{i}"
            dst = "park" if i == n - 1 else f"c{i + 1}"
            why = "; ".join(f"arm {a}: {r}" for a, r in sorted(leg.stats.get("reasons", {}).items()))
            arms = ", ".join(str(a) for a in leg.failed_arms)
            out.append(f"leg {i + 1} ({src} -> {dst}): arms {arms} not planned" + (f" ({why})" if why else ""))
        return tuple(out)


@dataclass(frozen=True)
class SequenceOptions:
    """Options of :func:`plan_sequence`, validated once."""

    seed: int = 0
    leg_time_limit_s: float = 10.0  # each plan_motion call
    # the whole sequence, used when plan_sequence is given no budget (None: no limit beyond
    # the legs'); a leg is started only while MIN_LEG_S of it is left, so the sequence ends
    # within it
    time_limit_s: float | None = None
    max_changes: int = 24  # allocation changes tried before a leg is left failed
    # a target moved or put on another IK branch stays within this of park (the allocation's
    # park move limit, solvers.sequencing.options.SequenceOptions; None: no limit)
    park_move_limit_s: float | None = None
    # no configuration is added beyond this many (None: no limit); a moved target that fits in
    # no later configuration but would in a new one is then dropped as "beyond_max_exposures"
    max_configurations: int | None = None
    # the first ``kept`` configurations are kept as given (keep_configurations, planner.keep):
    # their legs may go through park, but no target, arm, branch or rest of theirs changes and
    # no moved target is put into them; a leg into one that cannot be planned stays failed
    kept: int = 0
    # (target id, arm, IK branch or None): a locked target moved or put on another branch stays
    # on that arm (and branch) (models.locks)
    locked: tuple[tuple[str, int, int | None], ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise InputError("seed", "must be an integer")
        if not (math.isfinite(self.leg_time_limit_s) and self.leg_time_limit_s > 0):
            raise InputError("leg_time_limit_s", "must be a positive finite number of seconds")
        if self.time_limit_s is not None and not (math.isfinite(self.time_limit_s) and self.time_limit_s > 0):
            raise InputError("time_limit_s", "must be a positive finite number of seconds or None")
        if not (isinstance(self.max_changes, int) and self.max_changes >= 0):
            raise InputError("max_changes", "must be an integer >= 0")
        lim = self.park_move_limit_s
        if lim is not None and not (isinstance(lim, int | float) and math.isfinite(lim) and lim > 0):
            raise InputError("park_move_limit_s", "must be a positive finite number of seconds or None")
        cap = self.max_configurations
        if cap is not None and (isinstance(cap, bool) or not isinstance(cap, int) or cap < 0):
            raise InputError("max_configurations", "must be an integer >= 0 or None")
        if isinstance(self.kept, bool) or not isinstance(self.kept, int) or self.kept < 0:
            raise InputError("kept", "must be an integer >= 0")




def end_of(plan: MotionPlan) -> np.ndarray:
    """Where a verified plan leaves the arms (theta2 unwrapped, as the next leg starts)."""
    return np.array([[tr.theta1_rad[-1], tr.theta2_rad[-1]] for tr in plan.trajectories])


def reversed_leg(instrument: Instrument, from_park: MotionPlan, start_q: np.ndarray) -> MotionPlan | None:
    """start (= the goal of ``from_park``) -> park as the time reversal of ``from_park``
    (kaiju, Sayres 2021: collisions, the zone of avoidance, joint speeds and stops are
    symmetric in time), verified."""
    trajs = reverse_trajectories(from_park.trajectories, start_q, from_park.makespan_s)
    stats = {"strategy": "reversed", "lower_bound_s": from_park.stats.get("lower_bound_s"),
             "compute_s": 0.0, "attempts": 0}
    return verified_plan(instrument, trajs, start_q, instrument.park_configuration,
                         max_start_stop=from_park.stats.get("max_stops"), stats=stats)


def via_park_leg(instrument: Instrument, from_park_a: MotionPlan, from_park_b: MotionPlan,
                 start_q: np.ndarray, goal_q: np.ndarray, lower_bound_s: float) -> MotionPlan | None:
    """start -> park -> goal: the reversal of park -> start, then park -> goal; verified as a
    whole. Each arm that moves in both halves comes to rest at park once more."""
    back = reverse_trajectories(from_park_a.trajectories, start_q, from_park_a.makespan_s)
    T1 = float(from_park_a.makespan_s)
    trajs = []
    for a, b in zip(back, from_park_b.trajectories, strict=True):
        # the reversal rests at park until T1 (its last way-point); b starts there, whole turns apart
        end = np.array([[a.theta1_rad[-1], a.theta2_rad[-1]]])
        a_q = np.column_stack([a.theta1_rad, a.theta2_rad])
        if a.t_s[-1] < T1 - 1e-12:
            a_t, a_q = np.concatenate([a.t_s, [T1]]), np.vstack([a_q, end])
        else:
            a_t = a.t_s
        keep = b.t_s > 1e-12
        b_q = np.column_stack([b.theta1_rad[keep], b.theta2_rad[keep] + (end[0, 1] - b.theta2_rad[0])])
        trajs.append(arm_trajectory(a.arm, np.concatenate([a_t, b.t_s[keep] + T1]), np.vstack([a_q, b_q])))
    stats = {"strategy": "via_park", "lower_bound_s": lower_bound_s, "compute_s": 0.0, "attempts": 0,
             "via_makespans_s": [T1, float(from_park_b.makespan_s)]}
    return verified_plan(instrument, trajs, start_q, goal_q, max_start_stop=None, stats=stats)


#: A leg that fails on its share of the sequence's time is planned once more on this many
#: times that share (:meth:`_Sequencer.escalated_s`): the leg searches (planner.driver) give
#: each strategy a fraction of the leg's budget, and a crowded leg from park that fails on
#: 0.5 s often plans in a quarter of a second once its evasion stage gets 0.15 s of 1 s.
ESCALATION = 4.0
#: The second try is made only when it gets at least this many times the first's budget.
ESCALATION_MIN_GAIN = 1.5
#: ... and at most this part of what the sequence has left, so that a leg no time plans
#: leaves its repairs and the later legs theirs.
ESCALATION_LEFT = 0.25


#: why a leg goes through park (:class:`PlanChange` "via_park")
VIA_PARK_REASON = "no direct motion found between the two configurations"


def _key(config: Configuration) -> bytes:
    """A configuration's joint angles, as the key of its park -> configuration plan."""
    return goal_key(config.q)


class _Sequencer:
    """The state of one pointing's plan while its legs are planned and repaired."""

    def __init__(self, instrument: Instrument, configurations: Sequence[Configuration],
                 options: SequenceOptions, priority_of: dict[str, int], budget: Budget,
                 progress: Callable[[float], None] | None = None, known: KnownLegs | None = None) -> None:
        self.ins = instrument
        self.known = known  # an earlier plan's verified legs, reused for the same moves
        self.progress = progress
        self.opt = options
        self.priority_of = priority_of
        self.configs = list(configurations)
        self.whole = budget  # the sequence's: every leg ends within it
        self.budget = budget.keep(MIN_LEG_S)  # a leg is started only before this deadline
        self.changes: list[PlanChange] = []
        self.dropped: list[Unallocated] = []
        self.legs: list[MotionPlan] = []
        self.from_park: dict[bytes, MotionPlan] = {}  # the configuration's joint angles -> park -> it
        self.edits = 0
        self.plans = 0
        self.reused = 0
        self.capped = False  # the target being placed fits only in a configuration the cap forbids
        self.buffer_mm = instrument.collision_buffer_mm

    # ---------------------------------------------------------------- planning primitives

    def budget_s(self) -> float:
        legs_left = max(1, len(self.configs) + 1 - len(self.legs))
        return max(MIN_LEG_S, min(self.opt.leg_time_limit_s, self.budget.left_s() / legs_left))

    def plan(self, start_q: np.ndarray, goal_q: np.ndarray, limit_s: float | None = None) -> MotionPlan:
        """The leg from ``start_q`` to ``goal_q``: a known leg making that move
        (:class:`planner.known_legs.KnownLegs`), else planned on ``limit_s`` (default: its
        share, :meth:`budget_s`)."""
        known = None if self.known is None else self.known.leg(self.ins, start_q, goal_q)
        if known is not None:
            self.reused += 1
            return known
        if self.budget.left_s() <= 0:  # the sequence's time limit has passed: no more planning
            arms = tuple(range(self.ins.n_arms))
            return MotionPlan("failed", math.nan, (), arms,
                              {"reasons": {k: "no time left in the sequence's time limit" for k in arms}})
        self.plans += 1
        return plan_motion(self.ins, start_q, goal_q, seed=self.opt.seed,
                           budget=self.whole.child(self.budget_s() if limit_s is None else limit_s), via=None)

    def plan_escalating(self, start_q: np.ndarray, goal_q: np.ndarray) -> MotionPlan:
        """:meth:`plan` on the leg's share; when that fails, once more on
        :meth:`escalated_s`: a hard leg takes time the easy ones leave rather than losing a
        target (a repair) to a share too short for its search."""
        share_s = self.budget_s()
        leg = self.plan(start_q, goal_q, share_s)
        again_s = self.escalated_s(share_s)
        if leg.status != "ok" and again_s is not None:
            leg = self.plan(start_q, goal_q, again_s)
        return leg

    def escalated_s(self, share_s: float) -> float | None:
        """The second try of a leg that failed on ``share_s``: :data:`ESCALATION` times it,
        at most ``leg_time_limit_s`` and :data:`ESCALATION_LEFT` of what the sequence has
        left; None when that is not :data:`ESCALATION_MIN_GAIN` times ``share_s``."""
        again_s = min(ESCALATION * share_s, self.opt.leg_time_limit_s, ESCALATION_LEFT * self.budget.left_s())
        return again_s if again_s >= ESCALATION_MIN_GAIN * share_s else None

    def park_to(self, config: Configuration) -> MotionPlan:
        key = _key(config)
        if key not in self.from_park:
            self.from_park[key] = self.plan(self.ins.park_configuration, config.q)
        return self.from_park[key]

    # ---------------------------------------------------------------- one transition

    def transition(self, i: int, start_q: np.ndarray) -> MotionPlan | None:
        """The leg into configuration i (i == len(configs): back to park), repaired if need be;
        None when configuration i lost its last target and was removed (leg i goes on)."""
        park = self.ins.park_configuration
        last = i == len(self.configs)
        goal = park if last else self.configs[i].q
        leg = self.from_park.get(_key(self.configs[0])) if i == 0 else None
        if leg is None:
            leg = self.plan_escalating(start_q, goal)
        if i == 0 and leg.status == "ok":
            self.from_park[_key(self.configs[0])] = leg
        if leg.status == "ok":
            return leg
        if last:
            return self._to_park(start_q, leg)
        if i > 0:
            via = self._via_park(i, start_q)
            if via is not None:
                return via
        if i < self.opt.kept:  # a kept configuration is never changed
            return leg
        return self._change(i, start_q, leg)

    def _to_park(self, start_q: np.ndarray, failed: MotionPlan) -> MotionPlan:
        back = self.park_to(self.configs[-1])
        if back.status == "ok":
            leg = reversed_leg(self.ins, back, start_q)
            if leg is not None:
                return leg
        return failed

    def _via_park(self, i: int, start_q: np.ndarray) -> MotionPlan | None:
        a, b = self.park_to(self.configs[i - 1]), self.park_to(self.configs[i])
        if a.status != "ok" or b.status != "ok":
            return None
        lb = float(b.stats.get("lower_bound_s", 0.0))
        leg = via_park_leg(self.ins, a, b, start_q, self.configs[i].q, lb)
        if leg is not None:
            self.changes.append(PlanChange("via_park", i, i, (), (), VIA_PARK_REASON))
        return leg

    def _note_via_park(self, i: int, leg: MotionPlan) -> None:
        """Leg i through park is a change of the plan, listed once however the leg came: planned
        here, or a known leg through park reused (:meth:`plan`, on any of the repairs' paths)."""
        if leg.status == "ok" and leg.stats.get("strategy") == "via_park" and not any(
                c.kind == "via_park" and c.leg == i for c in self.changes):
            self.changes.append(PlanChange("via_park", i, i, (), (), VIA_PARK_REASON))

    def _change(self, i: int, start_q: np.ndarray, failed: MotionPlan) -> MotionPlan | None:
        """Take the blocking targets out of configuration i, one at a time, until it can be reached."""
        leg = failed
        while leg.status != "ok" and self.edits < self.opt.max_changes and self.budget.left_s() > MIN_LEG_S:
            if self._rested(i, leg.failed_arms):
                leg = self._replan(i, start_q)
                continue
            config = self.configs[i]
            k = self._lowest_priority(config, leg.failed_arms)
            if k is None:  # idle arms block: a target of the arms beside them moves instead
                k = self._lowest_priority(config, self._beside(leg.failed_arms))
            if k is None:
                break
            branch = self._other_branch(i, k, start_q)
            if branch is not None:
                return branch
            changed, out = take_out(self.ins, config, [k], self.priority_of)
            self.edits += 1
            self.pending.extend(out)
            self.changes.append(PlanChange("moved_target", i, i, (k,), tuple(p.target_id for p in out),
                                           f"arm {k} blocked the motion into configuration {i + 1}; "
                                           "its target moves to another configuration"))
            if changed.arm_yield == 0:  # nothing left to observe there
                last = self.changes[-1]
                self.changes[-1] = replace(last, configuration=None,
                                           reason=last.reason + "; the configuration, left empty, is removed")
                del self.configs[i]
                return None
            self.configs[i] = changed
            leg = self._replan(i, start_q)
        return leg

    def _rested(self, i: int, arms: Sequence[int]) -> bool:
        """Idle arms of configuration i among ``arms`` from their blank-sky rest to park (no
        target changes), recorded; False when none of them can go to park."""
        config = self.configs[i]
        changed = rest_at_park(self.ins, config, arms, self.buffer_mm)
        if changed is None:
            return False
        self.edits += 1
        moved = tuple(k for k in arms if changed.assignments[k].kind != config.assignments[k].kind)
        self.configs[i] = changed
        self.changes.append(PlanChange("rest_to_park", i, i, moved, (),
                                       f"idle arms {', '.join(map(str, moved))} rest at park instead of on "
                                       f"blank sky in configuration {i + 1}"))
        return True

    def _beside(self, arms: Sequence[int]) -> tuple[int, ...]:
        """The two arms whose bases are nearest each of ``arms`` (its neighbours on the
        instrument's ring), nearest first, without ``arms`` themselves."""
        x, y = self.ins.arm_array("base_x_mm"), self.ins.arm_array("base_y_mm")
        out: list[int] = []
        for k in arms:
            d = np.hypot(x - x[k], y - y[k])
            out += [int(j) for j in np.argsort(d, kind="stable")[1:3] if int(j) not in arms]
        return tuple(dict.fromkeys(out))

    def _lowest_priority(self, config: Configuration, arms: Sequence[int]) -> int | None:
        """The arm among ``arms`` observing the lowest-priority target (the first on ties)."""
        blockers = [k for k in arms if config.assignments[k].kind == "target"]
        if not blockers:
            return None
        return min(blockers, key=lambda a: (self.priority_of.get(config.assignments[a].target_id or "", 1),
                                            blockers.index(a)))

    def _replan(self, i: int, start_q: np.ndarray) -> MotionPlan:
        """The leg into the (changed) configuration i: directly, or through park."""
        changed = self.configs[i]
        leg = self.plan(start_q, changed.q) if i == 0 else self._direct_or_via(i, start_q)
        if i == 0 and leg.status == "ok":
            self.from_park[_key(changed)] = leg
        return leg

    def _lock(self, target_id: str | None) -> tuple[int, int | None] | None:
        """The (arm, branch or None) a target is locked to, or None."""
        return next(((k, b) for t, k, b in self.opt.locked if t == target_id), None)

    def _other_branch(self, i: int, k: int, start_q: np.ndarray) -> MotionPlan | None:
        """Arm k of configuration i on the same target through another IK branch, if that plans
        (never for a target locked to its branch)."""
        lock = self._lock(self.configs[i].assignments[k].target_id)
        if lock is not None and lock[1] is not None:
            return None
        for changed in other_branches(self.ins, self.configs[i], k, self.buffer_mm,
                                      self.opt.park_move_limit_s):
            if self.edits >= self.opt.max_changes or self.budget.left_s() <= MIN_LEG_S:
                break
            self.edits += 1
            old, self.configs[i] = self.configs[i], changed
            leg = self._replan(i, start_q)
            if leg.status == "ok":
                tid = changed.assignments[k].target_id or ""
                self.changes.append(PlanChange("other_branch", i, i, (k,), (tid,),
                                               f"arm {k} reaches its target in configuration {i + 1} "
                                               "through another IK branch"))
                return leg
            self.configs[i] = old
        return None

    def _direct_or_via(self, i: int, start_q: np.ndarray) -> MotionPlan:
        leg = self.plan(start_q, self.configs[i].q)
        if leg.status == "ok":
            return leg
        return self._via_park(i, start_q) or leg

    # ---------------------------------------------------------------- moved targets

    def place_pending(self, after: int) -> None:
        """Put the targets taken out into configurations after ``after`` or into new ones: on
        another arm than the one that could not reach it if any can, else on the same arm."""
        while self.pending:
            p = self.pending.pop(0)
            self.capped = False
            if not any(self._place(p, after, exclude) for exclude in ((p.from_arm,), ())):
                self.dropped.append(Unallocated(p.target_index if p.target_index is not None else -1,
                                                p.target_id, "beyond_max_exposures" if self.capped
                                                else "conflict"))

    def _place(self, p: Placed, after: int, exclude: tuple[int, ...]) -> bool:
        lock = self._lock(p.target_id)
        branch = None
        if lock is not None:  # a locked target goes only to its own arm (and branch)
            exclude, branch = tuple(k for k in range(self.ins.n_arms) if k != lock[0]), lock[1]
        for j in range(max(after + 1, self.opt.kept), len(self.configs)):
            c = try_place(self.ins, self.configs[j], p, self.buffer_mm, exclude_arms=exclude, branch=branch,
                          park_move_limit_s=self.opt.park_move_limit_s)
            if c is not None:
                self.configs[j] = c
                return True
        c = try_place(self.ins, new_configuration(self.ins, len(self.configs)), p, self.buffer_mm,
                      exclude_arms=exclude, branch=branch, park_move_limit_s=self.opt.park_move_limit_s)
        if c is None:
            return False
        cap = self.opt.max_configurations
        if cap is not None and len(self.configs) >= cap:  # a new configuration would take it
            self.capped = True
            return False
        self.configs.append(c)
        self.changes.append(PlanChange("new_configuration", len(self.configs), len(self.configs) - 1,
                                       (), (p.target_id,), "a configuration added for moved targets"))
        return True

    def run(self) -> SequencePlan:
        self.pending: list[Placed] = []
        starts = [self.ins.park_configuration]  # starts[i]: where leg i starts
        i = 0
        while i <= len(self.configs):
            leg = self.transition(i, starts[i])
            if leg is None:  # configuration i was emptied and removed: plan leg i again
                if self.pending:
                    self.place_pending(i - 1)
                continue
            if leg.status != "ok" and i == len(self.configs) and i > 0 and self._lighten_last():
                # neither the return to park nor its reversal from park plans: the last
                # configuration lost a blocking target; plan the leg into it again
                self.legs.pop()
                starts.pop()
                i -= 1
                self.changes = [c for c in self.changes if not (c.kind == "via_park" and c.leg == i)]
                continue
            self._note_via_park(i, leg)
            self.legs.append(leg)
            if self.progress is not None:
                self.progress(min(1.0, len(self.legs) / (len(self.configs) + 1)))
            if self.pending:
                self.place_pending(i)
            starts.append(end_of(leg) if leg.status == "ok" else (self.configs[i].q if i < len(self.configs)
                                                                  else self.ins.park_configuration))
            i += 1
        configs = tuple(replace(c, index=n) for n, c in enumerate(self.configs))
        stats = {"legs": len(self.legs), "plans": self.plans, "reused_legs": self.reused, "edits": self.edits,
                 "compute_s": self.budget.elapsed_s()}
        return SequencePlan(configs, tuple(self.legs), tuple(self.changes), tuple(self.dropped), stats)

    def _lighten_last(self) -> bool:
        """Take one blocking target out of the last configuration (from its park -> c plan)."""
        n = len(self.configs)
        if self.edits >= self.opt.max_changes or self.budget.left_s() <= MIN_LEG_S or n <= self.opt.kept:
            return False
        config = self.configs[-1]
        back = self.park_to(config)
        if back.status == "ok":
            return False
        if self._rested(n - 1, back.failed_arms):  # idle arms to park first: no target changes
            return True
        k = self._lowest_priority(config, back.failed_arms)
        if k is None:
            return False
        changed, out = take_out(self.ins, config, [k], self.priority_of)
        self.edits += 1
        self.configs[-1] = changed
        self.pending.extend(out)
        self.changes.append(PlanChange("moved_target", n - 1, n - 1, (k,), tuple(p.target_id for p in out),
                                       f"arm {k} blocked the return to park from configuration {n}; "
                                       "its target moves to another configuration"))
        return True


def plan_sequence(instrument: Instrument, configurations: Sequence[Configuration],
                  options: SequenceOptions | None = None, *, targets: PlaneTargets | None = None,
                  progress: Callable[[float], None] | None = None,
                  budget: Budget | None = None, known: KnownLegs | None = None) -> SequencePlan:
    """Plans park -> c1 -> ... -> park and repairs the plan where a leg cannot be planned.

    ``budget`` is the sequence's time, on the caller's clock (default: ``options.time_limit_s``
    from now): every leg gets a child of it (its share of what is left over the legs still to
    plan, at most ``options.leg_time_limit_s``, at least :data:`MIN_LEG_S`) and none is
    started in its last :data:`MIN_LEG_S`, so the sequence ends within it.

    ``targets`` (the pointing's targets, as given to the allocator) supply the priorities that
    decide which blocking target moves first (the lowest); without them all count the same.
    ``progress(fraction)`` is called after each leg. ``known``: an earlier plan's verified
    legs, reused where this plan makes the same move instead of planning it again
    (:mod:`planner.known_legs`). Returns a :class:`SequencePlan`;
    ``executable`` is False only when every change was tried.
    """
    options = options or SequenceOptions()
    priority_of = {} if targets is None else {t: int(p) for t, p in zip(targets.ids, targets.priority, strict=True)}
    if not configurations:
        return SequencePlan((), (_stationary(instrument),), (), (), {"legs": 1})
    budget = Budget.start(options.time_limit_s) if budget is None else budget.child(math.inf)
    return _Sequencer(instrument, configurations, options, priority_of, budget, progress, known).run()


#: The verified park -> park leg of the instruments seen last (a pointing with no exposure
#: has only this leg, and a plan out of time has many such pointings): id -> (instrument, leg)
_STATIONARY: dict[int, tuple[Instrument, MotionPlan]] = {}


def _stationary(instrument: Instrument) -> MotionPlan:
    """park -> park: every arm stays where it is (verified like any other leg, once per
    instrument)."""
    seen = _STATIONARY.get(id(instrument))
    if seen is not None and seen[0] is instrument:
        return seen[1]
    leg = _verified_stationary(instrument)
    if len(_STATIONARY) >= 8:
        _STATIONARY.clear()
    _STATIONARY[id(instrument)] = (instrument, leg)
    return leg


def _verified_stationary(instrument: Instrument) -> MotionPlan:
    park = instrument.park_configuration
    trajs = tuple(ArmTrajectory(k, np.array([0.0]), park[k, :1].copy(), park[k, 1:].copy())
                  for k in range(instrument.n_arms))
    leg = verified_plan(instrument, trajs, park, park, max_start_stop=0,
                        stats={"strategy": "stationary", "compute_s": 0.0})
    if leg is None:  # the parked arms collide: an instrument file error, reported as a failed leg
        return MotionPlan("failed", float("nan"), trajs, tuple(range(instrument.n_arms)),
                          {"reasons": {k: "the parked arms collide" for k in range(instrument.n_arms)}})
    return leg
