"""benchmarks/motion.py: the thesis 6.4.2 protocol plans the allocator's own configurations,
each field through the plan's per-pointing function (planner.programme.plan_pointing)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import planner.pointing as pointing
import planner.programme as programme
from benchmarks import motion, motion_fields
from models.instrument import default_instrument
from models.types import ArmTrajectory, MotionPlan
from planner.sequence import PlanChange, SequencePlan
from service.schemas import PlanRequest

INST = default_instrument()
PARK_Q = INST.park_configuration


class AllocateRecorder:
    """Wraps the real allocator where plan_pointing calls it: records every call's options."""

    def __init__(self, real):
        self.real = real
        self.calls: list[dict] = []

    def __call__(self, instrument, targets, **kwargs):
        result = self.real(instrument, targets, **kwargs)
        self.calls.append({"method": kwargs["method"], "solver": kwargs["solver"],
                           "configurations": kwargs["configurations"], "seed": kwargs["seed"],
                           "park_move_limit_s": kwargs["options"].sequence.park_move_limit_s,
                           "n_targets": len(targets.ids), "result": result})
        return result


class PlanSequenceRecorder:
    """A cheap stand-in for planner.sequence.plan_sequence where plan_pointing calls it: every
    leg "ok", no change; records the configurations and options it was given."""

    def __init__(self):
        self.calls: list[tuple[tuple, object]] = []

    def __call__(self, instrument, configurations, options=None, *, targets=None, progress=None,
                 budget=None, known=None):
        self.calls.append((tuple(configurations), options))
        ok = MotionPlan("ok", 1.0, (), (), {})
        return SequencePlan(tuple(configurations), (ok,) * (len(configurations) + 1))


class PlanPointingRecorder:
    """Wraps the real plan_pointing: records every call and the pointing's plan it returned."""

    def __init__(self, real):
        self.real = real
        self.calls: list[dict] = []

    def __call__(self, inst, targets, options, share_s, progress):
        pointing = self.real(inst, targets, options, share_s, progress)
        self.calls.append({"options": options, "share_s": share_s, "n_targets": len(targets.ids),
                           "pointing": pointing, "result": pointing.allocation})
        return pointing


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


class Recorders:
    def __init__(self, monkeypatch, sequence=None):
        self.alloc = AllocateRecorder(pointing.allocate)
        self.sequence = PlanSequenceRecorder() if sequence is None else sequence
        self.pointing = PlanPointingRecorder(motion.plan_pointing)
        self.plan = PlanMotionRecorder()
        monkeypatch.setattr(pointing, "allocate", self.alloc)
        monkeypatch.setattr(pointing, "plan_sequence", self.sequence)
        monkeypatch.setattr(motion, "plan_pointing", self.pointing)
        monkeypatch.setattr(motion, "plan_motion", self.plan)


def run_with_recorders(monkeypatch, argv: list[str], sequence=None) -> tuple[dict, Recorders]:
    rec = Recorders(monkeypatch, sequence)
    return motion.main(argv), rec


def expected_legs(calls: list[dict], max_configurations: int | None) -> list[tuple[np.ndarray | None, np.ndarray]]:
    """(start or None for "where the previous leg ended", goal) of every leg the benchmark must
    plan: the chain park -> c1 -> ... -> cn -> park, then park -> c_i for i >= 2."""
    legs: list[tuple[np.ndarray | None, np.ndarray]] = []
    for call in calls:
        qs = [c.q for c in call["result"].configurations[:max_configurations]]
        legs += [(PARK_Q, qs[0])] + [(None, q) for q in qs[1:] + [PARK_Q]]
        legs += [(PARK_Q, q) for q in qs[1:]]
    return legs


def single_pointing_share_s(limit_s: float, n_targets: int) -> float:
    return programme.pointing_shares(limit_s, [programme.pointing_need(n_targets)])[0]


