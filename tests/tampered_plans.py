"""A corpus of tampered plans generated from one real plan (issue 39 item 5).

Each :class:`Tamper` plants one defect in a copy of the plan and names the violation kind
the validator must report for it. Except for the tampers aimed at the hash itself, the
content hash is recomputed after the edit, so only the geometric and structural checks can
catch the defect. The edits are made with the models (forward kinematics, the collision
model's clearance), never with the validator.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from models.collision import arm_pair_clearance_mm
from models.instrument import Instrument
from models.kinematics import Links, d34_mm, tip_fov
from planner.plan_file import HASH_FIELD, content_hash

Plan = dict[str, Any]
REST_S = 1e-3  # a rest short enough not to change the clearances


@dataclass(frozen=True)
class Tamper:
    name: str
    kind: str  # the violation kind the validator must report
    edit: Callable[[Plan, Instrument], None]  # edits the plan in place
    rehash: bool = True


# --------------------------------------------------------------------------- finding


def _pointing(plan: Plan) -> dict[str, Any]:
    """The first pointing with at least two configurations and every leg planned."""
    for p in plan["pointings"]:
        if len(p["configurations"]) >= 2 and all(m["status"] == "ok" for m in p["motions"]):
            return p
    raise ValueError("the plan has no executable pointing with two configurations")


def _observing(p: dict[str, Any], n: int = 2) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A configuration with at least ``n`` observing arms, and those assignments."""
    for c in p["configurations"]:
        obs = [a for a in c["assignments"] if a["target_id"] is not None]
        if len(obs) >= n:
            return c, obs
    raise ValueError("no configuration observes enough targets")


def _moving_in(p: dict[str, Any], leg: int = 0, points: int = 3) -> tuple[dict[str, Any], dict[str, Any]]:
    """A motion leg and one of its trajectories with at least ``points`` way-points that moves
    on its first segment: in leg ``leg`` when it has one, else in the first leg that has; when
    no trajectory moves on its first segment (every arm waits before it moves), the first that
    moves on any."""
    motions = p["motions"]
    for first in (True, False):
        for m in [motions[leg]] + motions:
            for tr in m["trajectories"]:
                w = tr["waypoints"]
                segments = list(zip(w, w[1:], strict=False))
                if len(w) >= points and any(_moves(a, b) for a, b in (segments[:1] if first else segments)):
                    return m, tr
    raise ValueError(f"no leg has a trajectory with {points} way-points that moves")


