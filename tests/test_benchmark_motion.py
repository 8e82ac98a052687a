"""benchmarks/motion.py: the thesis 6.4.2 protocol plans the allocator's own configurations."""

from __future__ import annotations

import json
import types

import numpy as np

from benchmarks import motion
from models.instrument import default_instrument
from models.types import ArmTrajectory, MotionPlan
from planner.sequence import PlanChange, SequenceOptions, SequencePlan
from service.schemas import PlanRequest

INST = default_instrument()
PARK_Q = INST.park_configuration


class AllocateRecorder:
    """Wraps the real allocator: records every call and the result it returned."""

    def __init__(self, real):
        self.real = real
        self.calls: list[dict] = []

    def __call__(self, instrument, targets, *, method, solver, configurations, time_limit_s, seed, options):
        result = self.real(instrument, targets, method=method, solver=solver,
                           configurations=configurations, time_limit_s=time_limit_s, seed=seed, options=options)
        options = {"method": method, "solver": solver, "configurations": configurations,
                   "park_move_limit_s": options.sequence.park_move_limit_s}
        self.calls.append({"options": options, "n_targets": len(targets.ids), "result": result})
        return result


class PlanMotionRecorder:
    """A cheap stand-in for plan_motion: straight 1 s moves, always "ok"."""

    def __init__(self):
        self.legs: list[tuple[np.ndarray, np.ndarray]] = []

    def __call__(self, instrument, start_q, goal_q, *, seed, time_budget_s):
        start_q, goal_q = np.array(start_q, float), np.array(goal_q, float)
        self.legs.append((start_q, goal_q))
        trajectories = tuple(
            ArmTrajectory(k, np.array([0.0, 1.0]), np.array([start_q[k, 0], goal_q[k, 0]]),
                          np.array([start_q[k, 1], goal_q[k, 1]]))
            for k in range(instrument.n_arms))
        return MotionPlan("ok", 1.0, trajectories, (), {"lower_bound_s": 1.0, "strategy": "fake"})


def run_with_recorders(monkeypatch, argv: list[str]) -> tuple[dict, AllocateRecorder,
                                                               PlanMotionRecorder]:
    alloc = AllocateRecorder(motion.allocate)
    plan = PlanMotionRecorder()
    monkeypatch.setattr(motion, "allocate", alloc)
    monkeypatch.setattr(motion, "plan_motion", plan)
    monkeypatch.setattr(motion, "sequence_module", types.SimpleNamespace())  # no plan_sequence
    return motion.main(argv), alloc, plan


def expected_legs(calls: list[dict], max_configurations: int | None) -> list[tuple[np.ndarray | None, np.ndarray]]:
    """(start or None for "where the previous leg ended", goal) of every leg the benchmark must
    plan: the chain park -> c1 -> ... -> cn -> park, then park -> c_i for i >= 2."""
    legs: list[tuple[np.ndarray | None, np.ndarray]] = []
    for call in calls:
        qs = [c.q for c in call["result"].configurations[:max_configurations]]
        legs += [(PARK_Q, qs[0])] + [(None, q) for q in qs[1:] + [PARK_Q]]
        legs += [(PARK_Q, q) for q in qs[1:]]
    return legs


def test_thesis_protocol_plans_the_allocators_configurations(monkeypatch):
    out, alloc, plan = run_with_recorders(
        monkeypatch, ["--fields", "2", "--targets", "30", "--methods", "ilp,semigreedy",
                      "--alloc-time-limit", "10"])
    assert [c["options"]["method"] for c in alloc.calls] == ["ilp", "ilp", "semigreedy", "semigreedy"]
    assert all(c["options"]["configurations"] == "all" for c in alloc.calls)
    assert all(c["options"]["solver"] == "bnb" and c["n_targets"] == 30 for c in alloc.calls)
    # the plan pipeline's park move limit (PlanRequest's default) reaches the allocator
    assert all(c["options"]["park_move_limit_s"] == PlanRequest.model_fields["park_move_limit_s"].default == 120.0
               for c in alloc.calls)
    want = expected_legs(alloc.calls, None)
    assert len(want) > len(alloc.calls) * 2  # several configurations per field
    assert len(plan.legs) == len(want)
    for i, ((start, got), (want_start, want_goal)) in enumerate(zip(plan.legs, want, strict=True)):
        np.testing.assert_array_equal(got, want_goal)
        # a chained leg starts where the previous one ended (the fake ends exactly at its goal)
        np.testing.assert_array_equal(start, plan.legs[i - 1][1] if want_start is None else want_start)
    legs = out["methods"]["ilp"]["legs"]
    n_conf = [len(c["result"].configurations) for c in alloc.calls[:2]]
    assert legs["park_to_configuration"]["legs"] == sum(n_conf)  # park -> every configuration
    assert legs["to_park"]["legs"] == 2
    assert legs["chained"]["legs"] == sum(n - 1 for n in n_conf)
    assert legs["chained"]["strategy_counts"] == {"fake": sum(n - 1 for n in n_conf)}
    assert out["methods"]["ilp"]["whole_field"]["planner_alone"]["share"] == 1.0
    assert out["methods"]["ilp"]["whole_field"]["plan_sequence"] == {"available": False}


