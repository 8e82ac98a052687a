"""The position angle search a request asks for with ``position_angle_deg: "auto"``: every
pointing takes, of the angles of a range at a step, the one that serves its members best.

The objective, compared in this order (each later key breaks the ties of the ones before):

1. the fewest members out of every arm's reach within the park move limit (the targets the
   angle loses; :func:`solvers.programme.reach.arm_masks`);
2. the fewest exposures by the programme model's bound on arm reach (rows (2) and (5) of
   docs/programme.md): at least ⌈reached / arms⌉, and for every window of ``w`` = 1 … 4
   neighbouring arms, ⌈members only that window reaches / w⌉;
3. the highest summed priority of the members reached;
4. the angle nearest the range's centre (any angle: nearest 0°, on the circle);
5. the smaller angle.

When the best angles of that grid still lose members, the angles within one step of them are
tried every 0.5° (:func:`refined_angles`): several rim members can leave an arc of angles
that reaches them all narrower than the step.

Each angle costs one reachability evaluation of the pointing's members (the allocation is not
run per angle), about a millisecond for a hundred members, so the angles are scored in turn
and the search is deterministic: the same members and options give the same angle.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from models.errors import InputError
from models.instrument import Instrument
from models.sky import sky_to_focal_mm
from solvers.programme.reach import MAX_WINDOW, arm_masks

__all__ = ["DEFAULT_STEP_DEG", "OBJECTIVE", "REFINE_STEP_DEG", "AngleChoice", "AngleScore", "AngleSearch",
           "choose_angle", "reach_exposures", "refined_angles"]

#: the default step, deg: a sixth of the default instrument's arm pitch (30°), so that the
#: search sees six placements of the arms relative to the members (reach repeats every 30°
#: there); a target at the FOV rim is reachable within the park move limit on arcs of PA at
#: least 15.5° wide (measured every 0.5° at r = 124.4 mm, 120 s), so the grid samples every
#: such arc at least three times. 72 angles take about 0.1 s for a pointing of 100 targets.
DEFAULT_STEP_DEG = 5.0
#: when the grid's best angles still lose members, the search also tries every this many
#: degrees within one grid step of each of them (several rim members can leave an arc of
#: angles that reaches them all narrower than the grid step), at most REFINE_MAX_ANGLES more
REFINE_STEP_DEG = 0.5
REFINE_MAX_ANGLES = 720
#: the objective in words (the field descriptions and the docs say the same)
OBJECTIVE = ("fewest targets out of every arm's reach within the park move limit, then fewest "
             "exposures (the arm-reach bound), then highest priority reached, then the angle "
             "nearest the range's centre (any angle: nearest 0), then the smaller angle")
_KEYS = ("targets lost to arm reach", "exposures", "priority reached", "nearness to the preferred angle",
         "the smaller angle")


@dataclass(frozen=True)
class AngleSearch:
    """The angles a pointing may take: ``range_deg`` (min, max; None: any angle, [0, 360))
    every ``step_deg``, both ends included."""

    range_deg: tuple[float, float] | None = None
    step_deg: float = DEFAULT_STEP_DEG

    def __post_init__(self) -> None:
        check_search(self.range_deg, self.step_deg)

    def angles(self) -> tuple[float, ...]:
        """The angles tried, ascending from the range's minimum; an angle equal modulo 360 to
        one before it is left out."""
        lo, hi = (0.0, 360.0) if self.range_deg is None else self.range_deg
        n = int(math.floor((hi - lo) / self.step_deg + 1e-9))
        grid = [round(lo + k * self.step_deg, 9) for k in range(n + 1)]
        if self.range_deg is not None and grid[-1] < hi:
            grid.append(float(hi))
        out: list[float] = []
        seen: set[float] = set()
        for a in grid:
            key = _angle_key(a)
            if key not in seen:
                seen.add(key)
                out.append(float(a))
        return tuple(out)

    def preferred_deg(self) -> float:
        """The angle ties go to: the range's centre, or 0 for any angle."""
        return 0.0 if self.range_deg is None else 0.5 * (self.range_deg[0] + self.range_deg[1])

    def distance_deg(self, a: float) -> float:
        """How far ``a`` is from :meth:`preferred_deg` (on the circle for any angle)."""
        if self.range_deg is not None:
            return abs(a - self.preferred_deg())
        d = abs(a) % 360.0
        return min(d, 360.0 - d)


