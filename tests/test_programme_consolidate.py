"""Step 5 of the programme optimiser (solvers.programme.consolidate): an exposure whose every
target an idle arm of another exposure can take, as it stands, is given up.

Oracles: forward kinematics (every observing arm's tip on its target, projected about its
pointing again), FCL clearances between every pair of arms of every exposure, the move from
park within the limit, and a count of every target observed before and after."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from models import clock
from models.budget import Budget
from models.collision import fcl_clearance_mm
from models.instrument import default_instrument
from models.kinematics import positive_turn_move_time_s, tip_fov
from models.sky import sky_to_focal_mm
from solvers.programme import fill
from solvers.programme.consolidate import consolidate
from solvers.programme.fill import Field, FillOptions, Pointing
from solvers.programme.spare import placements, spare_arm_for

INST = default_instrument()
LIMIT_S = 120.0
DEG_PER_MM = INST.plate_scale_arcsec_per_mm / 3600.0
V1 = INST.arm_array("joint1_speed_rad_s")
V2 = INST.arm_array("joint2_speed_rad_s")
OPTS = FillOptions(park_move_limit_s=LIMIT_S)


def _field(xy_mm: np.ndarray, seed: int) -> Field:
    rng = np.random.default_rng(seed)
    ra = 150.0 + xy_mm[:, 0] * DEG_PER_MM / np.cos(np.radians(20.0))
    dec = 20.0 + xy_mm[:, 1] * DEG_PER_MM
    return Field(INST, ra, dec, rng.choice([1, 10, 100, 500], len(xy_mm)).astype(np.int64))


def _pointing(f: Field, members: np.ndarray, centre_mm: tuple[float, float]) -> Pointing:
    centre = (150.0 + centre_mm[0] * DEG_PER_MM / np.cos(np.radians(20.0)), 20.0 + centre_mm[1] * DEG_PER_MM)
    members = np.asarray(sorted(members), np.int64)
    assert fill.within(f, members, centre).all()
    p = Pointing(centre, 0.0, members)
    result = fill.allocate_pointing(f, p, f.priority, OPTS, Budget.start(60.0))
    p.exposures = len(result.configurations)
    p.allocation = fill.witness(result, members, members, p.exposures, f.priority)
    assert p.allocation is not None
    return p


def _observed(pts: list[Pointing]) -> list[int]:
    return sorted(int(p.members[a.target_index]) for p in pts if p.allocation is not None
                  for c in p.allocation.configurations for a in c.assignments if a.target_index is not None)


def _check_exposures(f: Field, pts: list[Pointing]) -> None:
    """Every exposure is a configuration the instrument can hold (module docstring)."""
    for p in pts:
        if p.allocation is None:
            continue
        assert p.exposures == len(p.allocation.configurations)
        x, y = sky_to_focal_mm(f.ra_deg[p.members], f.dec_deg[p.members], p.centre[0], p.centre[1], f.scale,
                               p.pa_deg)
        for c in p.allocation.configurations:
            assert [a.arm for a in c.assignments] == list(range(INST.n_arms))
            for a in c.assignments:
                if a.target_index is None:
                    continue
                assert a.target_id == str(int(p.members[a.target_index]))
                tip = tip_fov(INST, a.arm, a.theta1_rad, a.theta2_rad)
                assert np.allclose(tip, (x[a.target_index], y[a.target_index]), atol=1e-6)
                assert positive_turn_move_time_s(INST.park_configuration[a.arm],
                                                 np.array([a.theta1_rad, a.theta2_rad]),
                                                 V1[a.arm], V2[a.arm]) <= LIMIT_S + 1e-9
            for a, b in itertools.combinations(c.assignments, 2):
                if a.target_index is None and b.target_index is None:
                    continue
                clear = fcl_clearance_mm(INST, a.arm, (a.theta1_rad, a.theta2_rad), b.arm,
                                         (b.theta1_rad, b.theta2_rad))
                assert clear >= INST.collision_buffer_mm - 1e-6, (p.centre, c.index, a.arm, b.arm)


def _overlapping(seed: int) -> tuple[Field, list[Pointing]]:
    """Two pointings 60 mm apart, every target inside both fields (within 85 mm of their
    midpoint): A with 13 targets, B with 5, each allocated to completeness on its own (reach
    and collisions take A two or three exposures, B one or two, with idle arms)."""
    rng = np.random.default_rng(seed)
    r = 85.0 * np.sqrt(rng.random(18))
    a = 2 * np.pi * rng.random(18)
    xy = np.column_stack([30.0 + r * np.cos(a), r * np.sin(a)])
    f = _field(xy, seed)
    return f, [_pointing(f, np.arange(13), (0.0, 0.0)), _pointing(f, np.arange(13, 18), (60.0, 0.0))]


def test_an_exposure_is_emptied_into_the_idle_arms_of_another_pointing() -> None:
    for seed in (1, 2, 3):
        f, pts = _overlapping(seed)
        before = _observed(pts)
        exposures = sum(p.exposures for p in pts)
        assert exposures >= 3  # A needs at least two exposures, B one
        saved = consolidate(f, pts, OPTS, Budget.start(30.0))
        assert saved >= 1
        assert sum(p.exposures for p in pts) == exposures - saved
        assert _observed(pts) == before  # every target still observed, once
        members = sorted(int(i) for p in pts for i in p.members)
        assert members == list(range(18))  # the members still partition the programme
        _check_exposures(f, pts)


def test_an_exposure_whose_target_no_other_field_holds_stays() -> None:
    """A's targets lie outside B's field: nothing of A can move, B's exposure keeps its arms."""
    rng = np.random.default_rng(7)
    r = 20.0 * np.sqrt(rng.random(18))
    a = 2 * np.pi * rng.random(18)
    xy = np.column_stack([r * np.cos(a), r * np.sin(a)])
    xy[13:] += (230.0, 0.0)  # B's targets, 230 mm away: the fields (r 124 mm) overlap
    f = _field(xy, 7)
    pts = [_pointing(f, np.arange(13), (0.0, 0.0)), _pointing(f, np.arange(13, 18), (230.0, 0.0))]
    assert pts[0].exposures >= 2
    exposures = [p.exposures for p in pts]
    assert consolidate(f, pts, OPTS, Budget.start(30.0)) == 0
    assert [p.exposures for p in pts] == exposures
    _check_exposures(f, pts)


