"""One default exact engine everywhere (issue 39, item 7): the customer's engine (CP-SAT or
HiGHS), set once in ``solvers.allocation.options.DEFAULT_SOLVER``, read by the library, the
API schema, the CLI and the page (through the served /openapi.json); its answers equal the
branch-and-bound's and a brute-force oracle's; it starts from the branch-and-bound dive."""

from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.instrument import default_instrument
from models.types import PlaneTargets
from solvers.allocation import allocate
from solvers.allocation.backends import get_backend
from solvers.allocation.options import DEFAULT_SOLVER, SOLVERS, AllocationOptions
from tests.test_ilp import _field, _oracle, _problem

INS = default_instrument()


def test_the_default_is_the_customers_engine_and_bnb_stays_available() -> None:
    from service.schemas import PlanRequest

    assert DEFAULT_SOLVER in ("cpsat", "highs")
    assert "bnb" in SOLVERS
    req = PlanRequest.model_validate({"targets": [{"id": "a", "ra_deg": 10.0, "dec_deg": 5.0, "priority": 1}],
                                      "solver": "bnb"})
    assert req.solver == "bnb"


def test_library_entry_points_default_to_it() -> None:
    from planner.programme import PointingOptions
    from solvers.programme import FillOptions

    assert inspect.signature(allocate).parameters["solver"].default == DEFAULT_SOLVER
    assert PointingOptions().solver == DEFAULT_SOLVER
    assert FillOptions().solver == DEFAULT_SOLVER


def test_api_cli_and_page_read_the_same_default(tmp_path: Path) -> None:
    """The request models, the CLI's parsed default and its help, and the default the page
    reads: PlanRequest.solver in the served /openapi.json (service/static/form.js)."""
    from service.app import create_app
    from service.cli import build_parser
    from service.schemas import AllocationRequest, PlanRequest
    from service.settings import Settings

    assert PlanRequest.model_fields["solver"].default == DEFAULT_SOLVER
    assert AllocationRequest.model_fields["solver"].default == DEFAULT_SOLVER
    parser = build_parser()
    assert parser.parse_args(["plan", "t.csv", "--out", str(tmp_path)]).solver == DEFAULT_SOLVER
    assert parser.parse_args(["plan", "t.csv", "--out", str(tmp_path), "--solver", "bnb"]).solver == "bnb"
    plan_parser = next(a for a in parser._subparsers._group_actions[0].choices.values()  # noqa: SLF001
                       if any(o.dest == "solver" for o in a._actions))  # noqa: SLF001
    solver_help = next(o.help for o in plan_parser._actions if o.dest == "solver")  # noqa: SLF001
    assert "%(default)s" in solver_help and f"default: {DEFAULT_SOLVER}" in plan_parser.format_help()
    with TestClient(create_app(Settings(job_db=tmp_path / "jobs.db"))) as client:
        doc = client.get("/openapi.json").json()
    schemas = doc["components"]["schemas"]
    assert schemas["PlanRequest"]["properties"]["solver"]["default"] == DEFAULT_SOLVER
    assert schemas["AllocationRequest"]["properties"]["solver"]["default"] == DEFAULT_SOLVER


def _targets(x: np.ndarray, y: np.ndarray, pr: np.ndarray) -> PlaneTargets:
    return PlaneTargets(tuple(f"t{i}" for i in range(len(x))), np.asarray(x, float), np.asarray(y, float),
                        np.asarray(pr, np.int64))


@pytest.mark.parametrize("seed", range(6))
def test_default_engine_finds_the_brute_force_and_bnb_optimum(seed: int) -> None:
    """One configuration on 5-8 targets: the default engine's total priority equals the
    brute-force oracle's (conflicts from geometry, tests.test_ilp._oracle) and bnb's."""
    rng = np.random.default_rng(900 + seed)
    n = 5 + seed % 4
    x, y = _field(rng, n, radius=50.0 + 10.0 * seed)
    pr = rng.choice([500, 100, 10, 1], size=n)
    best = _oracle(x, y, pr)
    default = allocate(INS, _targets(x, y, pr), configurations="one", time_limit_s=60.0, seed=seed)
    bnb = allocate(INS, _targets(x, y, pr), solver="bnb", configurations="one", time_limit_s=60.0, seed=seed)
    (c,), (b,) = default.configurations, bnb.configurations
    assert c.status == "optimal"
    assert c.total_priority == best == b.total_priority


@pytest.mark.parametrize("seed", range(3))
def test_default_sequence_observes_what_bnb_observes(seed: int) -> None:
    """To completeness on 8 targets: the default engine's sequence observes the same total
    priority as bnb's, every target's (the post-passes may rebuild a configuration, so the
    per-configuration optimum is checked on one configuration above)."""
    rng = np.random.default_rng(950 + seed)
    x, y = _field(rng, 8, radius=30.0)
    pr = rng.choice([500, 100, 10, 1], size=8)
    # 20 s: both sequences are complete well within it (the packing post-pass then looks for
    # fewer configurations for a share of the limit)
    default = allocate(INS, _targets(x, y, pr), configurations="all", time_limit_s=20.0, seed=seed)
    bnb = allocate(INS, _targets(x, y, pr), solver="bnb", configurations="all", time_limit_s=20.0, seed=seed)

    def observed(res) -> int:
        return sum(c.total_priority for c in res.configurations)

    assert observed(default) == observed(bnb) == int(pr.sum())
    assert default.stats["field_completeness"] == bnb.stats["field_completeness"] == 1.0


