"""The programme optimiser's model variants (docs/programme.md, "The fewest exposures"): the
time they may take comes only from what the rounds are not expected to need, and the search
kept is the one whose real allocations take the least telescope time, never more than the
first variant's."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models import clock
from models.budget import Budget
from models.instrument import load_instrument
from models.sky import tangent_radius_mm
from planner import programme
from planner.programme import SHARES, optimiser_s, usable_s, variants_s
from planner.time_advice import needed_limit_s, pointings_part_s
from solvers.programme import segment_programme
from solvers.programme.optimiser import VARIANTS
from tests.test_programme_optimiser import programme as uniform_programme

INST = load_instrument()
SCALE = float(INST.plate_scale_arcsec_per_mm)
FOV_R = float(INST.fov_radius_mm)


def rounds_need_s(n: int) -> float:
    """What the rounds of ``n`` targets are expected to need at most, wall seconds (the
    variants leave at least this to them)."""
    targets = n + SHARES.fixed_need_targets  # a pointing's fixed part, once
    return SHARES.variants_need_factor * SHARES.typical_effort_per_target_s * targets / SHARES.effort_share


@pytest.mark.parametrize("limit_s", [10.0, 30.0, 60.0, 120.0, 300.0])
def test_variants_take_only_time_the_rounds_are_not_expected_to_need(limit_s: float) -> None:
    share_s = optimiser_s(limit_s)  # without a count: the optimiser's share alone
    last = math.inf
    for n in range(1, 1001, 7):
        extra = variants_s(limit_s, n_targets=n)
        assert 0.0 <= extra <= SHARES.variants_max_s
        assert extra <= last + 1e-12  # fewer targets never get less
        last = extra
        assert optimiser_s(limit_s, n_targets=n) == pytest.approx(share_s + extra)
        if extra > 0:
            assert usable_s(limit_s) - share_s - extra >= rounds_need_s(n) - 1e-9
        else:
            assert pointings_part_s(limit_s, True, n_targets=n) == pointings_part_s(limit_s, True)


def test_programmes_of_250_stars_or_more_get_no_variants_at_the_default_limit() -> None:
    limit_s = programme.DEFAULT_LIMIT_S
    assert variants_s(limit_s, n_targets=150) == SHARES.variants_max_s  # premise: small ones do
    for n in (250, 300, 1000):
        assert variants_s(limit_s, n_targets=n) == 0.0
        assert optimiser_s(limit_s, n_targets=n) == optimiser_s(limit_s)


def test_no_limit_or_no_count_gives_no_variants() -> None:
    assert variants_s(None, n_targets=10) == variants_s(math.inf, n_targets=10) == 0.0
    assert variants_s(120.0) == 0.0


def test_the_needed_limit_holds_the_pointings_with_the_variants_counted() -> None:
    for n, pointings_s in ((40, 20.0), (150, 60.0), (150, 200.0)):
        needed = needed_limit_s(pointings_s, True, n_targets=n)
        assert pointings_part_s(needed, True, n_targets=n) >= pointings_s - 1e-9
        assert pointings_part_s(needed - 1.0, True, n_targets=n) < pointings_s


# ------------------------------------------------------------------------ the searches

PROG = uniform_programme(seed=11, n=40, extent_arcmin=8.0)


def optimised(variants_effort_s: float, base_s: float = 3.0):
    ra, dec, prio = PROG
    with clock.effort():
        return segment_programme(INST, ra, dec, prio, mode="fewest-exposures", seed=4,
                                 budget=Budget.start(base_s + variants_effort_s), variants_s=variants_effort_s)


@pytest.fixture(scope="module")
def with_variants():
    return optimised(6.0)


def key(v: dict) -> tuple[float, int]:
    return v["exposures"] + 0.3 * v["pointings"], v["exposures"]


def test_every_variant_is_searched_when_time_allows_and_the_best_is_kept(with_variants) -> None:
    tried = with_variants.stats["optimiser"]["model_variants"]
    assert [(v["pointing_cost"], v["crowding"]) for v in tried] == [(m.pointing_cost, m.crowding) for m in VARIANTS]
    chosen = [v for v in tried if v["chosen"]]
    assert len(chosen) == 1 and chosen[0]["complete"]
    assert key(chosen[0]) == min(key(v) for v in tried if v["complete"])
    assert key(chosen[0]) <= key(tried[0])  # never more telescope time than the first variant
    st = with_variants.stats["optimiser"]
    assert st["exposures_estimate"] == chosen[0]["exposures"]
    assert len(with_variants.pointings) == chosen[0]["pointings"]
    # complete: a pointing's witness's exposures are the ones counted; one without a witness
    # (its allocation kept no exposure) counts at least one
    witnessed = [p for p in with_variants.pointings if p.allocation is not None]
    assert all(len(p.allocation.configurations) == p.exposures for p in witnessed)
    others = len(with_variants.pointings) - len(witnessed)
    assert chosen[0]["exposures"] >= sum(p.exposures for p in witnessed) + others
    assert others or chosen[0]["exposures"] == sum(p.exposures for p in witnessed)


def test_the_kept_search_partitions_the_programme_inside_each_fov(with_variants) -> None:
    ra, dec, _ = PROG
    members = sorted(i for p in with_variants.pointings for i in p.target_indices)
    assert members == list(range(len(ra)))
    for p in with_variants.pointings:
        m = np.asarray(p.target_indices)
        assert np.all(tangent_radius_mm(ra[m], dec[m], p.ra_deg, p.dec_deg, SCALE) <= FOV_R + 1e-6)


def test_without_time_for_variants_only_the_first_is_searched_and_it_is_the_same(with_variants) -> None:
    alone = optimised(0.0)
    tried = alone.stats["optimiser"]["model_variants"]
    assert len(tried) == 1 and tried[0]["chosen"]
    first = with_variants.stats["optimiser"]["model_variants"][0]
    assert {k: tried[0][k] for k in ("exposures", "pointings", "complete")} == {
        k: first[k] for k in ("exposures", "pointings", "complete")}


def test_the_searches_are_deterministic(with_variants) -> None:
    again = optimised(6.0)
    assert again.stats["optimiser"]["model_variants"] == with_variants.stats["optimiser"]["model_variants"]
    assert [tuple(p.target_indices) for p in again.pointings] == [
        tuple(p.target_indices) for p in with_variants.pointings]


def test_the_rounds_get_the_time_the_variants_did_not_use() -> None:
    share_s = optimiser_s(120.0)
    for n, used_effort_s in ((40, 0.0), (40, 2.0), (150, 100.0), (300, 5.0)):
        extra = min(used_effort_s / SHARES.effort_share, variants_s(120.0, n_targets=n))
        assert programme.rounds_limit_s(120.0, n, used_effort_s) == pytest.approx(120.0 - share_s - extra)
    assert programme.rounds_limit_s(120.0, 150, 0.0) == pytest.approx(120.0 - share_s)  # none used: none lost
    assert programme.rounds_limit_s(120.0, 150, 1e9) == pytest.approx(120.0 - share_s - SHARES.variants_max_s)


def test_the_searches_report_the_effort_the_variants_used(with_variants) -> None:
    st = with_variants.stats["optimiser"]
    assert len(st["model_variants"]) > 1 and 0.0 < st["variants_effort_s"] <= 6.0 + 1e-6
    assert optimised(0.0).stats["optimiser"]["variants_effort_s"] == 0.0


def test_the_cli_summary_names_the_variant_kept_when_it_is_not_the_first() -> None:
    from service.cli import exposures_summary

    def stats(chosen: int) -> dict:
        tried = [{"pointing_cost": v.pointing_cost, "crowding": v.crowding, "exposures": 20 - 2 * i,
                  "pointings": 10 - i, "complete": True, "chosen": i == chosen} for i, v in enumerate(VARIANTS)]
        return {"configurations": 18, "exposures_lower_bound": 13, "segmentation": {"optimiser": {"model_variants": tried}}}

    assert "optimiser" not in exposures_summary(stats(0))
    crowding = exposures_summary(stats(1))
    assert "kept its model with the crowding rows (18 exposures in 9 pointings against 20 in 10" in crowding
    assert "first of 3 searched" in crowding
    dearer = exposures_summary(stats(2))
    assert "with a pointing weighed as 0.6 exposures (16 exposures in 8 pointings" in dearer
    assert "optimiser" not in exposures_summary({"configurations": 3})  # complete linkage: no optimiser
    merged = stats(0)
    merged["segmentation"]["optimiser"]["pointings_merged"] = 2
    assert exposures_summary(merged).endswith("; 2 pointings merged into another that one field of view holds")
    assert "merged" not in exposures_summary(stats(1))


def test_a_commit_that_keeps_no_exposure_estimates_the_exposures_of_its_targets() -> None:
    """With ``fill_min`` above the arms' count and every target held elsewhere, no exposure is
    kept: the pointing keeps the model's targets, no witness, and an estimate of at least
    ⌈observed / arms⌉ (an exposure observes at most one target per arm) and at most one
    exposure per target."""
    from solvers.programme.fill import Field, FillOptions, commit

    ra, dec, prio = PROG
    f = Field(INST, ra, dec, prio)
    centre = (float(np.mean(ra)), float(np.mean(dec)))
    inside = np.flatnonzero(tangent_radius_mm(ra, dec, *centre, SCALE) <= FOV_R - 1.0)
    given = inside[:20]
    todo = np.zeros(len(ra), bool)
    todo[given] = True
    with clock.effort():
        p = commit(f, todo, given, centre, np.ones(len(ra), bool), FillOptions(seed=1, fill_min=13),
                   Budget.start(5.0))
        kept = commit(f, todo, given, centre, np.ones(len(ra), bool), FillOptions(seed=1), Budget.start(5.0))
    assert p.exposures is None and p.allocation is None and sorted(p.members) == sorted(given)
    assert math.ceil(len(given) / INST.n_arms) <= p.estimate <= len(given)
    assert kept.allocation is not None and kept.estimate is None  # premise: the same pointing keeps some
