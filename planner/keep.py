"""Keep c1..ck of a previous plan's pointing as they were and re-plan the rest (issue 39).

A kept pointing (:class:`KeptPointing`) is reused as it is: the same centre, position angle
and members. Its kept configurations are rebuilt from their joint angles and checked again
here, independently of the plan that produced them (:func:`kept_configurations`): one entry
per arm, joint angles outside the zone of avoidance, every observing arm's tip on its
target (the target projected about the pointing as the plan projects it), no target
observed twice, no two arms closer than the collision buffer. A kept configuration that
fails a check is an :class:`~models.errors.InputError` naming it, never a silent change.

The members the kept configurations do not observe are allocated from ck's arm states
(:func:`allocate_rest`) and become c(k+1)...; the motion legs park -> c1 -> ... -> park are
then all planned and verified as usual, with the kept configurations frozen
(:attr:`planner.sequence.SequenceOptions.kept`). Request targets in no kept pointing are
segmented as usual (:func:`kept_segmentation` puts those pointings after the kept ones).
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, replace

import numpy as np

from models.collision import colliding_arm_pairs
from models.errors import InputError
from models.instrument import Instrument
from models.kinematics import Links, in_zoa, tip_fov
from models.locks import TargetLock, branch_of
from models.sky import sky_to_focal_mm, tangent_radius_mm
from models.types import AllocationResult, ArmAssignment, Configuration, PlaneTargets, Unallocated
from solvers.segmentation import Pointing, Segmentation

__all__ = ["FIELD", "TIP_TOL_MM", "XY_TOL_MM", "KeptArm", "KeptPointing", "allocate_rest", "check_excluded", "check_locks",
           "kept_configurations", "kept_count", "kept_segmentation", "member_groups", "split_rest",
           "with_kept"]

#: the request field every error names
FIELD = "keep_configurations"
#: an observing arm's tip is on its target when within this of it (the allocator's own
#: re-check, solvers.problem.check_solution; far below the instrument's 130 um accuracy)
TIP_TOL_MM = 0.01
#: a kept arm's x_mm / y_mm, when given, are the tip of its joint angles to within this
XY_TOL_MM = 1e-3
#: the FOV radius a kept member may exceed by (rounding of the projection)
FOV_TOL_MM = 1e-6
KIND_NAMES = ("park", "blank", "fixed", "sky")


@dataclass(frozen=True)
class KeptArm:
    """One arm of a kept configuration: its joint angles, the target it observes (None: idle),
    and optionally the tip position and kind the previous plan reported for it."""

    arm: int
    target_id: str | None
    theta1_rad: float
    theta2_rad: float
    x_mm: float | None = None
    y_mm: float | None = None
    kind: str | None = None


@dataclass(frozen=True)
class KeptPointing:
    """A previous plan's pointing to reuse: centre, position angle (None: the request's),
    members and its configurations c1..ck; ``field`` names it in errors
    (``keep_configurations.pointings[i]``)."""

    id: str
    ra_deg: float
    dec_deg: float
    position_angle_deg: float | None
    target_ids: tuple[str, ...]
    configurations: tuple[tuple[KeptArm, ...], ...]
    field: str = f"{FIELD}.pointings[0]"

    def at_angle(self, position_angle_deg: float) -> KeptPointing:
        """This pointing with its position angle resolved to ``position_angle_deg``."""
        return replace(self, position_angle_deg=float(position_angle_deg))


def member_groups(kept: Sequence[KeptPointing], ids: Sequence[str],
                  excluded: Collection[str] = ()) -> list[np.ndarray]:
    """Each kept pointing's members as indices of the request's ``ids``, in the order of its
    ``target_ids``; -1 for a member the request excludes (``excluded``: it is no longer a
    member, unless a kept configuration observes it, which :func:`check_excluded` refuses).
    A member not in the request, or in two kept pointings (or twice in one), is an
    InputError naming ``...target_ids[j]``; two kept pointings with one id name the second's
    ``id``."""
    index = {t: i for i, t in enumerate(ids)}
    owner: dict[str, str] = {}
    names: set[str] = set()
    groups = []
    for p in kept:
        if p.id in names:
            raise InputError(f"{p.field}.id", f"pointing id {p.id!r} is kept twice")
        names.add(p.id)
        for j, t in enumerate(p.target_ids):
            if t in owner:
                raise InputError(f"{p.field}.target_ids[{j}]", f"target {t!r} is already a member of "
                                 f"{owner[t]}")
            if t not in index and t not in excluded:
                raise InputError(f"{p.field}.target_ids[{j}]", f"target {t!r} is not in the request's targets")
            owner[t] = f"pointing {p.id!r}"
        groups.append(np.array([index.get(t, -1) for t in p.target_ids], dtype=np.int64))
    return groups


def check_excluded(kept: KeptPointing, excluded: Collection[str]) -> None:
    """A kept configuration that observes a target the request excludes is an InputError
    naming it (a kept configuration is kept as it was: the request cannot change it)."""
    for j, arms in enumerate(kept.configurations):
        for m, a in enumerate(arms):
            if a.target_id is not None and a.target_id in excluded:
                raise InputError(f"{kept.field}.configurations[{j}][{m}]", f"arm {a.arm} observes target "
                                 f"{a.target_id!r}, which excluded_targets excludes")


def check_locks(inst: Instrument, configs: Sequence[Configuration], kept: KeptPointing,
                locks: Sequence[TargetLock]) -> None:
    """A kept configuration that observes a locked target on another arm (or IK branch) than
    its lock's is an InputError naming it."""
    by_id = {lk.target_id: lk for lk in locks}
    for j, c in enumerate(configs):
        field = f"{kept.field}.configurations[{j}]"
        for a in c.assignments:
            lk = by_id.get(a.target_id or "")
            if lk is None:
                continue
            if a.arm != lk.arm:
                raise InputError(field, f"arm {a.arm} observes target {a.target_id!r}, which is locked to "
                                 f"arm {lk.arm}")
            if lk.branch is not None and branch_of(inst, a.arm, a.x_mm, a.y_mm, a.theta1_rad,
                                                   a.theta2_rad) != lk.branch:
                raise InputError(field, f"arm {a.arm} observes target {a.target_id!r} through another IK "
                                 f"branch than its lock's ({lk.branch})")