def _angle_key(a_deg: float) -> float:
    """An angle modulo 360, rounded, so that equal angles compare equal."""
    return round(a_deg % 360.0, 6) % 360.0


def check_search(range_deg: Sequence[float] | None, step_deg: float,
                 range_field: str = "position_angle_range_deg",
                 step_field: str = "position_angle_step_deg") -> None:
    """Raise InputError naming the field when the range is not [min, max] with
    -360 <= min <= max <= 360, or the step is not in (0, 360]."""
    if not (isinstance(step_deg, int | float) and math.isfinite(step_deg) and 0.0 < step_deg <= 360.0):
        raise InputError(step_field, f"must be a number of degrees in (0, 360], got {step_deg!r}")
    if range_deg is None:
        return
    if len(range_deg) != 2 or not all(isinstance(v, int | float) and math.isfinite(v) for v in range_deg):
        raise InputError(range_field, f"must be [min_deg, max_deg], got {list(range_deg)!r}")
    lo, hi = float(range_deg[0]), float(range_deg[1])
    if not (-360.0 <= lo <= 360.0 and -360.0 <= hi <= 360.0):
        raise InputError(range_field, f"both ends must lie in [-360, 360] deg, got [{lo:g}, {hi:g}]")
    if lo > hi:
        raise InputError(range_field, f"is empty: min {lo:g} deg > max {hi:g} deg")


@dataclass(frozen=True)
class AngleScore:
    """One angle's terms of the objective: members lost, exposures (arm-reach bound) and the
    summed priority of the members reached."""

    angle_deg: float
    lost: int
    exposures: int
    priority: int


@dataclass(frozen=True)
class AngleChoice:
    """The angle chosen, every angle tried (in the order tried), their scores and the
    objective in words, with what decided it."""

    chosen_deg: float
    tried_deg: tuple[float, ...]
    scores: tuple[AngleScore, ...]
    objective: str


def reach_exposures(masks: np.ndarray, n_arms: int) -> int:
    """The fewest exposures that can observe every reached member (``masks``: bit k set
    when arm k reaches it; 0: nobody does): ⌈reached / arms⌉, and ⌈members only a window of
    ``w`` neighbouring arms reaches / w⌉ for w = 1 … :data:`MAX_WINDOW` (docs/programme.md,
    rows (2) and (5))."""
    reached = masks[masks != 0]
    best = math.ceil(len(reached) / max(n_arms, 1))
    for w in range(1, min(MAX_WINDOW, n_arms) + 1):
        for k0 in range(n_arms):
            window = sum(1 << ((k0 + d) % n_arms) for d in range(w))
            only = int(np.count_nonzero((reached & ~window) == 0))
            best = max(best, math.ceil(only / w))
    return best


def _score(inst: Instrument, ra_deg: np.ndarray, dec_deg: np.ndarray, priority: np.ndarray,
           centre: tuple[float, float], angle_deg: float, park_move_limit_s: float | None,
           arm_limits: np.ndarray | None = None) -> AngleScore:
    x, y = sky_to_focal_mm(ra_deg, dec_deg, centre[0], centre[1], float(inst.plate_scale_arcsec_per_mm),
                           angle_deg)
    masks = arm_masks(inst, x, y, park_move_limit_s)
    if arm_limits is not None:
        masks = masks & arm_limits
    return AngleScore(float(angle_deg), int(np.count_nonzero(masks == 0)), reach_exposures(masks, inst.n_arms),
                      int(priority[masks != 0].sum()))


