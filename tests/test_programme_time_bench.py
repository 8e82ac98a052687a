"""benchmarks/programme_time.py: its smoke run reports every programme in every mode the plan
request accepts, names the modes it rejects, and its figures (exposures, ratios to
complete-linkage, totals, medians, completeness, small exposures) are what the returned plans
give when recomputed here from them; the generators keep the original shapes for a seed."""

from __future__ import annotations

import math
import statistics
import sys
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import programme_time as pt  # noqa: E402
from benchmarks import programmes  # noqa: E402

#: the module's tests share its module-scoped plans: one pytest-xdist worker runs them all
pytestmark = pytest.mark.xdist_group("test_programme_time_bench")

ROW_KEYS = {"exposures", "pointings", "exposures_lower_bound", "gap", "targets_bound",
            "pointing_bounds", "allocation_gap",
            "priority_completeness", "field_completeness", "executable",
            "not_observed_by_reason", "telescope_time_s", "wall_s", "limit_s", "elapsed_s",
            "optimiser_s", "optimiser_fraction", "optimiser_own_s", "optimiser_own_fraction", "optimiser_overran", "small_exposures", "small_exposures_only_here",
            "small_exposures_explained", "only_here_flag", "ratio_to_complete_linkage", "valid", "hash_ok", "violations",
            "violation_kinds", "validate_s"}
SUMMARY_KEYS = {"programmes", "errors", "exposures_total", "pointings_total",
                "pointing_bounds_total", "allocation_gap_total",
                "ratio_to_complete_linkage_total", "ratio_to_complete_linkage", "with_bound",
                "gap_median", "gap_max", "within_gap_goal", "executable", "wall_s_median",
                "wall_s_total", "over_limit", "priority_completeness_min", "field_completeness_min",
                "telescope_time_total_s", "optimiser_fraction_median", "optimiser_fraction_max",
                "optimiser_own_fraction_median", "optimiser_own_fraction_max",
                "optimiser_overran", "small_exposures_total", "small_exposures_only_here_total",
                "small_exposures_explained_total", "valid", "bounds_total",
                "bound_ratio_to_complete_linkage_total", "ratio_goal_allows_gap",
                "violations_total"}


@pytest.fixture(scope="module")
def smoke() -> tuple[dict[str, Any], dict[tuple[str, str], dict[str, Any]]]:
    plans: dict[tuple[str, str], dict[str, Any]] = {}
    out = pt.main(["--smoke"], plans=plans)
    return out, plans


def smoke_targets() -> dict[str, list[dict[str, Any]]]:
    """The smoke programmes' targets, drawn again here."""
    return {f"{shape}-{seed}": programmes.programme_targets(
        shape, seed, n_range=pt.SMOKE["n_range"], extent_arcmin=pt.EXTENT_ARCMIN)[0]
        for shape, seed in pt.SMOKE["programmes"]}


def test_the_smoke_run_has_every_programme_and_mode(smoke) -> None:
    out, plans = smoke
    run = out["modes_run"]
    assert run[:2] == ["complete-linkage", "balanced"]
    # a mode the schema does not know yet is reported with the schema's message, not run
    for mode, why in out["modes_rejected"].items():
        assert mode in pt.MODES and mode not in run and "segmentation_mode" in why
    assert set(run) | set(out["modes_rejected"]) == set(pt.MODES)
    assert out["params"]["time_limit_s"] == pt.SMOKE["time_limit_s"]
    names = [r["name"] for r in out["programmes"]]
    assert names == [f"{s}-{k}" for s, k in pt.SMOKE["programmes"]]
    assert set(out["summary"]) == set(run)
    for row in out["programmes"]:
        assert set(row["modes"]) == set(run)
        for mode, res in row["modes"].items():
            assert set(res) == ROW_KEYS, (row["name"], mode)
            assert (row["name"], mode) in plans
            assert res["limit_s"] == pt.SMOKE["time_limit_s"]
            assert res["wall_s"] > 0 and 0 <= res["optimiser_fraction"] < 1
            assert 0 <= res["optimiser_own_fraction"] <= res["optimiser_fraction"]
            seg = plans[(row["name"], mode)]["stats"]["segmentation"]
            assert res["optimiser_own_s"] == round(seg.get("own_time_s", seg["time_s"]), 4)
    for s in out["summary"].values():
        assert set(s) == SUMMARY_KEYS and s["programmes"] == len(names) and s["errors"] == 0
        assert s["valid"] == s["programmes"] and s["violations_total"] == 0