# ------------------------------------------------------------- kept configurations


def kept_configurations(inst: Instrument, targets: PlaneTargets, kept: KeptPointing,
                        buffer_mm: float | None = None) -> tuple[Configuration, ...]:
    """``kept``'s configurations on ``targets`` (its members projected about it), checked;
    each is marked ``stats["kept"]``. Raises InputError naming
    ``...configurations[j]`` (or ``...configurations[j][m]`` for one entry)."""
    seen: dict[str, int] = {}
    index = {t: i for i, t in enumerate(targets.ids)}
    return tuple(_configuration(inst, targets, index, arms, j, f"{kept.field}.configurations[{j}]",
                                seen, buffer_mm)
                 for j, arms in enumerate(kept.configurations))


def _configuration(inst: Instrument, targets: PlaneTargets, index: dict[str, int],
                   arms: Sequence[KeptArm], j: int, field: str, seen: dict[str, int],
                   buffer_mm: float | None) -> Configuration:
    """Configuration ``j`` of a kept pointing, checked (:func:`kept_configurations`)."""
    n = inst.n_arms
    if sorted(a.arm for a in arms) != list(range(n)):
        raise InputError(field, f"give every arm 0..{n - 1} once (got arms {[a.arm for a in arms]})")
    by_arm = sorted(range(len(arms)), key=lambda m: arms[m].arm)
    q = np.array([[arms[m].theta1_rad, arms[m].theta2_rad] for m in by_arm], float)
    k = np.arange(n)
    bad = np.flatnonzero(in_zoa(q[:, 0], q[:, 1], Links.of(inst, k)))
    if len(bad):
        raise InputError(f"{field}[{by_arm[bad[0]]}]", f"arm {int(bad[0])}: joint angles in the zone of "
                         "avoidance or beyond the joint limits")
    tips = tip_fov(inst, k, q[:, 0], q[:, 1])
    out = [_arm(inst, targets, index, arms[m], tips[a], j, f"{field}[{m}]", seen)
           for a, m in enumerate(by_arm)]
    pairs = colliding_arm_pairs(inst, q, buffer_mm)
    if pairs:
        buffer = inst.collision_buffer_mm if buffer_mm is None else buffer_mm
        named = ", ".join(f"{a} and {b}" for a, b in pairs)
        raise InputError(field, f"arms {named} collide (closer than the {buffer:g} mm collision buffer)")
    observed = [a.target_index for a in out if a.target_index is not None]
    return Configuration(j, tuple(out), int(sum(int(targets.priority[i]) for i in observed)),
                         len(observed), "feasible", {"kept": True})


