"""Top-level allocate(): option validation, back-end dispatch, position-angle search."""

from __future__ import annotations

import numpy as np
import pytest

from models.errors import InputError
from models.instrument import default_instrument
from models.types import PlaneTargets
from solvers.allocation import (
    AllocationOptions,
    BnbOptions,
    CpsatOptions,
    HighsOptions,
    PackingOptions,
    RepairOptions,
    SemiGreedyOptions,
    SequenceOptions,
    allocate,
    backend_names,
    get_backend,
)

INS = default_instrument()
T = PlaneTargets.from_lists([f"t{i}" for i in range(20)], np.linspace(-80, 80, 20), np.linspace(60, -60, 20),
                            [500, 100, 10, 1] * 5)


@pytest.mark.parametrize("kw,field", [
    ({"method": "magic"}, "method"), ({"solver": "gurobi"}, "solver"), ({"configurations": "some"}, "configurations"),
    ({"time_limit_s": -1}, "time_limit_s"), ({"collision_buffer_mm": -2.0}, "collision_buffer_mm"),
    ({"start_q": np.zeros((3, 2))}, "start_q"), ({"fixed": {99: (0.0, 0.0)}}, "fixed[99]"),
])
def test_invalid_options_name_the_field(kw, field) -> None:
    with pytest.raises(InputError) as e:
        allocate(INS, T, **kw)
    assert e.value.field == field


@pytest.mark.parametrize("make,field", [
    (lambda: HighsOptions(form="triangular"), "form"), (lambda: CpsatOptions(workers=0), "workers"),
    (lambda: BnbOptions(node_limit=0), "node_limit"), (lambda: BnbOptions(fallback="gurobi"), "fallback"),
    (lambda: SequenceOptions(config_time_limit_s=float("nan")), "config_time_limit_s"),
    (lambda: SequenceOptions(max_configurations=0), "max_configurations"),
    (lambda: SequenceOptions(tie_break="sometimes"), "tie_break"),
    (lambda: PackingOptions(lp_bound_time_limit_s=-1.0), "packing.lp_bound_time_limit_s"),
    (lambda: RepairOptions(time_limit_s=0.0), "repair.time_limit_s"),
    (lambda: AllocationOptions(engine="bnb"), "options.engine"),
])
def test_option_dataclasses_validate_once_naming_the_field(make, field) -> None:
    with pytest.raises(InputError) as e:
        make()
    assert e.value.field == field


@pytest.mark.parametrize("solver", ["highs", "cpsat"])
def test_one_configuration_both_solvers_agree(solver) -> None:
    r = allocate(INS, T, solver=solver, configurations="one", time_limit_s=120.0)
    assert len(r.configurations) == 1
    ref = allocate(INS, T, solver="cpsat", configurations="one", time_limit_s=120.0)
    if r.configurations[0].status == ref.configurations[0].status == "optimal":
        assert r.configurations[0].total_priority == ref.configurations[0].total_priority


def test_all_configurations_and_position_angle_search() -> None:
    r = allocate(INS, T, configurations="all", position_angles_deg=(0.0, 15.0), time_limit_s=600.0)
    assert r.stats["field_completeness"] == 1.0
    assert r.stats["position_angle_deg"] in (0.0, 15.0)
    assert len(r.stats["position_angle_search"]) == 2


def test_every_registered_backend_resolves_with_its_own_options() -> None:
    """Each registry name gives the back-end of that name; a foreign option set is refused
    naming ``options.engine``; an unknown name is a KeyError naming the known ones."""
    for name in backend_names():
        b = get_backend(name)
        assert b.name == name and b.options_type in {BnbOptions, HighsOptions, CpsatOptions, SemiGreedyOptions}
    with pytest.raises(KeyError, match="known"):
        get_backend("gurobi")
    with pytest.raises(InputError) as e:
        allocate(INS, T, solver="highs", options=AllocationOptions(engine=CpsatOptions(workers=3)))
    assert e.value.field == "options.engine"


def test_semigreedy_fast_path_defaults() -> None:
    """method="semigreedy" runs with blank-sky rests by default (park only on request); the
    exact method keeps park-only rests; the repair budget is validated by name."""
    r = allocate(INS, T, method="semigreedy", configurations="all", time_limit_s=600.0)
    assert r.stats["field_completeness"] == 1.0
    n_sg = r.stats["incompatibility"]["assignments"]
    e = allocate(INS, T, configurations="all", time_limit_s=600.0)
    n_exact = e.stats["incompatibility"]["assignments"]
    assert n_sg == n_exact + 16 * INS.n_arms  # 16 blank-sky rests per arm
    r2 = allocate(INS, T, method="semigreedy", configurations="all", time_limit_s=600.0,
                  options=AllocationOptions(sequence=SequenceOptions(blank_per_arm=0)))
    assert r2.stats["incompatibility"]["assignments"] == n_exact
    with pytest.raises(InputError) as err:
        allocate(INS, T, method="semigreedy", options=AllocationOptions(repair=RepairOptions(time_limit_s=-1.0)))
    assert err.value.field == "repair.time_limit_s"


