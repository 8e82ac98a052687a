"""The planner driver and its strategy interface: one verification per candidate, unsafe
candidates never "ok", time-reversed legs, validated options, module boundaries."""

from __future__ import annotations

import ast
import pathlib

import numpy as np
import pytest

import planner.driver as driver
from models.budget import Budget
from models.errors import InputError
from models.instrument import default_instrument
from models.types import ArmTrajectory
from planner import MotionOptions, plan_motion, verify_trajectories
from planner.registry import STRATEGIES
from planner.strategies.reversed import reverse_trajectories
from planner.strategy import Candidate, Leg, Refusal
from tests.test_planner import _en_route

INST = default_instrument()
PARK = INST.park_configuration
V = INST.max_joint_speed_rad_s
TWO_PI = 2 * np.pi
GOAL_CONFLICT = [[3.0136971541900013, 0.18301607390023514], [1.928770938121543, 2.7180407071074124]]


def _two_arm():
    inst = INST.with_arms_disabled(list(range(2, 12)))
    goal = PARK.copy()
    goal[[0, 1]] = GOAL_CONFLICT
    return inst, goal




class Unsafe:
    """Every arm straight to its goal at full speed, all departing together (they collide)."""

    name = "unsafe-straight"

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        trajs = []
        for k in range(leg.n_arms):
            q0, q1 = leg.start_q[k], leg.goal_q[k].copy()
            d = q1 - q0
            d[1] = (d[1] + np.pi) % TWO_PI - np.pi
            T = float(np.abs(d).max() / V)
            if T == 0:
                trajs.append(ArmTrajectory(k, np.array([0.0]), q0[:1].copy(), q0[1:].copy()))
            else:
                trajs.append(ArmTrajectory(k, np.array([0.0, T]), np.array([q0[0], q0[0] + d[0]]),
                                           np.array([q0[1], q0[1] + d[1]])))
        return Candidate(tuple(trajs), max(float(t.t_s[-1]) for t in trajs), self.name, {})


class Counting:
    """Wraps a strategy, counting the candidates it returns."""

    def __init__(self, inner, counter: dict) -> None:
        self.inner, self.name, self.counter = inner, inner.name, counter

    def plan(self, leg, budget):
        out = self.inner.plan(leg, budget)
        if isinstance(out, Candidate):
            self.counter["candidates"] += 1
        return out


class Refusing:
    """Refuses every leg, recording that it was asked."""

    def __init__(self, name: str, calls: list) -> None:
        self.name, self.calls = name, calls

    def plan(self, leg, budget):
        self.calls.append(self.name)
        return Refusal()


def test_evasion_goes_before_sequenced_on_legs_from_park_only(monkeypatch):
    calls: list[str] = []
    for name in ("delays", "sequenced", "evasion", "detours"):
        monkeypatch.setitem(STRATEGIES, name, Refusing(name, calls))
    inst, goal = _two_arm()
    opts = {"strategies": ("delays", "sequenced", "evasion"), "time_budget_s": 5.0}
    assert plan_motion(inst, PARK, goal, **opts).status == "failed"
    assert calls == ["delays", "evasion", "sequenced", "detours"]
    calls.clear()
    assert plan_motion(inst, goal, PARK, **opts).status == "failed"
    assert calls == ["delays", "sequenced", "evasion", "detours"]


@pytest.fixture
def counted(monkeypatch):
    """verify_trajectories calls of the driver, and candidates of every registered strategy."""
    counter = {"verify": 0, "candidates": 0}
    real = driver.verify_trajectories

    def verify(*args, **kwargs):
        counter["verify"] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(driver, "verify_trajectories", verify)
    monkeypatch.setitem(STRATEGIES, Unsafe.name, Unsafe())
    for name, s in list(STRATEGIES.items()):
        monkeypatch.setitem(STRATEGIES, name, Counting(s, counter))
    return counter


def test_unsafe_candidate_is_never_ok(counted):
    inst, goal = _two_arm()
    plan = plan_motion(inst, PARK, goal, strategies=(Unsafe.name,), via=None)
    assert plan.status == "failed" and {0, 1} <= set(plan.failed_arms)
    assert plan.stats["reasons"][0].startswith("verification failed")
    assert counted == {"verify": 1, "candidates": 1}
    assert plan.stats["attempt_log"][-1]["verified"] is False