def _arm(inst: Instrument, targets: PlaneTargets, index: dict[str, int], a: KeptArm,
         tip: np.ndarray, j: int, field: str, seen: dict[str, int]) -> ArmAssignment:
    """One kept arm as an :class:`ArmAssignment`, its target, tip and kind checked."""
    if (a.x_mm is None) != (a.y_mm is None):
        raise InputError(field, "give both x_mm and y_mm, or neither")
    if a.x_mm is not None and np.hypot(a.x_mm - tip[0], a.y_mm - tip[1]) > XY_TOL_MM:
        raise InputError(field, f"arm {a.arm}: x_mm, y_mm ({a.x_mm:g}, {a.y_mm:g}) are not the tip of its "
                         f"joint angles ({tip[0]:.4f}, {tip[1]:.4f})")
    if a.target_id is None:
        return ArmAssignment(a.arm, _idle_kind(inst, a, field), a.theta1_rad, a.theta2_rad,
                             *_xy(a, tip))
    t = a.target_id
    if t not in index:
        raise InputError(field, f"arm {a.arm}: target {t!r} is not a member of this pointing")
    if t in seen:
        raise InputError(field, f"arm {a.arm}: target {t!r} is already observed in configuration "
                         f"{seen[t] + 1}")
    if a.kind not in (None, "target"):
        raise InputError(field, f"arm {a.arm}: kind {a.kind!r} with a target; use 'target'")
    i = index[t]
    goal = np.array([targets.x_mm[i], targets.y_mm[i]], float)
    miss = float(np.hypot(*(tip - goal)))
    if miss > TIP_TOL_MM:
        raise InputError(field, f"arm {a.arm} does not reach target {t!r}: its tip is {miss:.3f} mm from it "
                         f"(at most {TIP_TOL_MM:g} mm)")
    seen[t] = j
    x, y = (float(goal[0]), float(goal[1])) if a.x_mm is None else (float(a.x_mm), float(a.y_mm))
    return ArmAssignment(a.arm, "target", a.theta1_rad, a.theta2_rad, x, y, i, t)


def _idle_kind(inst: Instrument, a: KeptArm, field: str) -> str:
    """An idle arm's kind: the one given, else park at the park angles, else blank sky. A
    "sky" rest is a blank-sky rest here (the answer reports it as sky again, with the RA/Dec
    its tip points at, when it is clear of every target: :func:`planner.sky.arm_sky`)."""
    if a.kind == "target":
        raise InputError(field, f"arm {a.arm}: kind 'target' without a target_id")
    if a.kind is not None:
        if a.kind not in KIND_NAMES:
            raise InputError(field, f"arm {a.arm}: kind must be one of {', '.join(KIND_NAMES)}")
        return "blank" if a.kind == "sky" else a.kind
    park = inst.park_configuration[a.arm]
    at_park = abs(a.theta1_rad - park[0]) <= 1e-9 and abs((a.theta2_rad - park[1] + np.pi) % (2 * np.pi)
                                                           - np.pi) <= 1e-9
    return "park" if at_park else "blank"


def _xy(a: KeptArm, tip: np.ndarray) -> tuple[float, float]:
    return (float(tip[0]), float(tip[1])) if a.x_mm is None else (float(a.x_mm), float(a.y_mm))


def kept_count(configs: Sequence[Configuration]) -> int:
    """How many leading configurations of ``configs`` are kept ones (``stats["kept"]``)."""
    n = 0
    for c in configs:
        if not c.stats.get("kept"):
            break
        n += 1
    return n


# ------------------------------------------------------------------- allocation


AllocateSub = Callable[[PlaneTargets, np.ndarray, int | None], AllocationResult]


def allocate_rest(targets: PlaneTargets, kept: Sequence[Configuration], cap: int | None,
                  allocate_sub: AllocateSub) -> AllocationResult:
    """The allocation of the members the ``kept`` configurations do not observe, from the
    last one's arm states (``allocate_sub(targets, start_q, cap)``, at most ``cap`` minus the
    kept ones; None: no cap), numbered after the kept ones and indexed on ``targets``; the
    kept configurations themselves are not in it (:func:`with_kept` puts them in front).
    With no member left, or no exposure left under ``cap``, nothing is allocated (the members
    left are ``beyond_max_exposures``)."""
    observed = {a.target_index for c in kept for a in c.assignments if a.target_index is not None}
    rest = np.array([i for i in range(len(targets)) if i not in observed], dtype=np.int64)
    left = None if cap is None else cap - len(kept)
    stats = {"kept_configurations": len(kept), "n_targets": len(targets)}
    if not len(rest):
        return AllocationResult((), (), stats)
    if left is not None and left <= 0:
        out = tuple(Unallocated(int(i), targets.ids[i], "beyond_max_exposures") for i in rest)
        return AllocationResult((), out, stats)
    sub = allocate_sub(targets.subset(rest), kept[-1].q, left)
    configs = tuple(replace(c, index=len(kept) + n, assignments=tuple(
        a if a.target_index is None else replace(a, target_index=int(rest[a.target_index]))
        for a in c.assignments)) for n, c in enumerate(sub.configurations))
    unallocated = tuple(replace(u, target_index=int(rest[u.target_index])) for u in sub.unallocated)
    return AllocationResult(configs, unallocated, {**sub.stats, **stats})


