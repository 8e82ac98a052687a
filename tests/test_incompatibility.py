"""Reachability and the incompatibility matrix against brute-force FCL."""

from __future__ import annotations

import fcl
import numpy as np

from models.collision import fcl_arm_objects
from models.incompatibility import (
    BLANK,
    FIXED,
    PARK,
    build_assignments,
    incompatibility_for_targets,
    sample_blank_sky,
)
from models.instrument import default_instrument
from models.kinematics import Links, in_zoa, inverse_fov, tip_fov

INS = default_instrument()


def random_fov_targets(rng: np.random.Generator, n: int, radius_mm: float = 125.0):
    r = radius_mm * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    return r * np.cos(a), r * np.sin(a)


def brute_force_pairs(inc) -> set[tuple[int, int]]:
    """Oracle: every cross-arm pair checked with FCL (objects built once), plus same-target pairs."""
    a = inc.assignments
    objs = [fcl_arm_objects(INS, int(a.arm[i]), a.theta1_rad[i], a.theta2_rad[i]) for i in range(len(a))]
    request = fcl.DistanceRequest()
    out = set()
    for i in range(len(a)):
        for j in range(i + 1, len(a)):
            if a.arm[i] == a.arm[j]:
                continue
            if a.target[i] >= 0 and a.target[i] == a.target[j]:
                out.add((i, j))
                continue
            d = min(fcl.distance(x, y, request, fcl.DistanceResult()) for x in objs[i] for y in objs[j])
            if d < inc.buffer_mm:
                out.add((i, j))
    return out


def test_incompatibility_equals_brute_force_fcl_on_60_targets() -> None:
    rng = np.random.default_rng(21)
    x, y = random_fov_targets(rng, 60)
    inc = incompatibility_for_targets(INS, x, y, blank_per_arm=2)
    assert (inc.assignments.target == BLANK).sum() == 24
    got = {tuple(p) for p in inc.pairs.tolist()}
    expected = brute_force_pairs(inc)
    assert len(expected) > 1000
    assert got == expected


def test_structure_views_are_consistent() -> None:
    rng = np.random.default_rng(22)
    x, y = random_fov_targets(rng, 80)
    inc = incompatibility_for_targets(INS, x, y, buffer_mm=8.0)
    a = inc.assignments
    # CSR symmetric and equal to the pair list
    for i, j in inc.pairs[:500]:
        assert j in inc.neighbours(i) and i in inc.neighbours(j)
        assert not inc.compatible(int(i), int(j))
        assert j in inc.conflicts(int(i), int(a.arm[j]))
    assert len(inc.indices) == 2 * len(inc.pairs)
    # same-target flags are right
    st = inc.pairs[inc.same_target]
    assert (a.target[st[:, 0]] == a.target[st[:, 1]]).all()
    # counts add up
    c = inc.counts()
    assert c["incompatible_pairs"] == c["geometric_pairs"] + c["same_target_pairs"]
    # every assignment's tip is on its target, to 1e-6 mm
    real = a.target >= 0
    tip = tip_fov(INS, a.arm[real], a.theta1_rad[real], a.theta2_rad[real])
    assert np.allclose(tip[:, 0], x[a.target[real]], atol=1e-6)
    assert np.allclose(tip[:, 1], y[a.target[real]], atol=1e-6)
    # each arm has its park location
    park = a.target == PARK
    assert sorted(a.arm[park].tolist()) == list(range(12))


def test_reachability_matches_ik_and_reports_unreachable_targets() -> None:
    x = np.array([0.0, 60.0, 500.0, -124.0])
    y = np.array([0.0, -30.0, 0.0, 0.0])
    reach = build_assignments(INS, x, y)
    sol = inverse_fov(INS, np.arange(12)[:, None], x[None], y[None])
    assert reach.arms_per_target.tolist() == sol.valid.any(-1).sum(0).tolist()
    assert reach.arms_per_target[0] == 12
    assert reach.unreachable.tolist() == [2]  # never silently dropped


def test_fixed_arm_and_current_locations() -> None:
    rng = np.random.default_rng(23)
    x, y = random_fov_targets(rng, 30)
    q_fixed = (np.pi * 0.6, 1.0)
    current = INS.park_configuration.copy()
    current[4] = (np.pi * 0.7, 0.5)
    reach = build_assignments(INS, x, y, fixed={3: q_fixed}, current=current)
    a = reach.assignments
    sl = a.of_arm(3)
    assert a.target[sl].tolist() == [FIXED]
    assert np.allclose(a.q[sl][0], q_fixed)
    assert (a.target[a.of_arm(4)] == FIXED).sum() == 1  # current differs from park
    assert (a.target[a.of_arm(5)] == FIXED).sum() == 0  # current == park: not duplicated
    # disabled arms in the instrument file stay parked and take no target
    ins = INS.with_arms_disabled([7])
    r2 = build_assignments(ins, x, y)
    assert r2.assignments.target[r2.assignments.of_arm(7)].tolist() == [FIXED]


def test_empty_target_list() -> None:
    inc = incompatibility_for_targets(INS, np.zeros(0), np.zeros(0))
    assert len(inc.assignments) == 12
    assert len(inc.pairs) == 0


def test_larger_buffer_only_adds_pairs() -> None:
    rng = np.random.default_rng(24)
    x, y = random_fov_targets(rng, 100)
    small = incompatibility_for_targets(INS, x, y, buffer_mm=5.0)
    big = incompatibility_for_targets(INS, x, y, buffer_mm=15.0)
    s = {tuple(p) for p in small.pairs.tolist()}
    b = {tuple(p) for p in big.pairs.tolist()}
    assert s < b


