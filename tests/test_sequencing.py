"""Sequencing to full completeness (thesis 5.5) and tail repacking."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

from models.collision import fcl_configuration_collisions
from models.instrument import default_instrument
from models.kinematics import tip_fov
from models.types import PlaneTargets
from solvers.allocation.cpsat import solve_ilp_cpsat
from solvers.problem import ConfigSolution
from solvers.sequencing import (
    PackingOptions,
    RescueOptions,
    SequenceOptions,
    SequencingOptions,
    UnverifiedConfigurationError,
    sequence_configurations,
)

INS = default_instrument()
# generous limits: CI machines are loaded; no assertion below may depend on solver speed
LIM = {"time_limit_s": 600.0}
CAP = SequenceOptions(config_time_limit_s=60.0)


def _targets(rng, n, radius=125.0):
    r = radius * np.sqrt(rng.random(n))
    a = rng.random(n) * 2 * np.pi
    pr = rng.choice([500, 100, 10, 1], size=n, p=[0.1, 0.4, 0.4, 0.1])
    return PlaneTargets.from_lists([f"t{i}" for i in range(n)], r * np.cos(a), r * np.sin(a), pr)


def test_sequence_completes_field_and_every_configuration_is_valid() -> None:
    t = _targets(np.random.default_rng(0), 40)
    r = sequence_configurations(INS, t, solve_ilp_cpsat, SequencingOptions(sequence=CAP), **LIM)
    seen = set()
    for c in r.configurations:
        q = c.q
        assert fcl_configuration_collisions(INS, q) == []
        tips = tip_fov(INS, np.arange(INS.n_arms), q[:, 0], q[:, 1])
        assert [a.arm for a in c.assignments] == list(range(INS.n_arms))
        for a in c.assignments:
            if a.kind == "target":
                assert a.target_index not in seen
                seen.add(a.target_index)
                assert np.hypot(tips[a.arm, 0] - t.x_mm[a.target_index], tips[a.arm, 1] - t.y_mm[a.target_index]) < 0.01
                assert a.target_id == t.ids[a.target_index]
    assert len(seen) + len(r.unallocated) == len(t)
    assert all(u.reason == "conflict" for u in r.unallocated)
    s = r.stats
    assert s["n_configurations"] >= s["lower_bound_configurations"] == 4
    assert len(s["per_configuration"]) == s["n_configurations"]
    assert 0 < s["priority_completeness"] <= 1


def test_priority_order_of_first_configuration() -> None:
    t = _targets(np.random.default_rng(1), 60)
    r = sequence_configurations(INS, t, solve_ilp_cpsat,
                                SequencingOptions(sequence=CAP, packing=PackingOptions(enabled=False)), **LIM)
    tp = [c.total_priority for c in r.configurations]
    if r.configurations[0].status == "optimal":
        assert tp[0] == max(tp)


def test_unreachable_targets_reported_and_arms_parked() -> None:
    t = PlaneTargets.from_lists(["a", "b"], [500.0, -600.0], [0.0, 0.0], [1, 2])
    r = sequence_configurations(INS, t, solve_ilp_cpsat, SequencingOptions(sequence=CAP), **LIM)
    assert r.configurations == ()
    assert sorted(u.reason for u in r.unallocated) == ["unreachable", "unreachable"]


def test_one_configuration_all_parked_when_nothing_reachable() -> None:
    from solvers.allocation import allocate

    t = PlaneTargets.from_lists(["a"], [500.0], [0.0], [1])
    r = allocate(INS, t, configurations="one")
    assert [u.reason for u in r.unallocated] == ["unreachable"]


def test_unverified_solution_raises() -> None:
    def bad(problem):
        a = problem.assignments
        # every arm on its first target assignment (or rest): collisions / duplicates
        chosen = np.array([a.arm_start[k + 1] - 1 for k in range(INS.n_arms)])
        return ConfigSolution(chosen, "optimal", 1, 12, 0.0)

    t = _targets(np.random.default_rng(2), 80, radius=40.0)
    with pytest.raises(UnverifiedConfigurationError):
        sequence_configurations(INS, t, bad)


def test_disabled_arms_respected_in_sequence() -> None:
    t = _targets(np.random.default_rng(3), 30)
    fixed = {0: (np.pi, 0.0), 5: (np.pi, 0.0)}
    r = sequence_configurations(INS, t, partial(solve_ilp_cpsat, minimize_move=False), SequencingOptions(sequence=CAP),
                                fixed=fixed, **LIM)
    for c in r.configurations:
        for k in fixed:
            assert c.assignments[k].kind == "fixed"


def test_repacking_never_increases_configurations() -> None:
    """Repacking only replaces a tail by a proven-feasible shorter one: compared within ONE
    run (greedy count vs final count), so CP-SAT's choice among tied optima cannot matter."""
    t = _targets(np.random.default_rng(4), 48, radius=70.0)
    f = partial(solve_ilp_cpsat, minimize_move=False)
    b = sequence_configurations(INS, t, f,
                                SequencingOptions(sequence=CAP, packing=PackingOptions(enabled=True)), **LIM)
    assert b.stats["n_configurations"] <= b.stats["n_configurations_greedy"]
    assert b.stats["field_completeness"] == 1.0
    assert b.stats["n_configurations"] >= b.stats["lower_bound_configurations"]


