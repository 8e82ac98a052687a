"""Ejection-chain repair of a configuration sequence (solvers/sequencing/repair.py).

Oracles: FCL on every returned configuration (the repair itself only reads the
incompatibility structure), the tip-on-target check, the multiset of observed targets, and
a CP-SAT packing as the known optimum of a constructed case.
"""

from __future__ import annotations

import numpy as np

from models.collision import fcl_configuration_collisions
from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from models.kinematics import tip_fov
from models.types import PlaneTargets
from solvers.sequencing import pack_targets
from solvers.sequencing.repair import absorb_configurations

INS = default_instrument()


def _field(seed: int, n: int, sigma_mm: float | None = None):
    rng = np.random.default_rng(seed)
    if sigma_mm is None:
        r = 125.0 * np.sqrt(rng.random(n))
        ang = rng.random(n) * 2 * np.pi
        x, y = r * np.cos(ang), r * np.sin(ang)
    else:
        x, y = rng.normal(0, sigma_mm, n), rng.normal(0, sigma_mm, n)
        keep = np.hypot(x, y) < 124.0
        x, y = x[keep], y[keep]
    pr = rng.choice([500, 100, 10, 1], size=len(x), p=[0.1, 0.4, 0.4, 0.1])
    t = PlaneTargets.from_lists([f"t{i}" for i in range(len(x))], x, y, pr)
    return t, incompatibility_for_targets(INS, np.asarray(x), np.asarray(y))


def _check_valid(inc, t, sequence) -> list[int]:
    """Every configuration collision-free (FCL), one location per arm, each tip on its
    target; returns the observed targets."""
    a = inc.assignments
    seen: list[int] = []
    for ch in sequence:
        assert a.arm[ch].tolist() == list(range(INS.n_arms))
        q = a.q[ch]
        assert fcl_configuration_collisions(INS, q) == []
        tips = tip_fov(INS, np.arange(INS.n_arms), q[:, 0], q[:, 1])
        for k, x in enumerate(ch):
            tg = int(a.target[x])
            if tg >= 0:
                assert np.hypot(tips[k, 0] - t.x_mm[tg], tips[k, 1] - t.y_mm[tg]) < 0.01
                seen.append(tg)
    return seen


def _rest_compatible(inc, ch: np.ndarray, k: int) -> int | None:
    """A rest location of arm ``k`` that conflicts with none of the other arms in ``ch``."""
    a = inc.assignments
    others = set(np.delete(ch, k).tolist())
    for r in range(a.arm_start[k], a.arm_start[k + 1]):
        if a.target[r] < 0 and not others & set(inc.indices[inc.indptr[r]:inc.indptr[r + 1]].tolist()):
            return r
    return None


def test_split_target_goes_back_into_the_packing() -> None:
    """A CP-SAT packing with one target moved out into a configuration of its own: the
    repair must return to the packing's count, every configuration valid."""
    t, inc = _field(3, 36)
    a = inc.assignments
    pool = np.flatnonzero(inc.reachability.arms_per_target > 0)
    packed = pack_targets(inc, pool, 4, time_limit_s=120.0)
    assert packed is not None
    packed = [ch.copy() for ch in packed]
    spread = None
    for ci, ch in enumerate(packed):
        for k in range(INS.n_arms):
            r = _rest_compatible(inc, ch, k) if a.target[ch[k]] >= 0 else None
            if r is None:
                continue
            # the target alone: arm k on it, every other arm on a compatible rest
            alone = np.full(INS.n_arms, -1, np.int64)
            alone[k] = ch[k]
            for j in range(INS.n_arms):
                if j != k:
                    placed = set(alone[alone >= 0].tolist())
                    fit = [x for x in range(a.arm_start[j], a.arm_start[j + 1]) if a.target[x] < 0
                           and not placed & set(inc.indices[inc.indptr[x]:inc.indptr[x + 1]].tolist())]
                    if not fit:
                        break
                    alone[j] = fit[0]
            if (alone >= 0).all():
                reduced = ch.copy()
                reduced[k] = r
                spread = packed[:ci] + [reduced] + packed[ci + 1:] + [alone]
                break
        if spread is not None:
            break
    assert spread is not None
    before = sorted(_check_valid(inc, t, spread))
    out, _ = absorb_configurations(inc, spread, np.asarray(t.priority), budget_s=60.0)
    assert len(out) == 4
    assert sorted(_check_valid(inc, t, out)) == before == sorted(pool.tolist())