def choose_angle(inst: Instrument, ra_deg, dec_deg, priority, centre: tuple[float, float], search: AngleSearch,
                 park_move_limit_s: float | None, arm_limits: np.ndarray | None = None) -> AngleChoice:
    """The angle of ``search`` for the members at (``ra_deg``, ``dec_deg``) with
    ``priority``, about the pointing ``centre`` (sky, deg), by the objective of the module
    docstring. ``arm_limits``: per member, the bit mask of the arms it may use (its lock), or
    None: a locked target counts as lost at an angle where its own arm cannot reach it."""
    ra, dec = np.atleast_1d(np.asarray(ra_deg, float)), np.atleast_1d(np.asarray(dec_deg, float))
    prio = np.atleast_1d(np.asarray(priority, np.int64))
    angles = search.angles()
    scores = tuple(_score(inst, ra, dec, prio, centre, a, park_move_limit_s, arm_limits) for a in angles)
    least = min(s.lost for s in scores)
    if least > 0:  # a narrow arc between grid angles may reach every member
        lo, hi = (-math.inf, math.inf) if search.range_deg is None else search.range_deg
        extra = refined_angles([s.angle_deg for s in scores if s.lost == least], search.step_deg, lo, hi, angles)
        if search.range_deg is None:  # any angle: reported in [0, 360)
            extra = tuple(a % 360.0 for a in extra)
        angles += extra
        scores += tuple(_score(inst, ra, dec, prio, centre, a, park_move_limit_s, arm_limits) for a in extra)
    keys: list[Callable[[AngleScore], float]] = [
        lambda s: s.lost, lambda s: s.exposures, lambda s: -s.priority,
        lambda s: round(search.distance_deg(s.angle_deg), 9), lambda s: s.angle_deg]
    best, decided = _lexicographic(scores, keys)
    return AngleChoice(best.angle_deg, angles, scores, _objective(best, len(ra), len(angles), decided))


def refined_angles(best_deg: Sequence[float], step_deg: float, lo_deg: float, hi_deg: float,
                   tried: Sequence[float]) -> tuple[float, ...]:
    """Every :data:`REFINE_STEP_DEG` within one ``step_deg`` of each angle of ``best_deg``,
    inside [lo_deg, hi_deg], not equal modulo 360 to an angle of ``tried`` or to one before it
    (ascending; at most :data:`REFINE_MAX_ANGLES`)."""
    seen = {_angle_key(a) for a in tried}
    n = int(math.ceil(step_deg / REFINE_STEP_DEG - 1e-9))
    out: list[float] = []
    for b in sorted(best_deg):
        for k in range(-n + 1, n):
            a = round(b + k * REFINE_STEP_DEG, 9)
            key = _angle_key(a)
            if lo_deg <= a <= hi_deg and key not in seen and len(out) < REFINE_MAX_ANGLES:
                seen.add(key)
                out.append(a)
    return tuple(out)


def _lexicographic(scores: Sequence[AngleScore], keys: Sequence[Callable[[AngleScore], float]],
                   ) -> tuple[AngleScore, int]:
    """The best score by ``keys`` in order, and the index of the key that settled it (the
    last one that left fewer angles standing)."""
    left, decided = list(scores), 0
    for i, key in enumerate(keys):
        best = min(key(s) for s in left)
        kept = [s for s in left if key(s) == best]
        if len(kept) < len(left):
            decided = i
        left = kept
        if len(left) == 1:
            break
    return left[0], decided


def _objective(best: AngleScore, n: int, tried: int, decided: int) -> str:
    """The objective in words, the chosen angle's terms and what settled it."""
    head = (f"{best.angle_deg:g} deg of {tried} angles tried, settled by {_KEYS[decided]}" if tried > 1
            else f"{best.angle_deg:g} deg, the one angle of the range")
    return (f"{head}: {best.lost} of {n} targets lost to arm reach, at least {best.exposures} "
            f"exposures, priority {best.priority} reached. Objective: {OBJECTIVE}.")