def test_rescue_places_targets_on_park_spots() -> None:
    """Targets on the ring of park tips (r ~ 122 mm) are reachable only by neighbours of
    an arm whose park spot blocks them: without the rescue they stay ``conflict``; with it
    idle arms rest on already observed targets (kind "blank") and every target is
    observed exactly once in verified configurations."""
    from solvers.allocation.bnb import solve_ilp_bnb

    rng = np.random.default_rng(0)
    n = 40
    r, a = 118 + 8 * rng.random(n), rng.random(n) * 2 * np.pi
    t = PlaneTargets.from_lists([f"t{i}" for i in range(n)], r * np.cos(a), r * np.sin(a), np.ones(n, np.int64))
    f = partial(solve_ilp_bnb, fallback=None)
    off = sequence_configurations(INS, t, f,
                                  SequencingOptions(sequence=CAP, rescue=RescueOptions(enabled=False),
                                                    packing=PackingOptions(enabled=False)), **LIM)
    assert any(u.reason == "conflict" for u in off.unallocated)
    on = sequence_configurations(INS, t, f,
                                 SequencingOptions(sequence=CAP, rescue=RescueOptions(enabled=True),
                                                   packing=PackingOptions(enabled=False)), **LIM)
    assert on.stats["n_allocated"] == on.stats["n_reachable"] and on.stats["stop_reason"] == "complete"
    seen = [x.target_index for c in on.configurations for x in c.assignments if x.target_index is not None]
    assert len(seen) == len(set(seen)) == on.stats["n_reachable"]
    for c in on.configurations:
        assert fcl_configuration_collisions(INS, c.q) == []
        assert c.arm_yield == sum(x.kind == "target" for x in c.assignments)
        assert all(x.target_index is None for x in c.assignments if x.kind == "blank")


def test_crowding_tie_break_counts_pending_neighbours() -> None:
    """hard_to_place: reach term plus pending neighbours within 15 mm (brute-force distances)."""
    from models.incompatibility import incompatibility_for_targets
    from solvers.sequencing import hard_to_place

    rng = np.random.default_rng(5)
    x, y = rng.normal(0, 20, 60), rng.normal(0, 20, 60)
    inc = incompatibility_for_targets(INS, x, y)
    xy = np.column_stack([x, y])
    pending = rng.random(60) < 0.7
    base = hard_to_place(inc, INS.n_arms)
    h = hard_to_place(inc, INS.n_arms, xy, pending)
    d = np.hypot(x[:, None] - x[None], y[:, None] - y[None])
    reach = inc.reachability.arms_per_target > 0
    for i in range(60):
        want = base[i] + (int(((d[i] <= 15.0) & pending & reach).sum()) - 1 if pending[i] and reach[i] else 0)
        assert h[i] == want


def test_pack_targets_proves_infeasibility_and_packs_validly() -> None:
    """30 targets cannot fit 2 configurations of 12 arms (CP-SAT proves it); a packing into
    enough configurations places every pooled target exactly once, collision-free (FCL)."""
    from models.incompatibility import incompatibility_for_targets
    from solvers.sequencing import pack_targets

    t = _targets(np.random.default_rng(6), 30)
    inc = incompatibility_for_targets(INS, np.asarray(t.x_mm), np.asarray(t.y_mm))
    pool = np.flatnonzero(inc.reachability.arms_per_target > 0)
    st: dict = {}
    assert pack_targets(inc, pool, 2, time_limit_s=60.0, status_out=st) is None
    assert st["infeasible"] is True
    packed = pack_targets(inc, pool, 6, time_limit_s=120.0, status_out=st)
    assert packed is not None and not st["infeasible"]
    a = inc.assignments
    got = np.concatenate([a.target[ch][a.target[ch] >= 0] for ch in packed])
    assert sorted(got.tolist()) == sorted(pool.tolist())
    for ch in packed:
        assert a.arm[ch].tolist() == list(range(INS.n_arms))
        assert fcl_configuration_collisions(INS, a.q[ch]) == []