def _moves(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Whether a joint moves between way-points ``a`` and ``b``."""
    return any(abs(b[k] - a[k]) > 1e-6 for k in ("theta1_rad", "theta2_rad"))


def _moving(p: dict[str, Any], leg: int = 0, points: int = 3) -> dict[str, Any]:
    """The trajectory of :func:`_moving_in`."""
    return _moving_in(p, leg, points)[1]


def _set_joints(inst: Instrument, a: dict[str, Any], t1: float, t2: float) -> None:
    """Assignment ``a`` at (t1, t2) with its position moved to the tip there."""
    tip = tip_fov(inst, a["arm"], t1, t2)
    a.update(theta1_rad=float(t1), theta2_rad=float(t2), x_mm=float(tip[0]), y_mm=float(tip[1]),
             target_id=None, kind="blank")


def _commands(wps: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One command per moving joint per way-point segment."""
    out = []
    for w0, w1 in zip(wps, wps[1:], strict=False):
        dur = w1["t_s"] - w0["t_s"]
        for j, key in ((1, "theta1_rad"), (2, "theta2_rad")):
            if abs(w1[key] - w0[key]) > 1e-12:
                out.append({"joint": j, "t_start_s": w0["t_s"], "from_rad": w0[key], "to_rad": w1[key],
                            "speed_rad_s": abs(w1[key] - w0[key]) / dur})
    return out


# ---------------------------------------------------------------------------- edits


def swap_arms(plan: Plan, inst: Instrument) -> None:
    _, obs = _observing(_pointing(plan))
    obs[0]["arm"], obs[1]["arm"] = obs[1]["arm"], obs[0]["arm"]


def swap_targets(plan: Plan, inst: Instrument) -> None:
    _, obs = _observing(_pointing(plan))
    obs[0]["target_id"], obs[1]["target_id"] = obs[1]["target_id"], obs[0]["target_id"]


def move_assignment(plan: Plan, inst: Instrument) -> None:
    _observing(_pointing(plan), 1)[1][0]["x_mm"] += 0.5


def move_target_listed(plan: Plan, inst: Instrument) -> None:
    p = _pointing(plan)
    observed = _observing(p, 1)[1][0]["target_id"]
    t = next(t for t in p["targets"] if t["id"] == observed)
    t["y_mm"] += 0.2


def target_ra(plan: Plan, inst: Instrument) -> None:
    p = _pointing(plan)
    observed = _observing(p, 1)[1][0]["target_id"]
    t = next(t for t in p["targets"] if t["id"] == observed)
    t["ra_deg"] += 1.0 / 3600.0  # 1 arcsec, 0.83 mm at 1.2 arcsec/mm


def pointing_centre(plan: Plan, inst: Instrument) -> None:
    _pointing(plan)["dec_deg"] += 0.5 / 3600.0


def position_angle(plan: Plan, inst: Instrument) -> None:
    p = _pointing(plan)
    p["position_angle_deg"] = float(p.get("position_angle_deg") or 0.0) + 1.0


def foreign_target(plan: Plan, inst: Instrument) -> None:
    _observing(_pointing(plan), 1)[1][0]["target_id"] = "not-a-target-of-this-pointing"


def twice_observed(plan: Plan, inst: Instrument) -> None:
    _, obs = _observing(_pointing(plan))
    obs[1]["target_id"] = obs[0]["target_id"]


def joint_beyond_limit(plan: Plan, inst: Instrument) -> None:
    a = _observing(_pointing(plan), 1)[1][0]
    _set_joints(inst, a, inst.arms[a["arm"]].theta1_min_rad - 0.3, a["theta2_rad"])


def into_zoa(plan: Plan, inst: Instrument) -> None:
    a = _observing(_pointing(plan), 1)[1][0]
    lk = Links.of(inst, a["arm"])
    t2 = np.linspace(0.0, 2 * np.pi, 721)
    d = d34_mm(a["theta1_rad"], t2, lk)
    bad = t2[(d <= lk.stop_min_mm) | (d >= lk.stop_max_mm)]
    _set_joints(inst, a, a["theta1_rad"], float(bad[0]))


def colliding_configuration(plan: Plan, inst: Instrument) -> None:
    """Arm k+1 of a configuration moved (within its limits, out of the ZoA) onto arm k."""
    c, obs = _observing(_pointing(plan), 1)
    k = obs[0]["arm"]
    q = {a["arm"]: (a["theta1_rad"], a["theta2_rad"]) for a in c["assignments"]}
    other = (k + 1) % inst.n_arms
    lk = Links.of(inst, other)
    for t1 in np.linspace(0.05, np.pi - 0.05, 40):
        for t2 in np.linspace(0.0, 2 * np.pi, 72, endpoint=False):
            d = float(d34_mm(t1, t2, lk))
            if not lk.stop_min_mm + 1 < d < lk.stop_max_mm - 1:
                continue
            clear = float(arm_pair_clearance_mm(inst, k, np.array(q[k]), other, np.array([t1, t2])))
            if clear < inst.collision_buffer_mm - 1.0:
                _set_joints(inst, next(a for a in c["assignments"] if a["arm"] == other), t1, t2)
                return
    raise ValueError("no colliding position found")


def waypoint_moved(plan: Plan, inst: Instrument) -> None:
    tr = _moving(_pointing(plan))
    tr["waypoints"][1]["theta2_rad"] += 0.05


def waypoint_removed(plan: Plan, inst: Instrument) -> None:
    tr = _moving(_pointing(plan))
    del tr["waypoints"][1]


def leg_ends_elsewhere(plan: Plan, inst: Instrument) -> None:
    tr = _moving(_pointing(plan), 0, 2)
    tr["waypoints"][-1]["theta2_rad"] += 0.01
    tr["commands"] = _commands(tr["waypoints"])


def leg_starts_elsewhere(plan: Plan, inst: Instrument) -> None:
    tr = _moving(_pointing(plan), 1, 2)
    tr["waypoints"][0]["theta1_rad"] -= 0.01
    tr["commands"] = _commands(tr["waypoints"])


def too_fast(plan: Plan, inst: Instrument) -> None:
    """An arm's leg run faster: its way-point times scaled so that its fastest joint moves
    at 1.5 x the instrument's speed."""
    tr = _moving(_pointing(plan), 0, 2)
    wps, arm = tr["waypoints"], inst.arms[tr["arm"]]
    ratio = max(abs(w1[k] - w0[k]) / (w1["t_s"] - w0["t_s"]) / v
                for w0, w1 in zip(wps, wps[1:], strict=False)
                for k, v in (("theta1_rad", arm.joint1_speed_rad_s), ("theta2_rad", arm.joint2_speed_rad_s)))
    for w in wps:
        w["t_s"] *= ratio / 1.5
    tr["commands"] = _commands(tr["waypoints"])


def trajectory_beyond_limit(plan: Plan, inst: Instrument) -> None:
    """A mid-way point of a move pushed past theta1's upper limit (the move is slow enough)."""
    tr = _moving(_pointing(plan), 0, 2)
    w0, w1 = tr["waypoints"][0], tr["waypoints"][1]
    mid = {"t_s": w0["t_s"] + 0.5 * (w1["t_s"] - w0["t_s"]), "theta1_rad": inst.arms[tr["arm"]].theta1_max_rad + 0.02,
           "theta2_rad": 0.5 * (w0["theta2_rad"] + w1["theta2_rad"])}
    if mid["t_s"] - w0["t_s"] < 30.0:  # keep the speed within the limit: only the limit is broken
        shift = 30.0 - (mid["t_s"] - w0["t_s"])
        for w in tr["waypoints"][1:]:
            w["t_s"] += 2 * shift
        mid["t_s"] += shift
    tr["waypoints"].insert(1, mid)
    tr["commands"] = _commands(tr["waypoints"])


def trajectory_missing(plan: Plan, inst: Instrument) -> None:
    del _pointing(plan)["motions"][0]["trajectories"][3]


def trajectory_twice(plan: Plan, inst: Instrument) -> None:
    trs = _pointing(plan)["motions"][0]["trajectories"]
    trs[3] = copy.deepcopy(trs[2])


def command_removed(plan: Plan, inst: Instrument) -> None:
    tr = _moving(_pointing(plan), 0, 2)
    del tr["commands"][0]


def command_edited(plan: Plan, inst: Instrument) -> None:
    tr = _moving(_pointing(plan), 0, 2)
    tr["commands"][0]["to_rad"] += 0.1


def extra_stop(plan: Plan, inst: Instrument) -> None:
    """An arm rests 1 ms at a third and at two thirds of its first move: two more stops."""
    m, tr = _moving_in(_pointing(plan), 0, 2)
    w0, w1 = tr["waypoints"][0], tr["waypoints"][1]
    points = []
    for i, f in enumerate((1 / 3, 2 / 3)):
        at = {k: w0[k] + f * (w1[k] - w0[k]) for k in ("theta1_rad", "theta2_rad")}
        t = w0["t_s"] + f * (w1["t_s"] - w0["t_s"]) + i * REST_S
        points += [{"t_s": t, **at}, {"t_s": t + REST_S, **at}]
    for w in tr["waypoints"][1:]:
        w["t_s"] += 2 * REST_S
    tr["waypoints"][1:1] = points
    tr["commands"] = _commands(tr["waypoints"])
    m["makespan_s"] = max(t["waypoints"][-1]["t_s"] for t in m["trajectories"])
    m.get("stats", {}).pop("max_stops", None)


def makespan_edited(plan: Plan, inst: Instrument) -> None:
    _pointing(plan)["motions"][0]["makespan_s"] -= 10.0


def configuration_removed(plan: Plan, inst: Instrument) -> None:
    del _pointing(plan)["configurations"][1]


def leg_status_failed(plan: Plan, inst: Instrument) -> None:
    _pointing(plan)["motions"][0]["status"] = "failed"


def pointing_not_executable(plan: Plan, inst: Instrument) -> None:
    _pointing(plan)["executable"] = False


def number_edited_hash_left(plan: Plan, inst: Instrument) -> None:
    _moving(_pointing(plan))["waypoints"][1]["t_s"] += 1e-6


def stats_edited_hash_left(plan: Plan, inst: Instrument) -> None:
    plan["stats"]["configurations"] = int(plan["stats"]["configurations"]) + 1


def hash_edited(plan: Plan, inst: Instrument) -> None:
    h = plan[HASH_FIELD]
    plan[HASH_FIELD] = h[:-1] + ("0" if h[-1] != "0" else "1")


def hash_removed(plan: Plan, inst: Instrument) -> None:
    del plan[HASH_FIELD]


TAMPERS: tuple[Tamper, ...] = (
    Tamper("swap_arms", "geometry", swap_arms),
    Tamper("swap_targets", "target", swap_targets),
    Tamper("move_assignment", "geometry", move_assignment),
    Tamper("move_target_listed", "target", move_target_listed),
    Tamper("target_ra", "target", target_ra),
    Tamper("pointing_centre", "target", pointing_centre),
    Tamper("position_angle", "target", position_angle),
    Tamper("foreign_target", "target", foreign_target),
    Tamper("twice_observed", "structure", twice_observed),
    Tamper("joint_beyond_limit", "joint_limit", joint_beyond_limit),
    Tamper("into_zoa", "zoa", into_zoa),
    Tamper("colliding_configuration", "collision", colliding_configuration),
    Tamper("waypoint_moved", "commands", waypoint_moved),
    Tamper("waypoint_removed", "commands", waypoint_removed),
    Tamper("leg_ends_elsewhere", "goal", leg_ends_elsewhere),
    Tamper("leg_starts_elsewhere", "start", leg_starts_elsewhere),
    Tamper("too_fast", "speed", too_fast),
    Tamper("trajectory_beyond_limit", "joint_limit", trajectory_beyond_limit),
    Tamper("trajectory_missing", "structure", trajectory_missing),
    Tamper("trajectory_twice", "structure", trajectory_twice),
    Tamper("command_removed", "commands", command_removed),
    Tamper("command_edited", "commands", command_edited),
    Tamper("extra_stop", "stops", extra_stop),
    Tamper("makespan_edited", "makespan", makespan_edited),
    Tamper("configuration_removed", "structure", configuration_removed),
    Tamper("leg_status_failed", "executable", leg_status_failed),
    Tamper("pointing_not_executable", "executable", pointing_not_executable),
    Tamper("number_edited_hash_left", "hash", number_edited_hash_left, rehash=False),
    Tamper("stats_edited_hash_left", "hash", stats_edited_hash_left, rehash=False),
    Tamper("hash_edited", "hash", hash_edited, rehash=False),
    Tamper("hash_removed", "hash", hash_removed, rehash=False),
)


def tampered(plan: Plan, inst: Instrument, tamper: Tamper) -> Plan:
    """A copy of ``plan`` with ``tamper``'s defect (hash recomputed unless the tamper is the
    hash's)."""
    out = copy.deepcopy(plan)
    tamper.edit(out, inst)
    if tamper.rehash:
        out[HASH_FIELD] = content_hash(out)
    return out


def corpus(plan: Plan, inst: Instrument) -> Iterator[tuple[Tamper, Plan]]:
    """Every tamper of :data:`TAMPERS` applied to ``plan``."""
    for t in TAMPERS:
        yield t, tampered(plan, inst, t)