def test_rejected_candidate_then_the_next_strategy(counted):
    inst, start, goal = _en_route()
    via = start.copy()  # arm 0 80 % of the way, arm 3 20 %: collision-free (tests/test_planner_delays.py)
    via[0] += 0.8 * (goal[0] - start[0])
    via[3] += 0.2 * (goal[3] - start[3])
    plan = plan_motion(inst, start, goal, strategies=(Unsafe.name, "via"), via=via)
    assert plan.status == "ok" and plan.stats["strategy"] == "via"
    assert verify_trajectories(inst, plan.trajectories, start, goal, exhaustive=True).ok
    assert counted == {"verify": 2, "candidates": 2}
    assert [e.get("verified") for e in plan.stats["attempt_log"]] == [False, True]


@pytest.mark.parametrize("kw", [{}, {"strategies": ("forward", "reverse")}])
def test_one_verification_per_candidate(counted, kw):
    inst, goal = _two_arm()
    plan = plan_motion(inst, PARK, goal, **kw)
    assert plan.status == "ok"
    assert counted["verify"] == counted["candidates"] >= 1


def test_reversal_of_a_plan_from_park_is_a_plan_to_park():
    inst, c = _two_arm()
    out = plan_motion(inst, PARK, c)
    assert out.status == "ok"
    end = np.array([[tr.theta1_rad[-1], tr.theta2_rad[-1]] for tr in out.trajectories])  # c, theta2 unwrapped
    back = reverse_trajectories(out.trajectories, end, out.makespan_s)
    rep = verify_trajectories(inst, back, end, PARK, exhaustive=True)
    assert rep.ok, rep.violations[:3]
    assert rep.min_clearance_mm == pytest.approx(
        verify_trajectories(inst, out.trajectories, PARK, c, exhaustive=True).min_clearance_mm)
    for tr in back:
        assert tr.t_s[0] == 0.0 and tr.t_s[-1] <= out.makespan_s + 1e-9
        assert tr.theta1_rad[-1] == PARK[tr.arm, 0] and tr.theta2_rad[-1] == PARK[tr.arm, 1]  # exactly park
        assert tr.theta1_rad[0] == end[tr.arm, 0] and tr.theta2_rad[0] == end[tr.arm, 1]
    # a start given modulo 2 pi (here one turn more on arm 0): the plan starts there exactly
    turned = end.copy()
    turned[0, 1] += TWO_PI
    back2 = reverse_trajectories(out.trajectories, turned, out.makespan_s)
    assert back2[0].theta2_rad[0] == pytest.approx(turned[0, 1], abs=1e-12)
    assert verify_trajectories(inst, back2, turned, PARK).ok


def test_reversed_strategy_plans_a_leg_to_park():
    inst, c = _two_arm()
    plan = plan_motion(inst, c, PARK, strategies=("reversed",), via=None)
    assert plan.status == "ok" and plan.stats["strategy"] == "reversed"
    assert verify_trajectories(inst, plan.trajectories, c, PARK, exhaustive=True).ok
    for tr in plan.trajectories:
        assert tr.theta1_rad[0] == c[tr.arm, 0] and tr.theta2_rad[0] == pytest.approx(c[tr.arm, 1], abs=1e-12)
        assert np.cos(tr.theta2_rad[-1]) == pytest.approx(np.cos(PARK[tr.arm, 1]), abs=1e-12)


