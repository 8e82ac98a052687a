"""Re-check a plan file anyone hands over (issue 39 item 5): every configuration, every
trajectory and the content hash, with the independent verifier and the models only.

Nothing here comes from the planner's search. The file is read into domain types
(:mod:`planner.plan_file`) and checked:

* **hash** - ``content_hash`` equals the SHA-256 of the plan's canonical JSON
  (:func:`planner.plan_file.content_hash`);
* **configurations** - one assignment per arm; each tip, by forward kinematics
  (:func:`models.kinematics.tip_fov`), is where the assignment says (``geometry``); each
  observed target is one of the pointing's, and the tip reaches the target's focal-plane
  position recomputed from its RA/Dec, the pointing's centre and position angle through
  :func:`models.sky.sky_to_focal_mm` (``target``), to :data:`POSITION_TOL_MM`; no target twice
  in one configuration; joint limits, zone of avoidance and every arm pair's clearance >= the
  collision buffer (:func:`planner.verify.verify_trajectories` on the configuration at rest);
* **trajectories** - every leg park -> c1 -> ... -> cn -> park of a pointing, with the
  verifier: one trajectory per arm, starting at the previous configuration and ending at the
  next (park at both ends), joint speeds <= the instrument's, joint limits and zone of
  avoidance at every sample, clearance sampled every :data:`DT_CHECK_S` (a tenth of the
  planner's 0.1 s collision step), controller commands matching the way-points; plus one
  command per moving joint per way-point segment (``commands``), the start-stop cycles at most
  :data:`MAX_STOPS` (a leg through park: those of its two halves and one more, at park;
  :func:`allowed_stops`), the leg's reported
  ``max_stops`` and ``makespan_s`` equal to the way-points' (``stops``, ``makespan``);
* **claims** - a pointing's and the plan's ``executable`` agree with their legs' statuses.

A leg with status "failed" was not planned: it is reported (the plan is not executable) but
has no trajectory to check. ``valid`` means the hash matches and no check failed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from models.errors import InputError
from models.instrument import Instrument
from models.kinematics import tip_fov
from models.sky import sky_to_focal_mm
from models.types import ArmTrajectory, Configuration
from planner.plan_file import FileLeg, FilePointing, PlanFile, read_plan
from planner.verify import verify_trajectories

#: Tolerance on a tip position against its assignment and its target, mm (the IK solutions
#: and the sky projection agree to ~1e-9 mm; the instrument's final accuracy is 0.13 mm).
POSITION_TOL_MM = 1e-3
#: Re-simulation step of the trajectory checks, s (the planner checks collisions every 0.1 s).
DT_CHECK_S = 0.01
#: Start-stop cycles allowed per arm on a direct leg (the planner's default, thesis 6.3.4.4).
#: A leg sent through park (a ``via_park`` change) is two such legs, start -> park and
#: park -> goal, each within it, with one more stop at park (:func:`allowed_stops`).
MAX_STOPS = 1
#: Violations listed in a report at most (all are counted).
MAX_LISTED = 100
_MOVE_EPS_RAD = 1e-12

Progress = Callable[[float], None]


@dataclass(frozen=True)
class PlanViolation:
    """One failed check. ``configuration`` and ``leg`` are counted from 1 as in the plan's
    reasons (leg 1 is park -> c1); None where the check is not about one."""

    pointing: str | None
    configuration: int | None
    leg: int | None
    arm: int | None
    kind: str
    message: str


@dataclass(frozen=True)
class ValidationReport:
    valid: bool
    hash_ok: bool
    executable: bool
    violations: tuple[PlanViolation, ...]  # the first MAX_LISTED
    violations_total: int
    checked: dict[str, int] = field(default_factory=dict)


@dataclass
class _Run:
    """What a validation has found and counted so far."""

    inst: Instrument
    violations: list[PlanViolation] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys((
        "pointings", "configurations", "assignments", "targets", "legs", "legs_failed",
        "trajectories", "waypoints", "samples", "pair_samples"), 0))

    def add(self, pointing: FilePointing | None, kind: str, message: str, *,
            configuration: int | None = None, leg: int | None = None, arm: int | None = None) -> None:
        self.violations.append(PlanViolation(None if pointing is None else pointing.id, configuration,
                                             leg, arm, kind, message))


def _stop_count(t: np.ndarray, q: np.ndarray) -> int:
    """Moving segments of distinct velocity, minus one (a rest or a turn is a stop)."""
    v = np.diff(q, axis=0) / np.diff(t)[:, None]
    moving = np.any(np.abs(np.diff(q, axis=0)) > _MOVE_EPS_RAD, axis=1)
    n, prev = 0, None
    for vi, m in zip(v, moving, strict=True):
        if not m:
            prev = None
            continue
        if prev is None or np.any(np.abs(vi - prev) > 1e-9 * max(1.0, float(np.abs(vi).max()))):
            n += 1
        prev = vi
    return max(n - 1, 0)


# -------------------------------------------------------------------- configurations


def _plane_targets(run: _Run, p: FilePointing) -> dict[str, np.ndarray]:
    """Each listed target's focal-plane position recomputed from its RA/Dec (a ``target``
    violation for a listed position that disagrees, or a list missing)."""
    if p.targets is None:
        run.add(p, "target", "the pointing lists no targets' RA/Dec: target positions cannot be re-checked")
        return {}
    if not p.targets:
        return {}
    ra = np.array([t.ra_deg for t in p.targets])
    dec = np.array([t.dec_deg for t in p.targets])
    try:
        x, y = sky_to_focal_mm(ra, dec, p.ra_deg % 360.0, p.dec_deg, run.inst.plate_scale_arcsec_per_mm,
                               p.position_angle_deg or 0.0)
    except InputError as exc:
        run.add(p, "target", f"targets cannot be projected about the pointing: {exc}")
        return {}
    out = {}
    for t, xi, yi in zip(p.targets, x, y, strict=True):
        out[t.id] = np.array([xi, yi])
        off = float(np.hypot(t.x_mm - xi, t.y_mm - yi))
        if off > POSITION_TOL_MM:
            run.add(p, "target", f"target {t.id}: listed at ({t.x_mm:.4f}, {t.y_mm:.4f}) mm, its RA/Dec "
                    f"project to ({xi:.4f}, {yi:.4f}) mm ({off:.4g} mm off)")
    missing = sorted(set(p.target_ids) - set(out))
    if missing:
        run.add(p, "target", f"targets {missing[:5]} of target_ids have no RA/Dec in the pointing's targets")
    return out


def _arms_once(run: _Run, p: FilePointing, ci: int, c: Configuration) -> bool:
    arms = [a.arm for a in c.assignments]
    if sorted(arms) != list(range(run.inst.n_arms)):
        run.add(p, "structure", f"assignments name arms {arms}, expected each of 0..{run.inst.n_arms - 1} once",
                configuration=ci)
        return False
    return True


def _check_tips(run: _Run, p: FilePointing, ci: int, c: Configuration, where: dict[str, np.ndarray]) -> None:
    """Forward kinematics against each assignment's position and its target's."""
    arms = np.array([a.arm for a in c.assignments])
    tips = tip_fov(run.inst, arms, np.array([a.theta1_rad for a in c.assignments]),
                   np.array([a.theta2_rad for a in c.assignments]))
    seen: dict[str, int] = {}
    ids = set(p.target_ids)
    for a, tip in zip(c.assignments, tips, strict=True):
        off = float(np.hypot(*(tip - (a.x_mm, a.y_mm))))
        if off > POSITION_TOL_MM:
            run.add(p, "geometry", f"arm {a.arm}: the joint angles put the tip at ({tip[0]:.4f}, {tip[1]:.4f}) mm, "
                    f"the assignment says ({a.x_mm:.4f}, {a.y_mm:.4f}) ({off:.4g} mm off)",
                    configuration=ci, arm=a.arm)
        if a.target_id is None:
            continue
        run.counts["targets"] += 1
        if a.target_id in seen:
            run.add(p, "structure", f"target {a.target_id} observed by arms {seen[a.target_id]} and {a.arm}",
                    configuration=ci, arm=a.arm)
        seen[a.target_id] = a.arm
        if a.target_id not in ids:
            run.add(p, "target", f"arm {a.arm}: target {a.target_id} is not one of the pointing's",
                    configuration=ci, arm=a.arm)
        elif a.target_id in where:
            off = float(np.hypot(*(tip - where[a.target_id])))
            if off > POSITION_TOL_MM:
                run.add(p, "target", f"arm {a.arm}: the tip is {off:.4g} mm from target {a.target_id}'s position "
                        "recomputed from its RA/Dec", configuration=ci, arm=a.arm)


def _at_rest(c: Configuration) -> list[ArmTrajectory]:
    zero = np.zeros(1)
    return [ArmTrajectory(a.arm, zero, np.array([a.theta1_rad]), np.array([a.theta2_rad])) for a in c.assignments]


def _check_configuration(run: _Run, p: FilePointing, ci: int, c: Configuration,
                         where: dict[str, np.ndarray]) -> bool:
    """Every check of configuration ``ci`` (counted from 1); False when its shape is wrong."""
    run.counts["configurations"] += 1
    run.counts["assignments"] += len(c.assignments)
    if not _arms_once(run, p, ci, c):
        return False
    c = Configuration(c.index, tuple(sorted(c.assignments, key=lambda a: a.arm)), c.total_priority,
                      c.arm_yield, c.status)
    _check_tips(run, p, ci, c, where)
    rep = verify_trajectories(run.inst, _at_rest(c), c.q, c.q, max_start_stop=None)
    for v in rep.violations:
        what = f"arms {v.arms[0]} and {v.arms[1]}: " if len(v.arms) == 2 else f"arm {v.arms[0]}: "
        run.add(p, v.kind, what + v.detail, configuration=ci, arm=v.arms[0] if v.arms else None)
    return True


# ------------------------------------------------------------------------- legs


def _check_commands(run: _Run, p: FilePointing, li: int, tr: ArmTrajectory) -> None:
    """One command per moving joint per way-point segment (the verifier matches each command
    to its segment; this catches a move with no command)."""
    q = np.column_stack([tr.theta1_rad, tr.theta2_rad])
    if len(q) < 2:
        moves = 0
    else:
        moves = int((np.abs(np.diff(q, axis=0)) > _MOVE_EPS_RAD).sum())
    if moves != len(tr.commands):
        run.add(p, "commands", f"arm {tr.arm}: {moves} joint moves in the way-points, {len(tr.commands)} commands",
                leg=li, arm=tr.arm)
        return
    t = np.asarray(tr.t_s, float)
    for c in tr.commands:
        i = np.flatnonzero(np.abs(t - c.t_start_s) < 1e-9)
        if len(i) == 0 or i[0] + 1 >= len(t):
            continue  # the verifier names a command off the way-points
        speed = abs(c.to_rad - c.from_rad) / (t[i[0] + 1] - t[i[0]])
        if abs(c.speed_rad_s - speed) > 1e-6 * max(1.0, speed):
            run.add(p, "commands", f"arm {tr.arm}: the joint {c.joint} command at t = {c.t_start_s:.3f} s "
                    f"runs at {c.speed_rad_s:.6g} rad/s, its way-points at {speed:.6g}", leg=li, arm=tr.arm)
            return


def allowed_stops(via_park: bool) -> int:
    """Start-stop cycles an arm may make on a leg: :data:`MAX_STOPS`, or on a leg through park
    (:func:`planner.sequence.via_park_leg`) those of its two halves and the rest at park."""
    return 2 * MAX_STOPS + 1 if via_park else MAX_STOPS


def _check_stops(run: _Run, p: FilePointing, li: int, leg: FileLeg, allowed: int) -> None:
    stops = []
    for tr in leg.trajectories:
        t = np.asarray(tr.t_s, float)
        if len(t) < 2 or np.any(np.diff(t) <= 0):
            stops.append(0)  # the verifier names a malformed trajectory
            continue
        n = _stop_count(t, np.column_stack([tr.theta1_rad, tr.theta2_rad]))
        stops.append(n)
        if n > allowed:
            run.add(p, "stops", f"arm {tr.arm}: {n} start-stop cycles > {allowed}", leg=li, arm=tr.arm)
    if leg.max_stops is not None and stops and leg.max_stops != max(stops):
        run.add(p, "stops", f"the leg reports max_stops {leg.max_stops}, its way-points stop {max(stops)} times",
                leg=li)


def _check_makespan(run: _Run, p: FilePointing, li: int, leg: FileLeg) -> None:
    ends = [float(tr.t_s[-1]) for tr in leg.trajectories if len(tr.t_s)]
    if leg.makespan_s is None or not ends:
        run.add(p, "makespan", "an executed leg needs a makespan_s and way-points", leg=li)
        return
    if abs(leg.makespan_s - max(ends)) > 1e-6:
        run.add(p, "makespan", f"makespan_s {leg.makespan_s:g} s, the way-points end at {max(ends):g} s", leg=li)


def _check_leg(run: _Run, p: FilePointing, li: int, leg: FileLeg, start_q: np.ndarray, goal_q: np.ndarray,
               via_park: bool) -> None:
    """Leg ``li`` (counted from 1) from ``start_q`` to ``goal_q`` with the verifier."""
    run.counts["legs"] += 1
    if leg.status != "ok":
        run.counts["legs_failed"] += 1
        return
    run.counts["trajectories"] += len(leg.trajectories)
    run.counts["waypoints"] += sum(len(tr.t_s) for tr in leg.trajectories)
    rep = verify_trajectories(run.inst, leg.trajectories, start_q, goal_q, max_start_stop=None,
                              dt_check_s=DT_CHECK_S)
    run.counts["samples"] += rep.n_samples
    run.counts["pair_samples"] += rep.pair_samples_checked
    for v in rep.violations:
        what = f"arms {v.arms[0]} and {v.arms[1]}" if len(v.arms) == 2 else f"arm {v.arms[0]}"
        run.add(p, v.kind, f"{what} at t = {v.t_s:.3f} s: {v.detail}", leg=li,
                arm=v.arms[0] if v.arms else None)
    if any(v.kind == "structure" for v in rep.violations):
        return
    for tr in leg.trajectories:
        _check_commands(run, p, li, tr)
    _check_stops(run, p, li, leg, allowed_stops(via_park))
    _check_makespan(run, p, li, leg)


# ---------------------------------------------------------------------- pointings


def _executable(p: FilePointing) -> bool:
    """Whether a pointing can be executed as it stands: every leg planned; a pointing the time
    limit left unplanned (``not_planned``) has nothing to execute when it has no
    configuration (its targets ``no_time``), and cannot be executed when it has any (their
    legs were not planned)."""
    if not p.planned:
        return not p.configurations
    return all(leg.status == "ok" for leg in p.legs)


def _check_pointing(run: _Run, p: FilePointing, via_park_legs: set[int], progress: Progress) -> None:
    run.counts["pointings"] += 1
    where = _plane_targets(run, p)
    park = run.inst.park_configuration
    qs = [park]
    for ci, c in enumerate(p.configurations, start=1):
        if not _check_configuration(run, p, ci, c, where):
            return
        qs.append(np.array([[a.theta1_rad, a.theta2_rad] for a in sorted(c.assignments, key=lambda a: a.arm)]))
    qs.append(park)
    if p.planned and len(p.legs) != len(p.configurations) + 1:
        run.add(p, "structure", f"{len(p.legs)} motion legs for {len(p.configurations)} configurations "
                f"(expected park -> c1 -> ... -> park: {len(p.configurations) + 1})")
        return
    for li, leg in enumerate(p.legs if p.planned else (), start=1):
        _check_leg(run, p, li, leg, qs[li - 1], qs[li], li in via_park_legs)
        progress(li / len(p.legs))
    all_ok = _executable(p)
    if p.executable != all_ok:
        run.add(p, "executable", f"the pointing says executable {str(p.executable).lower()}, its legs "
                + ("are all planned" if all_ok else "are not all planned"))


def validate_plan(inst: Instrument, plan: object, progress: Progress | None = None,
                  via_park: dict[str, set[int]] | None = None) -> ValidationReport:
    """Re-check a parsed plan JSON (see the module doc). ``via_park``: per pointing id, the legs
    (counted from 1) the plan sends through park (read from its ``changes`` when None).
    ``progress`` hears the fraction done after each leg (it may raise to stop). InputError
    naming the field when the JSON does not have a plan's shape."""
    pf: PlanFile = read_plan(plan)
    if via_park is None:
        via_park = via_park_legs(plan)
    run = _Run(inst)
    hash_ok = pf.content_hash == pf.computed_hash
    if pf.content_hash is None:
        run.add(None, "hash", "the plan has no content_hash")
    elif not hash_ok:
        run.add(None, "hash", f"content_hash {pf.content_hash[:80]} does not match the content "
                f"({pf.computed_hash}): the plan was edited after it was written")
    n = max(len(pf.pointings), 1)
    for i, p in enumerate(pf.pointings):
        _check_pointing(run, p, via_park.get(p.id, set()),
                        lambda f, i=i: None if progress is None else progress((i + f) / n))
    executable = all(_executable(p) for p in pf.pointings)
    if pf.executable != executable:
        run.add(None, "executable", f"the plan says executable {str(pf.executable).lower()}, its pointings "
                + ("are all executable" if executable else "are not all executable"))
    vio = run.violations
    return ValidationReport(not vio, hash_ok, executable and pf.executable, tuple(vio[:MAX_LISTED]),
                            len(vio), dict(run.counts))


def via_park_legs(plan: object) -> dict[str, set[int]]:
    """Per pointing id, the legs (counted from 1) its ``changes`` send through park."""
    out: dict[str, set[int]] = {}
    if not isinstance(plan, dict):
        return out
    for p in plan.get("pointings") or []:
        if not isinstance(p, dict):
            continue
        for ch in p.get("changes") or []:
            if isinstance(ch, dict) and ch.get("kind") == "via_park" and isinstance(ch.get("leg"), int):
                out.setdefault(str(p.get("id")), set()).add(ch["leg"] + 1)
    return out