def test_max_configurations_keeps_the_first_configurations_and_the_return_to_park(monkeypatch):
    _, alloc, plan = run_with_recorders(
        monkeypatch, ["--fields", "1", "--targets", "40", "--methods", "semigreedy",
                      "--max-configurations", "2"])
    assert len(alloc.calls) == 1 and alloc.calls[0]["options"]["configurations"] == "all"
    assert alloc.calls[0]["options"]["park_move_limit_s"] == 120.0
    want = expected_legs(alloc.calls, 2)
    assert len(want) == 4  # park -> c1 -> c2 -> park, and park -> c2
    for (_, got), (_, want_goal) in zip(plan.legs, want, strict=True):
        np.testing.assert_array_equal(got, want_goal)


def test_field_generator_priority_mix_and_clustering():
    rng = np.random.default_rng(5)
    uniform = motion.make_field(2000, None, rng)
    shares = {p: float(np.mean(uniform.priority == p)) for p in motion.PRIORITY_VALUES}
    for p, share in zip(motion.PRIORITY_VALUES, motion.PRIORITY_SHARES, strict=True):
        assert abs(shares[p] - share) < 0.03, (p, shares[p])
    radius_mm = {}
    for sigma_mm in (40.0, 60.0, 90.0, None):
        f = motion.make_field(2000, sigma_mm, np.random.default_rng(6))
        r_mm = np.hypot(f.x_mm, f.y_mm)
        assert r_mm.max() <= motion.FOV_RADIUS_MM + 1e-9
        radius_mm[sigma_mm] = float(np.median(r_mm))
    assert radius_mm[40.0] < radius_mm[60.0] < radius_mm[90.0] < radius_mm[None]


def test_thesis_fields_cycle_shapes_and_are_seeded():
    shapes = [motion.thesis_field(20, 0, i)[0] for i in range(5)]
    assert shapes == ["uniform", "gauss40", "gauss60", "gauss90", "uniform"]
    a, b = motion.thesis_field(50, 3, 2)[1], motion.thesis_field(50, 3, 2)[1]
    np.testing.assert_array_equal(a.x_mm, b.x_mm)
    np.testing.assert_array_equal(a.priority, b.priority)
    assert not np.array_equal(a.x_mm, motion.thesis_field(50, 3, 6)[1].x_mm)


def test_smoke_output_has_the_reported_keys(tmp_path, capsys):
    out_file, legs_file = tmp_path / "motion.json", tmp_path / "legs.npz"
    out = motion.main(["--smoke", "--fields", "1", "--targets", "40", "--max-configurations", "1",
                       "--methods", "ilp", "--out", str(out_file), "--save-legs", str(legs_file)])
    assert json.loads(capsys.readouterr().out) == json.loads(out_file.read_text())
    for key in ("parameters", "commit", "load_average_start", "load_average_end", "wall_s"):
        assert key in out
    assert out["protocol"] == "thesis" and out["parameters"]["leg_budget_s"] == 3.0
    legs = out["methods"]["ilp"]["legs"]
    assert set(legs) == {"park_to_configuration", "chained", "to_park"}
    assert legs["park_to_configuration"]["legs"] == 1 and legs["to_park"]["legs"] == 1
    assert legs["chained"]["legs"] == 0
    for key in ("success_rate", "compute_s_median", "compute_s_p90", "compute_s_p99",
                "compute_s_max", "makespan_s_median", "makespan_over_lower_bound_median",
                "makespan_over_lower_bound_p90", "makespan_le_120s_rate", "stops_per_arm_max",
                "stops_per_arm_mean", "strategy_counts", "failed_legs"):
        assert key in legs["to_park"]
    whole = out["methods"]["ilp"]["whole_field"]
    assert whole["planner_alone"]["fields"] == 1
    assert "available" in whole["plan_sequence"]
    n_failed = sum(len(s["failed_legs"]) for s in legs.values())
    saved = np.load(legs_file)
    assert saved["start_q"].shape == (n_failed, INST.n_arms, 2)
    assert saved["goal_q"].shape == (n_failed, INST.n_arms, 2)