def _off_centre_cluster(k: int) -> PlaneTargets:
    """``k`` targets within 1.5 mm of a point 70 mm from the centre (priority 10, first)
    and 30 scattered ones."""
    rng = np.random.default_rng(11)
    ang = rng.random(k) * 2 * np.pi
    cx, cy = 70.0 + 1.5 * np.cos(ang) * rng.random(k), 1.5 * np.sin(ang) * rng.random(k)
    base = _targets(rng, 30)
    x = np.r_[cx, np.asarray(base.x_mm)]
    y = np.r_[cy, np.asarray(base.y_mm)]
    return PlaneTargets.from_lists([f"t{i}" for i in range(len(x))], x, y, np.r_[np.full(k, 10), base.priority])


def test_lp_bound_proves_an_off_centre_cluster_optimal() -> None:
    """Seven targets within 1.5 mm of a point 70 mm from the centre: no two arms can observe
    two of them at once (their tips would be closer than the bodies allow), so at least seven
    configurations are needed.  The disc crowding bound (discs about the centre up to 50 mm)
    and ceil(t / 12) cannot see it; the configuration LP bound must, and the sequence can
    never use fewer configurations than any proven bound."""
    from models.incompatibility import incompatibility_for_targets
    from solvers.sequencing.bounds import max_simultaneous_targets

    t = _off_centre_cluster(7)
    inc = incompatibility_for_targets(INS, np.asarray(t.x_mm), np.asarray(t.y_mm))
    m, proven = max_simultaneous_targets(inc, np.arange(7), time_limit_s=60.0)
    assert proven and m == 1  # the premise: pairwise exclusive
    r = sequence_configurations(INS, t, solve_ilp_cpsat,
                                SequencingOptions(sequence=CAP,
                                                  packing=PackingOptions(lp_bound_time_limit_s=300.0,
                                                                         attempt_time_limit_s=0.25)), **LIM)
    s = r.stats
    assert s["field_completeness"] == 1.0
    assert s["lower_bound_configurations_crowding"] < 7 and s["lower_bound_configurations"] < 7
    assert s["lower_bound_configurations_lp"] >= 7
    assert s["n_configurations"] >= s["lower_bound_configurations_proven"] >= 7


def test_repacking_never_repeats_a_tabu_search(monkeypatch) -> None:
    """The tabu search is deterministic in (pool, count, hint, seed): a second call with all
    four equal repeats the first step for step and wastes its budget.  With the LP bound off,
    an exclusive cluster of five makes every count below 5 infeasible, so the whole-field
    packing at the cheap floor fails and the repacking tries the same pool, count and hint
    again — with another seed."""
    import solvers.sequencing.packing as seq

    calls: list[tuple] = []
    real = seq.tabu_pack

    def recording(inc, pool, n_configs, **kw):
        hint = tuple(tuple(int(v) for v in h) for h in (kw.get("hint") or []))
        calls.append((tuple(sorted(int(t) for t in pool)), n_configs, hint, kw.get("seed")))
        return real(inc, pool, n_configs, **kw)

    monkeypatch.setattr(seq, "tabu_pack", recording)
    t = _off_centre_cluster(5)
    r = sequence_configurations(INS, t, solve_ilp_cpsat,
                                SequencingOptions(sequence=SequenceOptions(config_time_limit_s=5.0),
                                                  packing=PackingOptions(lp_bound_time_limit_s=0.0,
                                                                         attempt_time_limit_s=0.25)),
                                time_limit_s=20.0)
    assert r.stats["field_completeness"] == 1.0
    same = [(a, b) for i, a in enumerate(calls) for b in calls[i + 1:] if a[:3] == b[:3]]
    assert same  # the premise: the repacking retried a pool, count and hint
    assert all(a[3] != b[3] for a, b in same)