def test_repair_on_a_greedy_sequence_keeps_every_target_and_validity() -> None:
    """A clustered field's one-at-a-time sequence (repair and repacking off) leaves a
    sparse tail; the repair never adds a configuration, keeps the targets exactly, and on
    this field removes at least one (deterministic: node-limited solves, large budget)."""
    from solvers.allocation.bnb import solve_ilp_bnb
    from solvers.sequencing import (
        PackingOptions,
        RepairOptions,
        RescueOptions,
        SequenceOptions,
        SequencingOptions,
        sequence_configurations,
    )

    t, inc = _field(11, 96, sigma_mm=40.0)
    r = sequence_configurations(INS, t, solve_ilp_bnb,
                                SequencingOptions(sequence=SequenceOptions(config_time_limit_s=60.0),
                                                  rescue=RescueOptions(enabled=False),
                                                  repair=RepairOptions(enabled=False),
                                                  packing=PackingOptions(enabled=False)), incompatibility=inc,
                                time_limit_s=600.0)
    a = inc.assignments
    seq = []
    for c in r.configurations:
        ch = np.empty(INS.n_arms, np.int64)
        for asg in c.assignments:
            k = asg.arm
            sl = np.arange(a.arm_start[k], a.arm_start[k + 1])
            ch[k] = sl[np.argmin(np.abs(a.theta1_rad[sl] - asg.theta1_rad) + np.abs(a.theta2_rad[sl] - asg.theta2_rad))]
        seq.append(ch)
    before = sorted(_check_valid(inc, t, seq))
    out, _ = absorb_configurations(inc, seq, np.asarray(t.priority), budget_s=60.0,
                                   min_keep=r.stats["lower_bound_configurations"])
    assert sorted(_check_valid(inc, t, out)) == before
    assert len(out) < len(seq)
    # highest total priority first
    tot = [sum(int(t.priority[x]) for x in a.target[ch] if x >= 0) for ch in out]
    assert tot == sorted(tot, reverse=True)


def test_loose_group_absorbed_all_or_nothing() -> None:
    """A loose group with a target no arm reaches cannot be absorbed: the sequence is left
    exactly as it was; without that target the group is absorbed, each target once."""
    t0, _ = _field(3, 36)
    x = np.append(np.asarray(t0.x_mm), 300.0)  # outside every arm's reach
    y = np.append(np.asarray(t0.y_mm), 0.0)
    t = PlaneTargets.from_lists(list(t0.ids) + ["far"], x, y, np.append(np.asarray(t0.priority), 500))
    inc = incompatibility_for_targets(INS, x, y)
    a = inc.assignments
    assert inc.reachability.arms_per_target[-1] == 0
    pool = np.flatnonzero(inc.reachability.arms_per_target > 0)
    packed = pack_targets(inc, pool, 4, time_limit_s=120.0)
    assert packed is not None
    # take one target out of the packing (its arm to a compatible rest): it is the free one
    seq = [ch.copy() for ch in packed]
    free = None
    for ch in seq:
        for k in range(INS.n_arms):
            r = _rest_compatible(inc, ch, k) if a.target[ch[k]] >= 0 else None
            if r is not None:
                free, ch[k] = int(a.target[ch[k]]), r
                break
        if free is not None:
            break
    assert free is not None
    out, absorbed = absorb_configurations(inc, [ch.copy() for ch in seq], np.asarray(t.priority),
                                          budget_s=60.0, loose=[np.array([free, len(x) - 1])])
    assert absorbed == [False]
    assert sorted(ch.tolist() for ch in out) == sorted(ch.tolist() for ch in seq)
    out, absorbed = absorb_configurations(inc, [ch.copy() for ch in seq], np.asarray(t.priority),
                                          budget_s=60.0, loose=[np.array([free])])
    assert absorbed == [True]
    assert sorted(_check_valid(inc, t, out)) == sorted(pool.tolist())