def test_default_engine_starts_from_the_bnb_dive() -> None:
    """The staged model's start is the branch-and-bound dive's incumbent, and its stats say
    so, whether or not the engine is needed to prove stage 1; a caller's hint is named as such."""
    rng = np.random.default_rng(11)
    x, y = _field(rng, 40, radius=110.0)
    pr = rng.choice([500, 100, 10, 1], size=40)
    res = allocate(INS, _targets(x, y, pr), configurations="one", time_limit_s=30.0)
    assert res.configurations[0].stats["incumbent"] == "bnb"
    backend = get_backend(DEFAULT_SOLVER)
    p = _problem(x, y, pr)
    first = backend.solve(p, AllocationOptions().engine_for(DEFAULT_SOLVER))
    again = backend.solve(p, AllocationOptions().engine_for(DEFAULT_SOLVER), hint=first.chosen)
    assert first.stats["incumbent"] == "bnb" and first.stats["hint"] is True and "incumbent_s" in first.stats
    assert first.stats["incumbent_coarse"] > 0 and again.stats["incumbent"] == "caller"
    assert again.total_priority == first.total_priority


def test_cpsat_hints_are_complete_and_it_runs_at_least_two_workers(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every CP-SAT stage model carries a hint on every variable (x_l of the longest-move
    stage too: OR-Tools 9.15's interleaved search can abort on a partial hint), and a
    problem asking for one thread still gets two workers (one can stall)."""
    import dataclasses

    from solvers.allocation import cpsat

    seen: list[tuple[int, int, int]] = []
    real = cpsat.cpsat_solve

    def spy(solver, model, time_limit_s):
        proto = model.Proto()
        seen.append((len(proto.variables), len(proto.solution_hint.vars), int(solver.parameters.num_workers)))
        return real(solver, model, time_limit_s)

    rng = np.random.default_rng(3)
    x, y = _field(rng, 30, radius=100.0)
    pr = rng.choice([500, 100, 10, 1], size=30)
    p = dataclasses.replace(_problem(x, y, pr), threads=1)
    start = get_backend("bnb").solve(p, AllocationOptions().engine_for("bnb")).chosen
    monkeypatch.setattr(cpsat, "cpsat_solve", spy)
    sol = cpsat.solve_ilp_cpsat(p, staged=False, hint=start)
    assert sol.status == "optimal" and len(seen) >= 2  # priority, then the longest move (x_l too)
    for n_vars, n_hinted, workers in seen:
        assert n_hinted == n_vars and workers >= 2
    # the staged solve: a model has the whole hint or none (a move-threshold probe the hint breaks)
    seen.clear()
    get_backend("cpsat").solve(p, AllocationOptions().engine_for("cpsat"))
    assert all(n_hinted in (0, n_vars) and workers >= 2 for n_vars, n_hinted, workers in seen)


def test_a_warm_worker_loads_no_engine_library_inside_a_plan() -> None:
    """``pipeline.warm_up`` (what every worker runs at its start) loads the libraries of the
    default plan's engines: a fewest-exposures plan run after it imports none of them, so no
    plan's budget pays for their loading. Without the warm-up the same plan does (which is
    what makes the check able to fail)."""
    root = Path(__file__).resolve().parents[1]
    code = (
        "import json, sys\n"
        "from service import pipeline\n"
        "from service.schemas import PlanRequest\n"
        "if sys.argv[1] == 'warm':\n"
        "    pipeline.warm_up()\n"
        "before = set(sys.modules)\n"
        "stars = [{'id': f's{i}', 'ra_deg': 132.8 + 0.01 * (i % 5), 'dec_deg': 11.8 + 0.01 * (i // 5),\n"
        "          'priority': 1 + i % 3} for i in range(15)]\n"
        "req = PlanRequest.model_validate({'targets': stars, 'seed': 1, 'time_limit_s': 30,\n"
        "                                  'segmentation_mode': 'fewest-exposures'})\n"
        "plan = pipeline.plan(req, pipeline.instrument_from(None))\n"
        "assert plan['executable'], plan\n"
        "print(json.dumps(sorted(m for m in set(sys.modules) - before\n"
        "                        if m.split('.')[0] in ('ortools', 'highspy', 'pandas'))))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(root)}
    loaded = {}
    for mode in ("warm", "cold"):
        r = subprocess.run([sys.executable, "-c", code, mode], cwd=root, env=env, capture_output=True,
                           text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        loaded[mode] = json.loads(r.stdout.strip().splitlines()[-1])
    assert loaded["warm"] == []
    assert "ortools.sat.python.cp_model" in loaded["cold"] and "highspy" in loaded["cold"]