def test_an_expired_budget_changes_nothing() -> None:
    f, pts = _overlapping(1)
    members = [p.members.copy() for p in pts]
    assert consolidate(f, pts, OPTS, Budget.start(0.0)) == 0
    assert all(np.array_equal(p.members, m) for p, m in zip(pts, members, strict=True))


def test_locked_targets_move_only_to_an_arm_they_may_use() -> None:
    """With A's targets locked to arms 0-2, a target of A that B takes sits on one of them;
    the lock can only keep targets from moving."""
    moved_free, moved_locked = 0, 0
    for seed in (1, 2, 3):
        f, pts = _overlapping(seed)
        consolidate(f, pts, OPTS, Budget.start(30.0))
        moved_free += sum(1 for i in pts[1].members if i < 13)
        f, pts = _overlapping(seed)
        limits = tuple([0b111] * 13 + [(1 << INST.n_arms) - 1] * 5)
        consolidate(f, pts, FillOptions(park_move_limit_s=LIMIT_S, arm_limits=limits),
                    Budget.start(30.0))
        for c in pts[1].allocation.configurations:
            for a in c.assignments:
                if a.target_index is not None and int(pts[1].members[a.target_index]) < 13:
                    assert a.arm <= 2
                    moved_locked += 1
        _check_exposures(f, pts)
    assert moved_free >= 1 and moved_locked <= moved_free