def test_thesis_protocol_plans_the_allocators_configurations(monkeypatch):
    out, rec = run_with_recorders(
        monkeypatch, ["--fields", "2", "--targets", "30", "--methods", "ilp,semigreedy"])
    calls = rec.pointing.calls
    assert [c["options"].method for c in calls] == ["ilp", "ilp", "semigreedy", "semigreedy"]
    assert all(c["options"].solver == "bnb" and c["n_targets"] == 30 for c in calls)
    # one plan_pointing per field, at the share of a single-pointing plan at the default limit
    assert motion.DEFAULTS["time_limit"] == programme.DEFAULT_LIMIT_S == 120.0
    assert all(c["share_s"] == single_pointing_share_s(120.0, 30) for c in calls)
    assert out["methods"]["ilp"]["whole_field"]["plan_pointing"]["share_s"] == calls[0]["share_s"]
    # the pointing's allocation is the allocator's sequence, every configuration
    assert [c["method"] for c in rec.alloc.calls] == ["ilp", "ilp", "semigreedy", "semigreedy"]
    assert all(c["configurations"] == "all" and c["seed"] == 0 for c in rec.alloc.calls)
    assert all(a["result"] is p["result"] for a, p in zip(rec.alloc.calls, calls, strict=True))
    # the plan pipeline's park move limit (PlanRequest's default) reaches the allocation
    assert all(c["park_move_limit_s"] == PlanRequest.model_fields["park_move_limit_s"].default == 120.0
               for c in rec.alloc.calls)
    want = expected_legs(calls, None)
    assert len(want) > len(calls) * 2  # several configurations per field
    assert len(rec.plan.legs) == len(want)
    for i, ((start, got), (want_start, want_goal)) in enumerate(zip(rec.plan.legs, want, strict=True)):
        np.testing.assert_array_equal(got, want_goal)
        # a chained leg starts where the previous one ended (the fake ends exactly at its goal)
        np.testing.assert_array_equal(start, rec.plan.legs[i - 1][1] if want_start is None else want_start)
    legs = out["methods"]["ilp"]["legs"]
    n_conf = [len(c["result"].configurations) for c in calls[:2]]
    assert legs["park_to_configuration"]["legs"] == sum(n_conf)  # park -> every configuration
    assert legs["to_park"]["legs"] == 2
    assert legs["chained"]["legs"] == sum(n - 1 for n in n_conf)
    assert legs["chained"]["strategy_counts"] == {"fake": sum(n - 1 for n in n_conf)}
    whole = out["methods"]["ilp"]["whole_field"]
    assert whole["planner_alone"]["share"] == 1.0
    assert whole["plan_pointing"]["fields_executable"] == 2
    assert whole["plan_pointing"]["legs"] == sum(n + 1 for n in n_conf)


def test_time_limit_sets_the_pointings_share(monkeypatch):
    out, rec = run_with_recorders(
        monkeypatch, ["--fields", "1", "--targets", "30", "--methods", "semigreedy", "--time-limit", "30"])
    assert rec.pointing.calls[0]["share_s"] == single_pointing_share_s(30.0, 30) < single_pointing_share_s(120.0, 30)
    assert out["parameters"]["time_limit_s"] == 30.0
    assert out["parameters"]["pointing_share_s"] == rec.pointing.calls[0]["share_s"]
    with pytest.raises(SystemExit):
        motion.parse_args(["--time-limit", "0"])


def test_max_configurations_keeps_the_first_configurations_and_the_return_to_park(monkeypatch):
    out, rec = run_with_recorders(
        monkeypatch, ["--fields", "1", "--targets", "40", "--methods", "semigreedy",
                      "--max-configurations", "2"])
    assert len(rec.alloc.calls) == 1 and rec.alloc.calls[0]["configurations"] == "all"
    assert rec.alloc.calls[0]["park_move_limit_s"] == 120.0
    want = expected_legs(rec.pointing.calls, 2)
    assert len(want) == 4  # park -> c1 -> c2 -> park, and park -> c2
    for (_, got), (_, want_goal) in zip(rec.plan.legs, want, strict=True):
        np.testing.assert_array_equal(got, want_goal)
    # the pointing's plan keeps every configuration of its allocation
    n_conf = len(rec.pointing.calls[0]["result"].configurations)
    assert n_conf > 2 and len(rec.sequence.calls[0][0]) == n_conf
    assert out["methods"]["semigreedy"]["whole_field"]["plan_pointing"]["legs"] == n_conf + 1