def test_blank_sky_locations_are_feasible_and_deterministic() -> None:
    for k in (0, 5, 11):
        q = sample_blank_sky(INS, k, 6, seed=3)
        assert q.shape == (6, 2)
        assert not in_zoa(q[:, 0], q[:, 1], Links.of(INS, k)).any()
        tip = tip_fov(INS, k, q[:, 0], q[:, 1])
        r = np.hypot(tip[:, 0], tip[:, 1])
        assert ((r > 0.6 * INS.fov_radius_mm) & (r < 1.3 * INS.fov_radius_mm)).all()
        assert np.array_equal(q, sample_blank_sky(INS, k, 6, seed=3))
        assert not np.array_equal(q, sample_blank_sky(INS, k, 6, seed=4))


def test_blank_sky_frees_an_arm_whose_park_blocks_a_rim_target() -> None:
    """A rim target right in front of arm 0's park is reachable only by other arms; with
    blank-sky poses arm 0 still has somewhere to rest while a neighbour observes it."""
    x, y = np.array([124.0]), np.array([0.0])
    assert not inverse_fov(INS, 0, 124.0, 0.0).valid.any()
    inc = incompatibility_for_targets(INS, x, y, blank_per_arm=6)
    a = inc.assignments
    arm0 = np.flatnonzero(a.arm == 0)
    park0 = arm0[a.target[arm0] == PARK][0]
    for t in np.flatnonzero(a.target == 0):
        assert park0 in inc.neighbours(t), "the park of arm 0 blocks the rim target"
        free = [i for i in arm0 if i not in inc.neighbours(t)]
        assert free and all(a.target[i] == BLANK for i in free)


def _capsule_pairs(inc, slack_mm: float = 0.0) -> set[tuple[int, int]]:
    """Cross-arm pairs closer than buffer + slack (capsule clearance, vectorised), plus same-target pairs."""
    from models.collision import body_segments_mm, clearance_mm

    a = inc.assignments
    seg = body_segments_mm(INS, a.arm, a.theta1_rad, a.theta2_rad)
    i, j = np.triu_indices(len(a), 1)
    keep = a.arm[i] != a.arm[j]
    i, j = i[keep], j[keep]
    c = clearance_mm(tuple(s[i] for s in seg), tuple(s[j] for s in seg))
    bad = (c < inc.buffer_mm + slack_mm) | ((a.target[i] >= 0) & (a.target[i] == a.target[j]))
    return set(zip(i[bad].tolist(), j[bad].tolist(), strict=True))


RING_POINTS = [(0.0, 0.0)] + [(r * np.cos(t), r * np.sin(t)) for r in (15.0, 25.0, 35.0)
                              for t in np.radians(np.arange(0, 360, 30))]


def test_symmetric_ring_layouts_never_miss_a_collision() -> None:
    """All 666 pairs of {centre} + rings of 15/25/35 mm at 30 deg, in one structure of the 37
    targets, and the 24 pairs whose tips are exactly 25 mm apart each in a structure of its
    own: every pair closer than the buffer is in the structure (ties at exactly the buffer
    included: two tips 25 mm apart measure 5 mm give or take rounding), and nothing farther
    than the buffer + 1e-5 mm is."""
    import itertools

    ring = np.array(RING_POINTS)
    ties = [(p, q) for p, q in itertools.combinations(RING_POINTS, 2)
            if abs(np.hypot(p[0] - q[0], p[1] - q[1]) - 25.0) < 1e-9]
    assert len(ties) == 24
    for xy in [ring] + [np.array(pq) for pq in ties]:
        inc = incompatibility_for_targets(INS, xy[:, 0], xy[:, 1])
        assert len(set(inc.assignments.target.tolist()) - {-1}) == len(xy)  # every target reached
        got = {tuple(x) for x in inc.pairs.tolist()}
        assert _capsule_pairs(inc) <= got, xy.tolist()
        assert got <= _capsule_pairs(inc, slack_mm=1e-5), xy.tolist()


def test_symmetric_pair_allocates_with_every_engine() -> None:
    """(0, 0) + (0, 25) mm: two tips exactly at the buffer; a structure that accepted them would
    hand the allocator's geometric check a configuration it rejects (a 503 at the service)."""
    from models.types import PlaneTargets
    from solvers.allocation import allocate

    t = PlaneTargets.from_lists(["a", "b"], [0.0, 0.0], [0.0, 25.0], [1, 1])
    for solver in ("bnb", "highs", "cpsat"):
        res = allocate(INS, t, method="ilp", solver=solver, configurations="all", time_limit_s=10.0)
        observed = {a.target_id for c in res.configurations for a in c.assignments if a.kind == "target"}
        assert observed == {"a", "b"}, solver


def test_crowded_symmetric_fields_agree_with_fcl() -> None:
    """Crowded fields near the centre (targets on axes, mirror pairs, 25 mm apart) against FCL."""
    rng = np.random.default_rng(5)
    for n in range(2, 7):
        base = rng.uniform(-40, 40, (n, 2)).round(0)
        mirrored = np.vstack([base, base * [-1, 1]])[: max(2, n)]
        for xy in (base, mirrored, np.column_stack([np.zeros(n), 25.0 * np.arange(n) - 40])):
            xy = np.unique(xy, axis=0)
            inc = incompatibility_for_targets(INS, xy[:, 0], xy[:, 1])
            got = {tuple(x) for x in inc.pairs.tolist()}
            fcl_pairs = brute_force_pairs(inc)
            assert fcl_pairs <= got
            assert got <= _capsule_pairs(inc, slack_mm=1e-5)