def test_targets_left_by_one_configuration_are_not_scheduled() -> None:
    """With configurations "one", the reachable targets outside the configuration are left for
    configurations the request did not ask for ("not_scheduled"), not "conflict"; the whole
    sequence of the same field observes them all."""
    far = PlaneTargets.from_lists([*T.ids, "far"], [*T.x_mm, 400.0], [*T.y_mm, 0.0], [*T.priority, 500])
    one = allocate(INS, far, configurations="one", time_limit_s=60.0)
    left = {u.target_id: u.reason for u in one.unallocated}
    assert left.pop("far") == "unreachable"
    assert len(left) >= len(T) - INS.n_arms and set(left.values()) == {"not_scheduled"}
    every = allocate(INS, far, configurations="all", time_limit_s=120.0)
    assert {u.target_id: u.reason for u in every.unallocated} == {"far": "unreachable"}


def test_sequencing_defaults_resolve_by_method_and_mode() -> None:
    """The "one" mode is exactly one configuration with the call's whole limit and no adaptive
    share; the semi-greedy fast path fills only what the caller left unset; a sequence caps
    each solve at min(call limit, 5 s)."""
    one = AllocationOptions().sequencing("one", 30.0)
    assert (one.sequence.max_configurations, one.sequence.config_time_limit_s, one.sequence.adaptive_limits) \
        == (1, 30.0, False)
    assert one.packing.enabled is True and one.repair.time_limit_s == 5.0 and one.sequence.blank_per_arm == 0
    seq = AllocationOptions(sequence=SequenceOptions(max_configurations=4)).sequencing("all", 3.0)
    assert (seq.sequence.max_configurations, seq.sequence.config_time_limit_s, seq.sequence.adaptive_limits) \
        == (4, 3.0, True)
    sg = AllocationOptions(packing=PackingOptions(enabled=True)).sequencing(
        "all", 60.0, get_backend("semigreedy").sequencing)
    assert sg.packing.enabled is True  # the caller's choice wins over the fast path
    assert (sg.sequence.tie_break, sg.sequence.blank_per_arm, sg.repair.time_limit_s) == (False, 16, 0.5)
    assert sg.sequence.config_time_limit_s == 5.0


def test_exact_engines_hold_back_a_quarter_for_the_post_passes() -> None:
    """HiGHS and CP-SAT sequences keep 25 % of the call from the greedy loop (their solves
    use the whole share they get); bnb and the semi-greedy path keep the driver's 10 %; the
    caller's value wins; a bad one is refused naming the field."""
    def reserve(opts: AllocationOptions, engine: str | None) -> float:
        defaults = None if engine is None else get_backend(engine).sequencing
        return opts.sequencing("all", 20.0, defaults).sequence.reserve_fraction

    for engine, want in (("highs", 0.25), ("cpsat", 0.25), ("bnb", 0.1), (None, 0.1)):
        assert reserve(AllocationOptions(), engine) == want
    assert reserve(AllocationOptions(), "semigreedy") == 0.1
    mine = AllocationOptions(sequence=SequenceOptions(reserve_fraction=0.05))
    assert reserve(mine, "highs") == 0.05
    for bad in (1.0, -0.1, True, "0.2"):
        with pytest.raises(InputError, match="reserve_fraction"):
            SequenceOptions(reserve_fraction=bad)


def test_the_reserve_shrinks_each_share() -> None:
    """A configuration's adaptive limit is twice its share of what is left after the reserve."""
    from models.budget import Budget
    from solvers.sequencing.shares import SHARES

    c = Budget(start_s=0.0, deadline_s=20.0, total_s=20.0)
    for reserve, want in ((0.1, 2 * (20.0 - 2.0) / 10), (0.25, 2 * (20.0 - 5.0) / 10)):
        got = SHARES.config_limit_s(20.0, c, 120, 12, 5.0, True, reserve)
        assert got == pytest.approx(want)
    assert SHARES.config_limit_s(20.0, c, 120, 12, 5.0, False, 0.25) == 5.0