def test_field_generator_priority_mix_and_clustering():
    rng = np.random.default_rng(5)
    uniform = motion_fields.make_field(2000, None, rng)
    shares = {p: float(np.mean(uniform.priority == p)) for p in motion_fields.PRIORITY_VALUES}
    for p, share in zip(motion_fields.PRIORITY_VALUES, motion_fields.PRIORITY_SHARES, strict=True):
        assert abs(shares[p] - share) < 0.03, (p, shares[p])
    radius_mm = {}
    for sigma_mm in (40.0, 60.0, 90.0, None):
        f = motion_fields.make_field(2000, sigma_mm, np.random.default_rng(6))
        r_mm = np.hypot(f.x_mm, f.y_mm)
        assert r_mm.max() <= motion_fields.FOV_RADIUS_MM + 1e-9
        radius_mm[sigma_mm] = float(np.median(r_mm))
    assert radius_mm[40.0] < radius_mm[60.0] < radius_mm[90.0] < radius_mm[None]


def test_thesis_fields_cycle_shapes_and_are_seeded():
    shapes = [motion_fields.thesis_field(20, 0, i)[0] for i in range(5)]
    assert shapes == ["uniform", "gauss40", "gauss60", "gauss90", "uniform"]
    a, b = motion_fields.thesis_field(50, 3, 2)[1], motion_fields.thesis_field(50, 3, 2)[1]
    np.testing.assert_array_equal(a.x_mm, b.x_mm)
    np.testing.assert_array_equal(a.priority, b.priority)
    assert not np.array_equal(a.x_mm, motion_fields.thesis_field(50, 3, 6)[1].x_mm)


def test_smoke_output_has_the_reported_keys(tmp_path, capsys):
    out_file, legs_file = tmp_path / "motion.json", tmp_path / "legs.npz"
    out = motion.main(["--smoke", "--fields", "1", "--targets", "40", "--max-configurations", "1",
                       "--methods", "ilp", "--out", str(out_file), "--save-legs", str(legs_file)])
    assert json.loads(capsys.readouterr().out) == json.loads(out_file.read_text())
    for key in ("parameters", "commit", "load_average_start", "load_average_end", "wall_s"):
        assert key in out
    assert out["protocol"] == "thesis" and out["parameters"]["leg_budget_s"] == 3.0
    assert out["parameters"]["time_limit_s"] == motion.SMOKE["time_limit"] < programme.DEFAULT_LIMIT_S
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
    pointing = whole["plan_pointing"]
    assert pointing["share_s"] == single_pointing_share_s(motion.SMOKE["time_limit"], 40)
    for key in ("fields", "fields_executable", "share", "legs", "legs_failed", "changes_by_kind",
                "targets_moved", "legs_through_park", "configurations_added", "targets_dropped",
                "wall_s_median", "wall_s_max", "effort_s_median", "effort_s_max", "overran",
                "fields_not_executable"):
        assert key in pointing
    assert pointing["fields"] == 1 and pointing["overran"] in (0, 1)
    assert 0.0 < out["methods"]["ilp"]["allocation"]["allocation_s_max"] <= pointing["wall_s_max"]
    n_failed = sum(len(s["failed_legs"]) for s in legs.values())
    saved = np.load(legs_file)
    assert saved["start_q"].shape == (n_failed, INST.n_arms, 2)
    assert saved["goal_q"].shape == (n_failed, INST.n_arms, 2)


class ChangingSequence(PlanSequenceRecorder):
    """A stand-in for plan_sequence: one leg through park, two moved targets and one added
    configuration per field; every other field not executable."""

    def __call__(self, instrument, configurations, options=None, *, targets=None, progress=None,
                 budget=None, known=None):
        self.calls.append((tuple(configurations), options))
        ok = MotionPlan("ok", 1.0, (), (), {})
        failed = MotionPlan("failed", float("nan"), (), (3,), {})
        changes = (PlanChange("via_park", 1, None, (), (), "test"),
                   PlanChange("moved_target", 1, 0, (3,), ("t1", "t2"), "test"))
        final = (*configurations, configurations[0])
        last = ok if len(self.calls) % 2 else failed
        return SequencePlan(final, (ok,) * len(final) + (last,), changes)


