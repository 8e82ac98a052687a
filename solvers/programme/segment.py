"""One entry point for every segmentation mode of a programme: the thesis' complete linkage,
"balanced" (:func:`solvers.segmentation.segment_field`) and "fewest-exposures", the programme
optimiser (:func:`solvers.programme.optimiser.optimise`), which also needs the priorities,
the instrument and the allocation the plan will run."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from models.budget import Budget
from models.errors import InputError
from models.instrument import Instrument
from solvers.programme.angle import AngleSearch, choose_angle
from solvers.programme.fill import FillOptions
from solvers.programme.optimiser import (
    OptimisedPointing,
    OptimiserOptions,
    ProgrammeResult,
    optimise,
)
from solvers.segmentation.field import (
    MODES,
    Segmentation,
    checked_pointings,
    field_plane,
    member_stats,
    segment_field,
)

__all__ = ["MAX_TARGETS", "MODES", "searched_angles", "segment_programme"]

#: the programme optimiser plans programmes of at most this many targets (its candidates
#: grow with the pairs of targets closer than a FOV diameter)
MAX_TARGETS = 1_000


def segment_programme(inst: Instrument, ra_deg, dec_deg, priority, *, mode: str = "complete-linkage",
                      threshold_mm: float | None = None, tangent_point: tuple[float, float] | None = None,
                      seed: int = 0, fill: FillOptions | None = None, budget: Budget | None = None,
                      mode_field: str = "mode", variants_s: float = 0.0) -> Segmentation:
    """The programme's pointings in ``mode`` (one of :data:`MODES`; ``threshold_mm`` is the
    complete linkage's, checked in every mode). ``fill``: how the plan
    allocates a pointing (the optimiser's feedback allocates the same way); ``budget``: the
    optimiser's (default: 10 s on the caller's clock), of which the last ``variants_s`` are for
    its model's other variants (:data:`solvers.programme.optimiser.VARIANTS`). With ``fill.angle_search`` (the
    request's "auto") every pointing of every mode takes its best angle of that search
    (:func:`solvers.programme.angle.choose_angle`; in mode "fewest-exposures" before its
    allocation feedback). Raises InputError naming the field (``mode_field`` for the mode)."""
    if mode not in MODES:
        raise InputError(mode_field, f"must be one of {', '.join(repr(m) for m in MODES)}, got {mode!r}")
    R, scale = float(inst.fov_radius_mm), float(inst.plate_scale_arcsec_per_mm)
    if mode != "fewest-exposures":
        seg = segment_field(ra_deg, dec_deg, threshold_mm=threshold_mm, tangent_point=tangent_point,
                            fov_radius_mm=R, plate_scale_arcsec_per_mm=scale, mode=mode, seed=seed)
        if fill is None or fill.angle_search is None:
            return seg
        return searched_angles(inst, seg, ra_deg, dec_deg, priority, fill.angle_search, fill.park_move_limit_s,
                               fill.arm_limits)
    if len(np.atleast_1d(ra_deg)) > MAX_TARGETS:
        raise InputError(mode_field, f"'fewest-exposures' plans programmes of at most {MAX_TARGETS:,} "
                         f"targets (this one has {len(np.atleast_1d(ra_deg)):,}): use 'balanced'")
    budget = Budget.start(10.0) if budget is None else budget
    ra, dec, _, tangent, xy = field_plane(ra_deg, dec_deg, threshold_mm=threshold_mm, tangent_point=tangent_point,
                                          fov_radius_mm=R, plate_scale_arcsec_per_mm=scale)
    prio = np.asarray(priority, dtype=np.int64)
    if prio.shape != ra.shape:
        raise InputError("priority", f"expected {ra.size} priorities, got shape {prio.shape}")
    opts = OptimiserOptions(fill=FillOptions(seed=int(seed)) if fill is None else fill)
    t0 = time.perf_counter()
    result = optimise(inst, ra, dec, prio, tangent, xy, opts, budget, variants_s)
    seg = _segmentation(result, ra, dec, tangent, R, scale, time.perf_counter() - t0)
    if opts.fill.angle_search is None:
        return seg
    return searched_angles(inst, seg, ra, dec, prio, opts.fill.angle_search, opts.fill.park_move_limit_s,
                           opts.fill.arm_limits)


def searched_angles(inst: Instrument, seg: Segmentation, ra_deg, dec_deg, priority, search: AngleSearch,
                    park_move_limit_s: float | None, arm_limits: Sequence[int] | None = None) -> Segmentation:
    """``seg`` with every pointing not yet searched at its best angle of ``search``, about its
    own centre, on its members (:func:`solvers.programme.angle.choose_angle`); a pointing the
    programme optimiser already turned (its allocation is at that angle) keeps its angle.
    ``arm_limits``: per target, the bit mask of the arms it may use (its lock), or None."""
    limits = None if arm_limits is None else np.asarray(arm_limits, np.int64)
    ra, dec = np.asarray(ra_deg, float), np.asarray(dec_deg, float)
    prio = np.broadcast_to(np.asarray(priority, np.int64), ra.shape)
    pointings = []
    for p in seg.pointings:
        if p.position_angle_search is None and p.allocation is None and p.target_indices:
            idx = np.asarray(p.target_indices, np.int64)
            c = choose_angle(inst, ra[idx], dec[idx], prio[idx], (p.ra_deg % 360.0, p.dec_deg), search,
                             park_move_limit_s, None if limits is None else limits[idx])
            p = replace(p, position_angle_deg=c.chosen_deg, position_angle_search=c)
        pointings.append(p)
    return replace(seg, pointings=tuple(pointings))


def _segmentation(result: ProgrammeResult, ra, dec, tangent, R, scale, wall_s: float) -> Segmentation:
    """The optimiser's pointings as a :class:`Segmentation`, after the guarantees every mode
    gives (:func:`solvers.segmentation.field.checked_pointings`)."""
    groups = [np.asarray(p.members, dtype=np.int64) for p in result.pointings]
    pra = np.array([p.ra_deg for p in result.pointings])
    pdec = np.array([p.dec_deg for p in result.pointings])
    extras = [{"position_angle_deg": _reported_angle(p), "exposures": p.exposures,
               "only_here": tuple(sorted(p.only_here)), "allocation": p.allocation,
               "allocation_final": p.allocation_final,
               "position_angle_search": p.position_angle_search} for p in result.pointings]
    pointings = checked_pointings(groups, pra, pdec, ra, dec, tangent, R, scale, extras)
    b = result.bound
    stats = {"mode": "fewest-exposures", "n_targets": len(ra), "n_pointings": len(pointings),
             "fov_radius_mm": R, **member_stats(pointings),
             "exposures_lower_bound": b.exposures,
             "bound": {"exposures": b.exposures, "trivial": b.trivial, "components": b.components,
                       "weight": b.weight, "method": b.method},
             "optimiser": result.stats, "time_s": wall_s, **_time_split(result, wall_s)}
    return Segmentation(float(tangent[0]), float(tangent[1]), pointings, stats)


def _time_split(result: ProgrammeResult, wall_s: float) -> dict[str, float]:
    """The optimiser's wall seconds split: ``allocations_kept_s``, those of the allocations
    the plan observes as they are (``allocation_final``: the plan allocates those pointings
    no more, so this is the plan's allocation, done in the optimiser), and ``own_time_s``, the
    rest (its model, bound, candidates, the allocations it did not keep or the plan allocates
    again, its consolidation and merges); ``pointings_allocated_once``, the pointings the plan
    does not allocate again."""
    final = [p for p in result.pointings if p.allocation_final]
    kept_s = min(sum(p.allocation_s for p in final), wall_s)
    return {"allocations_kept_s": kept_s, "own_time_s": wall_s - kept_s, "pointings_allocated_once": len(final)}


def _reported_angle(p: OptimisedPointing) -> float:
    """A pointing's angle as the search chose it (inside the request's range, e.g. -15), the
    optimiser's angle in [0, 360) when no range search chose it (the same rotation)."""
    c = p.position_angle_search
    if c is not None and c.scores:
        return float(c.chosen_deg)
    return float(p.position_angle_deg)