def test_each_figure_is_what_its_plan_gives(smoke) -> None:
    out, plans = smoke
    targets = smoke_targets()
    for row in out["programmes"]:
        prio = {t["id"]: t["priority"] for t in targets[row["name"]]}
        assert row["n"] == len(prio)
        for mode, res in row["modes"].items():
            plan = plans[(row["name"], mode)]
            configs = [c for p in plan["pointings"] for c in p["configurations"]]
            observed = [[a["target_id"] for a in c["assignments"] if a["target_id"] is not None]
                        for c in configs]
            seen = {t for obs in observed for t in obs}
            assert res["exposures"] == len(configs) == plan["stats"]["configurations"]
            assert res["pointings"] == len(plan["pointings"])
            assert res["valid"] and res["hash_ok"] and res["violations"] == 0  # every plan re-checks
            assert res["executable"] == all(p["executable"] for p in plan["pointings"])
            assert res["small_exposures"] == sum(len(obs) <= 2 for obs in observed)
            few = plan["few_target_exposures"]
            assert res["small_exposures_only_here"] <= res["small_exposures_explained"] == sum(
                {o["target_id"] for o in f["only_here"]} >= set(f["target_ids"]) for f in few)
            assert res["field_completeness"] == pytest.approx(len(seen) / len(prio), abs=1e-4)
            assert res["priority_completeness"] == pytest.approx(
                sum(prio[t] for t in seen) / sum(prio.values()), abs=1e-4)
            assert res["targets_bound"] == math.ceil(len(prio) / 12)
            # each pointing's proven least, recomputed: no plan of it takes fewer exposures
            least = []
            for p in plan["pointings"]:
                seen_here = {t for c in p["configurations"] for t in
                             (a["target_id"] for a in c["assignments"]) if t is not None}
                alloc = p["stats"].get("allocation") or {}
                proven = alloc.get("lower_bound_configurations_proven")
                ok = isinstance(proven, int) and alloc.get("n_allocated") == len(seen_here)
                least.append(max(math.ceil(len(seen_here) / 12), proven if ok else 0))
                assert least[-1] <= len(p["configurations"]) and pt.pointing_bound(p) == least[-1]
            assert res["pointing_bounds"] == sum(least)
            assert res["allocation_gap"] == res["exposures"] - sum(least) >= 0
            bound = plan["stats"].get("exposures_lower_bound")
            if res["exposures_lower_bound"] is None:
                assert res["gap"] is None
            else:
                assert bound is not None and res["exposures"] >= res["exposures_lower_bound"]
                assert res["gap"] == pytest.approx(res["exposures"] / res["exposures_lower_bound"],
                                                   abs=1e-4)
            assert res["optimiser_s"] == pytest.approx(
                plan["stats"]["segmentation"]["time_s"], abs=1e-4)
            assert res["optimiser_fraction"] == pytest.approx(
                res["optimiser_s"] / res["wall_s"], abs=2e-3)
            optimiser = plan["stats"]["segmentation"].get("optimiser") or {}
            assert res["optimiser_overran"] == bool(optimiser.get("overran", False))
            base = len([c for p in plans[(row["name"], pt.BASELINE)]["pointings"]
                        for c in p["configurations"]])
            assert res["ratio_to_complete_linkage"] == pytest.approx(len(configs) / base, abs=1e-4)


def test_the_summary_adds_up(smoke) -> None:
    out, plans = smoke
    names = [r["name"] for r in out["programmes"]]

    def exposures(name: str, mode: str) -> int:
        return sum(len(p["configurations"]) for p in plans[(name, mode)]["pointings"])

    for mode, s in out["summary"].items():
        rows = [r["modes"][mode] for r in out["programmes"]]
        total = sum(exposures(n, mode) for n in names)
        assert s["exposures_total"] == total
        assert s["pointings_total"] == sum(len(plans[(n, mode)]["pointings"]) for n in names)
        assert s["pointing_bounds_total"] == sum(r["pointing_bounds"] for r in rows)
        assert s["allocation_gap_total"] == total - s["pointing_bounds_total"]
        assert s["ratio_to_complete_linkage_total"] == pytest.approx(
            total / sum(exposures(n, pt.BASELINE) for n in names), abs=1e-4)
        assert s["ratio_to_complete_linkage"] == pytest.approx(
            [exposures(n, mode) / exposures(n, pt.BASELINE) for n in names], abs=1e-4)
        assert s["executable"] == sum(plans[(n, mode)]["executable"] for n in names)
        assert s["wall_s_median"] == pytest.approx(statistics.median(r["wall_s"] for r in rows))
        assert s["over_limit"] == sum(r["wall_s"] > r["limit_s"] for r in rows)
        assert s["small_exposures_total"] == sum(r["small_exposures"] for r in rows)
        assert s["small_exposures_explained_total"] == sum(r["small_exposures_explained"] for r in rows)
        gaps = [r["gap"] for r in rows if r["gap"] is not None]
        assert s["with_bound"] == len(gaps)
        assert s["gap_median"] == (statistics.median(gaps) if gaps else None)
    assert out["summary"][pt.BASELINE]["ratio_to_complete_linkage_total"] == 1.0