def test_plan_pointing_section_counts_changes(monkeypatch):
    out, rec = run_with_recorders(
        monkeypatch, ["--fields", "2", "--targets", "30", "--methods", "semigreedy",
                      "--max-configurations", "2", "--leg-budget", "4"], sequence=ChangingSequence())
    seq = out["methods"]["semigreedy"]["whole_field"]["plan_pointing"]
    assert seq["fields"] == 2 and seq["fields_executable"] == 1 and seq["share"] == 0.5
    assert seq["fields_not_executable"] == [{"field": 1, "failed_legs": 1, "unplanned_reason": None}]
    assert seq["changes_by_kind"] == {"moved_target": 2, "via_park": 2}
    assert seq["targets_moved"] == 4 and seq["legs_through_park"] == 2
    assert seq["configurations_added"] == 2 and seq["legs_failed"] == 1
    assert seq["effort_s_max"] > 0.0 and seq["wall_s_max"] > 0.0 and seq["overran"] == 0
    # the pointing's sequence gets every configuration of its allocation, with its seed and limit
    for (configurations, options), call in zip(rec.sequence.calls, rec.pointing.calls, strict=True):
        assert configurations == tuple(call["result"].configurations)
        assert options.seed == call["options"].seed == 0 and options.park_move_limit_s == 120.0


def test_a_pointing_whose_legs_were_not_planned_is_not_executable():
    """plan_pointing reports a planner error as the unchanged configurations with no legs and its
    reason: the benchmark counts that pointing as not executable."""
    targets = motion_fields.thesis_field(20, 0, 0)[1]
    allocation = pointing.allocate(INST, targets, method="semigreedy", configurations="all", seed=0)
    configurations = tuple(allocation.configurations)
    unplanned = programme.PointingPlan(targets, allocation, SequencePlan(configurations, ()),
                                       "planner error: boom", {}, 1.5)
    record = motion.pointing_record(unplanned, field=3, wall_s=2.0, allocation_s=0.5)
    assert not record.executable and record.unplanned_reason == "planner error: boom"
    assert record.effort_s == 1.5 and record.configurations_added == 0
    ok = MotionPlan("ok", 1.0, (), (), {})
    planned = programme.PointingPlan(targets, allocation, SequencePlan(configurations, (ok,) * (len(configurations) + 1)))
    assert motion.pointing_record(planned, field=3, wall_s=2.0, allocation_s=0.5).executable
    not_attempted = programme.PointingPlan(targets, None, SequencePlan((), (ok,)))
    assert not motion.pointing_record(not_attempted, field=3, wall_s=0.1, allocation_s=0.1).executable


def test_effort_figures_leave_out_pointings_that_reached_their_wall_clock_share():
    """Past its wall-clock share a pointing's effort clock jumps (models.clock.PAST_WALL_S):
    such a pointing is counted as overran, its effort left out of the effort figures."""
    def rec(field, effort_s, overran):
        return motion.PointingRecord(field, True, 5.0, 1.0, effort_s, overran, 3, 0, {}, 0, 0, 0, None)
    out = motion.pointing_summary([rec(0, 4.0, False), rec(1, 1e9 + 3.0, True), rec(2, 6.0, False)])
    assert out["overran"] == 1 and out["effort_s_max"] == 6.0 and out["effort_s_median"] == 5.0
    assert out["fields_executable"] == 3 and out["wall_s_max"] == 5.0


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
    out, rec = run_with_recorders(
        monkeypatch, ["--fields", "1", "--targets", "60", "--methods", "semigreedy",
                      "--park-move-limit", "none"])
    assert rec.pointing.calls[0]["options"].park_move_limit_s is None
    assert rec.alloc.calls[0]["park_move_limit_s"] is None
    assert out["parameters"]["park_move_limit_s"] is None
    out, rec = run_with_recorders(
        monkeypatch, ["--fields", "1", "--targets", "60", "--methods", "semigreedy"])
    assert out["parameters"]["park_move_limit_s"] == 120.0
    goals = [goal for _, goal in rec.plan.legs]
    assert max(motion.positive_sense_s(PARK_Q, g).max() for g in goals) <= 120.0 + 1e-9