def with_kept(result: AllocationResult, kept: Sequence[Configuration]) -> AllocationResult:
    """``result`` (:func:`allocate_rest`, after the exposure rules and the sky) with the kept
    configurations in front, every configuration numbered in order."""
    if not kept:
        return result
    configs = tuple(kept) + tuple(result.configurations)
    return replace(result, configurations=tuple(replace(c, index=n) for n, c in enumerate(configs)))


def split_rest(configs: Sequence[Configuration], split: Callable[[Sequence[Configuration]], tuple]
               ) -> tuple[tuple[Configuration, ...], tuple[Unallocated, ...]]:
    """``split`` (an exposure-threshold rule: configurations -> kept ones, targets dropped)
    applied to the configurations after the kept ones only: a kept configuration is never
    dropped. Returns every configuration kept, numbered in order, and the targets dropped."""
    k = kept_count(configs)
    rest, dropped = split(configs[k:])
    out = tuple(configs[:k]) + tuple(rest)
    return tuple(replace(c, index=n) for n, c in enumerate(out)), tuple(dropped)


# ------------------------------------------------------------------ segmentation


def kept_pointing(p: KeptPointing, members: np.ndarray, ra_deg: np.ndarray, dec_deg: np.ndarray,
                  tangent: tuple[float, float], inst: Instrument) -> Pointing:
    """``p`` as a :class:`Pointing` on the plan's tangent plane (``members``: of
    :func:`member_groups`). A member outside its field of view is an InputError naming
    ``...target_ids[j]``."""
    scale = inst.plate_scale_arcsec_per_mm
    at = np.flatnonzero(members >= 0)  # positions in target_ids of the members still in the request
    members = members[at]
    r = tangent_radius_mm(ra_deg[members], dec_deg[members], p.ra_deg, p.dec_deg, scale)
    far = np.flatnonzero(~(r <= inst.fov_radius_mm + FOV_TOL_MM))
    if len(far):
        j = int(at[far[0]])
        raise InputError(f"{p.field}.target_ids[{j}]", f"target {p.target_ids[j]!r} lies {float(r[far[0]]):.1f} mm "
                         f"from the pointing's centre, outside its {inst.fov_radius_mm:g} mm field of view")
    x, y = sky_to_focal_mm(np.array([p.ra_deg]), np.array([p.dec_deg]), tangent[0], tangent[1], scale)
    return Pointing(id=p.id, ra_deg=float(p.ra_deg), dec_deg=float(p.dec_deg), x_mm=float(x[0]),
                    y_mm=float(y[0]), radius_mm=float(r.max()) if len(r) else 0.0,
                    target_indices=tuple(sorted(int(i) for i in members)),
                    position_angle_deg=p.position_angle_deg)


def kept_segmentation(inst: Instrument, kept: Sequence[KeptPointing], groups: Sequence[np.ndarray],
                      rest: Segmentation | None, rest_index: np.ndarray, ra_deg: np.ndarray,
                      dec_deg: np.ndarray) -> Segmentation:
    """The plan's segmentation: the kept pointings (in the order given), then ``rest``'s
    pointings (the segmentation of the request's other targets, ``rest_index[i]`` the
    request's index of its target ``i``), renamed where an id is a kept one's. The tangent
    point is ``rest``'s, else the first kept pointing's centre."""
    tangent = (kept[0].ra_deg, kept[0].dec_deg) if rest is None else (rest.tangent_ra_deg,
                                                                      rest.tangent_dec_deg)
    out = [kept_pointing(p, g, ra_deg, dec_deg, tangent, inst) for p, g in zip(kept, groups, strict=True)]
    used = {p.id for p in out}
    for p in () if rest is None else rest.pointings:
        pid = p.id
        while pid in used:
            pid += "n"
        used.add(pid)
        out.append(replace(p, id=pid, target_indices=tuple(int(rest_index[i]) for i in p.target_indices),
                           only_here=tuple(int(rest_index[i]) for i in p.only_here)))
    stats = {} if rest is None else {k: v for k, v in rest.stats.items() if k != "exposures_lower_bound"}
    if rest is not None and "exposures_lower_bound" in rest.stats:
        # a bound on the re-segmented targets only, not on the plan's exposures
        stats["rest_exposures_lower_bound"] = rest.stats["exposures_lower_bound"]
    stats.update({"kept_pointings": len(kept), "n_pointings": len(out)})
    return Segmentation(float(tangent[0]), float(tangent[1]), tuple(out), stats)