def test_the_bound_ratio_is_the_plans_bounds_over_complete_linkage_and_no_plan_beats_it(smoke) -> None:
    out, plans = smoke
    names = [r["name"] for r in out["programmes"]]
    base = sum(len(p["configurations"]) for n in names for p in plans[(n, pt.BASELINE)]["pointings"])
    fe = out["summary"]["fewest-exposures"]
    bounds = [pt.bound_of(plans[(n, "fewest-exposures")]["stats"]["exposures_lower_bound"]) for n in names]
    assert all(isinstance(b, int) and b > 0 for b in bounds)
    assert fe["bounds_total"] == sum(bounds)
    assert fe["bound_ratio_to_complete_linkage_total"] == pytest.approx(sum(bounds) / base, abs=1e-4)
    assert fe["ratio_goal_allows_gap"] == pytest.approx(pt.RATIO_GOAL * base / sum(bounds), abs=1e-4)
    for s in out["summary"].values():  # a proven bound: no plan of any mode takes fewer
        assert s["ratio_to_complete_linkage_total"] >= fe["bound_ratio_to_complete_linkage_total"]
    assert out["summary"][pt.BASELINE]["bound_ratio_to_complete_linkage_total"] is None  # no bound


def test_a_mode_the_schema_rejects_is_named_with_its_message() -> None:
    ok, rejected = pt.check_modes(["balanced", "no-such-mode"])
    assert ok == ["balanced"]
    assert set(rejected) == {"no-such-mode"} and "segmentation_mode" in rejected["no-such-mode"]


def test_small_exposures_count_the_only_here_flag_when_the_plan_has_one() -> None:
    def conf(ids: list[str], **flag: Any) -> dict[str, Any]:
        return {"assignments": [{"arm": i, "target_id": t} for i, t in enumerate(ids)]
                + [{"arm": 11, "target_id": None}], "stats": {}, **flag}

    unflagged = {"pointings": [{"configurations": [conf(["a"]), conf(["b", "c", "d"])]}]}
    assert pt.small_exposures(unflagged) == {
        "small_exposures": 1, "small_exposures_only_here": None, "only_here_flag": None}
    flagged = {"pointings": [{"configurations": [
        conf(["a"], only_here=True), conf(["b", "c"], only_here=False),
        conf(["e", "f"], only_here=["e", "f"]), conf(["g", "h"], only_here=["g"]),
        conf(["b", "c", "d"], only_here=False)]}]}
    assert pt.small_exposures(flagged) == {
        "small_exposures": 4, "small_exposures_only_here": 2, "only_here_flag": "only_here"}
    assert pt.bound_of(7) == 7 and pt.bound_of({"exposures": 5}) == 5 and pt.bound_of(None) is None


def test_the_original_shapes_are_unchanged_and_the_new_ones_in_range() -> None:
    # benchmarks/programmes.py's shapes at its defaults, as drawn before two-clump was added
    pinned = {
        "cluster": (192, {"core_arcmin": 1.38}, (317.13599204, 38.523219191, 10)),
        "cluster-halo": (180, {"halo_radius_arcmin": 5.64}, (315.524765848, 43.846301335, 1)),
        "clumps": (85, {"spread_arcmin": 12.67}, (164.36463723, 47.378753477, 100)),
        "scattered": (157, {"side_arcmin": 14.19}, (21.986084674, -11.427719677, 100)),
    }
    for shape, (n, params, first) in pinned.items():
        targets, got = programmes.programme_targets(shape, 7)
        assert got["n"] == len(targets) == n and params.items() <= got.items()
        t = targets[0]
        assert (t["ra_deg"], t["dec_deg"], t["priority"]) == pytest.approx(first, abs=1e-8)
    for shape in pt.SHAPES:
        for seed in range(3):
            a, pa = programmes.programme_targets(shape, seed, n_range=pt.N_RANGE,
                                                 extent_arcmin=pt.EXTENT_ARCMIN)
            assert (a, pa) == programmes.programme_targets(shape, seed, n_range=pt.N_RANGE,
                                                           extent_arcmin=pt.EXTENT_ARCMIN)
            assert 50 <= len(a) <= 300
            dec = [t["dec_deg"] for t in a]
            assert (max(dec) - min(dec)) * 60 <= 15.0 + 1e-6


def test_targets_sets_the_generated_programmes_size_and_is_checked(capsys) -> None:
    progs = pt.generated([(shape, 5) for shape in pt.SHAPES], n_range=(300, 300))
    assert [len(p["targets"]) for p in progs] == [300] * len(pt.SHAPES)
    assert all(p["params"]["n"] == 300 for p in progs)
    with pytest.raises(SystemExit):
        pt.main(["--targets", "300", "200", "--n", "1"])
    assert "--targets" in capsys.readouterr().err