@pytest.mark.parametrize("field,kw,message", [
    ("dt_s", {"dt_s": 0.0}, "dt_s and dt_col_s must be positive"),
    ("dt_s", {"dt_col_s": float("nan")}, "dt_s and dt_col_s must be positive"),
    ("dt_col_s", {"dt_col_s": 0.07}, "must divide dt_s into a whole number of collision steps"),
    ("max_start_stop", {"max_start_stop": -1}, "must be >= 0"),
    ("horizon_s", {"horizon_s": -5.0}, None),
    ("max_attempts", {"max_attempts": 1.5}, None),
    ("grid", {"grid": (0, 6)}, None),
    ("strategies", {"strategies": ("delays", "teleport")}, "teleport"),
    ("collision_buffer_mm", {"collision_buffer_mm": -1.0}, None),
    ("turn_sense", {"turn_sense": 0}, None),
    ("via", {"via": "somewhere"}, None),
    ("via", {"via": np.zeros(3)}, None),
])
def test_motion_options_reject_bad_values_naming_the_field(field, kw, message):
    with pytest.raises(InputError) as e:
        MotionOptions(**kw)
    assert e.value.field == field
    if message:
        assert message in e.value.message
    with pytest.raises(InputError) as e2:  # the same through the public keywords
        plan_motion(INST, PARK, PARK, **kw)
    assert e2.value.field == field


def test_motion_options_defaults_and_explicit_options():
    o = MotionOptions()
    assert (o.dt_s, o.dt_col_s, o.max_start_stop, o.horizon_s, o.grid, o.via) == (6.0, 0.1, 1, 220.0, (8, 6), "park")
    assert o.strategies == ("delays", "sequenced", "evasion", "cluster", "forward", "reverse") and o.collision_steps == 60
    inst, goal = _two_arm()
    a = plan_motion(inst, PARK, goal, seed=2, max_start_stop=0)
    b = plan_motion(inst, PARK, goal, options=MotionOptions(seed=2, max_start_stop=0))
    assert a.status == b.status and a.failed_arms == b.failed_arms


def _planner_imports() -> dict[str, set[str]]:
    root = pathlib.Path(driver.__file__).parent
    out = {}
    for f in root.rglob("*.py"):
        mods = set()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                mods.add(node.module)
            elif isinstance(node, ast.Import):
                mods.update(a.name for a in node.names)
        out[str(f.relative_to(root))] = mods
    return out


def test_only_the_driver_imports_the_verifier():
    imports = _planner_imports()
    users = {f for f, mods in imports.items() if "planner.verify" in mods}
    assert users <= {"driver.py", "__init__.py", "validate.py"}
    # the plan-file re-check (validate.py) reads the file and calls the verifier, nothing of
    # the planner's search
    assert {m for m in imports["validate.py"] if m.startswith("planner")} <= {"planner.plan_file", "planner.verify"}
    assert not {m for m in imports["verify.py"] if m.startswith("planner")}
    # no strategy goes back through the public entry point
    for f, mods in imports.items():
        if f.startswith("strategies"):
            assert "planner.driver" not in mods and "planner" not in mods, f


THIN = [[1.5068486993930823, 2.592683017496547], [1.3948972100113546, 2.6121715572481228]]


@pytest.mark.parametrize("case", ["goal_conflict", "thin", "en_route", "planned"])
def test_planner_recheck_agrees_with_the_verifier(case):
    """planner.geometry.timed_collisions, the strategies' own re-check, finds the colliding
    pairs the verifier finds (straight simultaneous moves, a thin en-route crossing, a plan)."""
    from planner.geometry import ArmGeom, timed_collisions

    if case == "en_route":
        inst, start, goal = _en_route()
    else:
        inst, goal = _two_arm()
        if case == "thin":
            goal[[0, 1]] = THIN
        start = PARK
    leg = Leg.build(inst, start, goal, MotionOptions())
    trajs = plan_motion(inst, start, goal).trajectories if case == "planned" else \
        Unsafe().plan(leg, Budget.start(1.0)).trajectories
    rep = verify_trajectories(inst, trajs, start, goal, max_start_stop=None)
    expected = sorted(v.arms for v in rep.violations if v.kind == "collision")
    timed = [(tr.t_s, np.column_stack([tr.theta1_rad, tr.theta2_rad])) for tr in trajs]
    found = timed_collisions([ArmGeom.of(inst, k) for k in range(12)], timed, leg.buffer_mm)
    assert sorted(found) == expected
    assert bool(expected) == (case != "planned")