def test_placements_is_spare_arm_for_on_every_configuration_at_once() -> None:
    f, pts = _overlapping(3)
    configs = pts[0].allocation.configurations
    q = np.stack([c.q for c in configs])
    idle = np.stack([[a.kind in ("park", "blank") for a in c.assignments] for c in configs])
    for x, y in [(0.0, 0.0), (60.0, -20.0), (-90.0, 40.0), (15.0, 100.0), (30.0, 10.0)]:
        arm, pose = placements(INST, q, idle, x, y, LIMIT_S)
        for e in range(len(configs)):
            one = spare_arm_for(INST, q[e], idle[e], x, y, LIMIT_S)
            assert (arm[e] >= 0) == (one is not None)
            if one is not None:
                assert (int(arm[e]), *pose[e]) == one


def _legs_of(a):
    """The exposures of ``a`` still alive as configurations (joint angles and targets: what
    planner.known_legs.new_legs compares; the target rides in theta1 of a dummy arm)."""
    from models.types import ArmAssignment, Configuration

    out = []
    for e in np.flatnonzero(a.alive):
        arms = tuple(ArmAssignment(k, "target", float(a.q[e, k, 0]), float(a.q[e, k, 1]), 0.0, 0.0)
                     for k in range(a.q.shape[1]))
        tag = ArmAssignment(a.q.shape[1], "park", float(hash(a.target[e].tobytes()) % 1000), 0.0, 0.0, 0.0)
        out.append(Configuration(len(out), (*arms, tag), 0, 0, "feasible"))
    return out


@pytest.mark.parametrize("seed", range(8))
def test_leg_costs_count_the_legs_a_taken_target_makes_new(seed) -> None:
    """LegCosts.extra_s against a restatement: the new legs (planner.known_legs.new_legs) of the
    pointing with the target taken, minus those without, at the pointing's cost per leg, over
    random emptied and changed exposures."""
    from planner.known_legs import new_legs
    from solvers.programme.consolidate import Arms, LegCosts

    rng = np.random.default_rng(seed)
    n_exp, n_arms = int(rng.integers(1, 6)), 3
    orig = Arms((0.0, 0.0), 0.0, rng.random((n_exp, n_arms, 2)), np.zeros((n_exp, n_arms), bool),
                rng.integers(0, 50, (n_exp, n_arms)), np.ones(n_exp, bool))
    legs = LegCosts.of({7: orig}, {7: 2.5})
    cur = orig.copy()
    for e in range(n_exp):
        r = rng.random()
        if r < 0.25 and cur.alive.sum() > 1:
            cur.alive[e] = False
        elif r < 0.5:
            cur.q[e, 0, 0] += 0.1
            cur.target[e, 0] = 99
    for x in np.flatnonzero(cur.alive):
        taken = cur.copy()
        taken.q[x, 1, 1] += 0.2
        taken.target[x, 1] = 98
        want = new_legs(_legs_of(orig), _legs_of(taken)) - new_legs(_legs_of(orig), _legs_of(cur))
        assert legs.extra_s(7, cur, int(x)) == pytest.approx(2.5 * want)
    assert legs.extra_s(3, cur, int(np.flatnonzero(cur.alive)[0])) == 0.0  # a pointing it does not know


def test_an_allocation_uses_what_is_left_of_a_long_budget() -> None:
    """A feedback allocation late in a long budget (9.5 of 10 s spent, 0.5 s left) gets those
    0.5 s: it observes every member, as the same allocation on a fresh budget does. Reading
    the seconds left as a fraction of the budget's length put its deadline 4.5 s in the past
    (it then observed nothing)."""
    f, pts = _overlapping(1)
    p = Pointing(pts[1].centre, 0.0, pts[1].members)
    fresh = fill.allocate_pointing(f, p, f.priority, OPTS, Budget.start(60.0))
    t_s = clock.now()
    late = Budget(t_s - 9.5, t_s + 0.5, 10.0)
    result = fill.allocate_pointing(f, p, f.priority, OPTS, late)
    observed = {a.target_index for c in result.configurations for a in c.assignments if a.target_index is not None}
    assert observed == {a.target_index for c in fresh.configurations for a in c.assignments
                        if a.target_index is not None}
    assert len(observed) == len(p.members)
    assert len(result.configurations) == len(fresh.configurations)