class PlanSequenceRecorder:
    """A stand-in for planner.sequence.plan_sequence: one leg through park, two moved targets
    and one added configuration per field; every other field not executable."""

    def __init__(self):
        self.calls: list[tuple[tuple, object]] = []

    def __call__(self, instrument, configurations, options, *, targets):
        self.calls.append((tuple(configurations), options))
        ok = MotionPlan("ok", 1.0, (), (), {})
        failed = MotionPlan("failed", float("nan"), (), (3,), {})
        changes = (PlanChange("via_park", 1, None, (), (), "test"),
                   PlanChange("moved_target", 1, 0, (3,), ("t1", "t2"), "test"))
        final = (*configurations, configurations[0])
        last = ok if len(self.calls) % 2 else failed
        return SequencePlan(final, (ok,) * len(final) + (last,), changes)


def test_plan_sequence_section_counts_changes(monkeypatch):
    fake = PlanSequenceRecorder()
    namespace = types.SimpleNamespace(plan_sequence=fake, SequenceOptions=SequenceOptions)
    monkeypatch.setattr(motion, "sequence_module", namespace)
    monkeypatch.setattr(motion, "plan_motion", PlanMotionRecorder())
    alloc = AllocateRecorder(motion.allocate)
    monkeypatch.setattr(motion, "allocate", alloc)
    out = motion.main(["--fields", "2", "--targets", "30", "--methods", "semigreedy",
                       "--max-configurations", "2", "--leg-budget", "4"])
    seq = out["methods"]["semigreedy"]["whole_field"]["plan_sequence"]
    assert seq["available"] is True and seq["fields"] == 2
    assert seq["fields_executable"] == 1 and seq["fields_not_executable"] == [1]
    assert seq["changes_by_kind"] == {"moved_target": 2, "via_park": 2}
    assert seq["targets_moved"] == 4 and seq["legs_through_park"] == 2
    assert seq["configurations_added"] == 2
    for (configurations, options), call in zip(fake.calls, alloc.calls, strict=True):
        assert configurations == call["result"].configurations[:2]
        assert options.seed == 0 and options.leg_time_limit_s == 4.0


def _record(start_q, goal_q, makespan_s, leg=0):
    return motion.LegRecord("ilp", 0, leg, "park_to_configuration", "ok", 0.1, makespan_s, 100.0, (0,) * 12,
                            "delays", (), np.array(start_q, float), np.array(goal_q, float))


def test_long_plans_classified_by_the_positive_way_from_park():
    """A plan over 120 s from park counts as "beyond the positive reach" exactly when some arm's
    goal is more than 120 s of theta2 travel ahead the positive way (216 degrees at the default
    speed), whatever the shorter way."""
    v2 = INST.arm_array("joint2_speed_rad_s")[0]
    far, near = PARK_Q.copy(), PARK_Q.copy()
    far[6, 1] = np.deg2rad(250.0)  # -110 degrees the short way, 139 s the positive way
    near[6, 1] = np.deg2rad(200.0)  # 111 s the positive way
    assert motion.positive_sense_s(PARK_Q, far)[6] == np.deg2rad(250.0) / v2
    assert motion.positive_sense_s(PARK_Q, near).max() < 120.0
    chained = far.copy()
    chained[:, 0] -= 0.2  # not from park
    out = motion.over_120s([_record(PARK_Q, far, 139.0), _record(PARK_Q, near, 125.0), _record(PARK_Q, far, 110.0),
                            _record(chained, far, 130.0)])
    assert out == {"legs": 3, "from_park": 2, "from_park_arm_beyond_positive_reach": 1}


def test_first_configuration_row_counts_leg_zero_only():
    recs = [_record(PARK_Q, PARK_Q, 100.0, leg=0), _record(PARK_Q, PARK_Q, 130.0, leg=-2),
            _record(PARK_Q, PARK_Q, 125.0, leg=0)]
    first = motion.summaries_by_kind(recs, motion.LEG_KINDS[:1])["park_to_configuration"]["first_configuration"]
    assert first == {"legs": 2, "success_rate": 1.0, "makespan_le_120s_rate": 0.5}


def test_park_move_limit_none_is_the_unlimited_secondary_row(monkeypatch):
    """``--park-move-limit none`` allocates without the limit and says so in the JSON; with the
    default every planned goal is within 120 s of park turning theta2 the positive way."""
    out, alloc, plan = run_with_recorders(
        monkeypatch, ["--fields", "1", "--targets", "60", "--methods", "semigreedy",
                      "--park-move-limit", "none"])
    assert alloc.calls[0]["options"]["park_move_limit_s"] is None
    assert out["parameters"]["park_move_limit_s"] is None
    out, alloc, plan = run_with_recorders(
        monkeypatch, ["--fields", "1", "--targets", "60", "--methods", "semigreedy"])
    assert out["parameters"]["park_move_limit_s"] == 120.0
    goals = [goal for _, goal in plan.legs]
    assert max(motion.positive_sense_s(PARK_Q, g).max() for g in goals) <= 120.0 + 1e-9