@pytest.mark.parametrize("kw, field", [({"dt_col_s": 1e-4}, "dt_col_s"), ({"dt_s": 1e-3, "dt_col_s": 1e-3}, "dt_s"),
                                       ({"dt_s": 0.6, "dt_col_s": 0.01}, "dt_col_s")])
def test_sampling_is_bounded(kw, field):
    """Steps small enough to exhaust memory (1e-4 s took a server past 6 GB) are refused."""
    with pytest.raises(InputError) as e:
        MotionOptions(**kw)
    assert e.value.field == field


def _one_arm_move(leg: Leg, rest_s: float) -> tuple[ArmTrajectory, ...]:
    """Arm 0 straight to its goal at full speed, resting ``rest_s`` halfway (0: no rest); the
    other arms (disabled) stay."""
    q0, q1 = leg.start_q[0], leg.goal_q[0].copy()
    d = q1 - q0
    d[1] = (d[1] + np.pi) % TWO_PI - np.pi
    T = float(np.abs(d).max() / V)
    if rest_s > 0:
        t = np.array([0.0, T / 2, T / 2 + rest_s, T + rest_s])
        q = np.array([q0, q0 + d / 2, q0 + d / 2, q0 + d])
    else:
        t, q = np.array([0.0, T]), np.array([q0, q0 + d])
    trajs = [ArmTrajectory(0, t, q[:, 0].copy(), q[:, 1].copy())]
    trajs += [ArmTrajectory(k, np.array([0.0]), leg.start_q[k, :1].copy(), leg.start_q[k, 1:].copy())
              for k in range(1, leg.n_arms)]
    return tuple(trajs)


class Resting:
    """Arm 0 to its goal with a rest halfway: one start-stop cycle, as its stats say."""

    name = "resting"

    def plan(self, leg: Leg, budget: Budget) -> Candidate:
        trajs = _one_arm_move(leg, rest_s=30.0)
        return Candidate(trajs, float(trajs[0].t_s[-1]), self.name, {"max_stops": 1})


class Straight:
    """Arm 0 straight to its goal: no stop; its stats say nothing of stops."""

    name = "straight"

    def plan(self, leg: Leg, budget: Budget) -> Candidate:
        trajs = _one_arm_move(leg, rest_s=0.0)
        return Candidate(trajs, float(trajs[0].t_s[-1]), self.name, {})


def test_a_shorter_plan_reports_its_own_stops(monkeypatch):
    """A shorter search's plan replaces the first candidate: the leg's ``max_stops`` is the
    count of the trajectories returned (what ``mxs-planner validate`` recounts), not the
    first strategy's."""
    inst = INST.with_arms_disabled(list(range(1, 12)))
    goal = PARK.copy()
    goal[0] = GOAL_CONFLICT[0]
    leg = Leg.build(inst, PARK, goal, MotionOptions())
    monkeypatch.setattr(driver, "_shorter_searches", lambda leg, strategy: [(Straight(), 0.0)])
    plan = driver.plan_leg(leg, Budget.start(10.0), sequence=[Resting()])
    assert plan.status == "ok"
    assert plan.stats["shorter_search"][0]["strategy"] == "straight"
    assert plan.makespan_s == pytest.approx(float(Straight().plan(leg, Budget.start(1.0)).makespan_s))
    from planner.validate import _stop_count

    counted = max(_stop_count(t.t_s, np.column_stack([t.theta1_rad, t.theta2_rad]))
                  for t in plan.trajectories if len(t.t_s) > 1)
    assert counted == 0
    assert plan.stats["max_stops"] == counted


def test_a_leg_reports_the_stops_of_its_trajectories(monkeypatch):
    """Without a shorter search the first candidate is kept, and so are its stops."""
    inst = INST.with_arms_disabled(list(range(1, 12)))
    goal = PARK.copy()
    goal[0] = GOAL_CONFLICT[0]
    leg = Leg.build(inst, PARK, goal, MotionOptions())
    monkeypatch.setattr(driver, "_shorter_searches", lambda leg, strategy: [])
    plan = driver.plan_leg(leg, Budget.start(10.0), sequence=[Resting()])
    assert plan.status == "ok"
    assert plan.stats["max_stops"] == 1
