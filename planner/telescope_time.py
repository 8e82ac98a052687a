"""Telescope time of a plan, and the astronomer's rules that bound it.

A programme's cost to an astronomer is the telescope time it takes. For one pointing with
``n`` exposures (configurations c1 ... cn, thesis ch. 5) it is

    T = n * t_exp + t_acq + sum_{legs} T_leg

where ``t_exp`` is the exposure time of one configuration, ``t_acq`` the acquisition
overhead of the pointing (slew, guide-star acquisition, the fine positioning of the arms on
their through-slit images, thesis 6.4.1.1), and ``T_leg`` the configuration time of each motion
leg park -> c1 -> ... -> cn -> park: its makespan, the time until the last arm is at rest at
its goal (thesis 6.3, "configuration time"). The motion legs are counted in full, as if the
arms moved while the telescope waits (no overlap with the slew or the detector read-out), so
the figure is what the plan costs at most. A pointing with no exposure is not visited: it
costs nothing. The time of a programme is the sum over its pointings.

A leg that was not planned (``executable: false``) has no makespan; it is counted in
``unplanned_legs`` and adds nothing to ``reconfiguration_s``: the figure is then a lower bound.

:class:`ObservingRules` are the request's inputs: the two times above and the stop rules that
trade completeness for telescope time (``max_exposures``, ``min_priority_per_exposure``,
``min_targets_per_exposure``; :mod:`planner.programme` applies them). The default is full
completeness: no stop rule.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from models.errors import InputError

__all__ = ["DEFAULT_ACQUISITION_S", "DEFAULT_EXPOSURE_TIME_S", "ObservingRules", "TelescopeTime",
           "pointing_time", "total"]

#: The exposure time of one configuration when the request gives none, s.
DEFAULT_EXPOSURE_TIME_S = 900.0
#: The acquisition overhead of one pointing when the request gives none, s.
DEFAULT_ACQUISITION_S = 300.0


def _seconds(name: str, v: object, *, positive: bool) -> None:
    ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and (
        v > 0 if positive else v >= 0)
    if not ok:
        raise InputError(name, "must be a positive finite number of seconds" if positive
                         else "must be a finite number of seconds >= 0")


def _count(name: str, v: object, lo: int) -> None:
    if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < lo):
        raise InputError(name, f"must be an integer >= {lo} or None, got {v!r}")


@dataclass(frozen=True)
class ObservingRules:
    """The times telescope time is counted with, and the astronomer's stop rules, validated
    once (an :class:`~models.errors.InputError` names the field).

    ``exposure_time_s`` (> 0): one configuration's exposure; ``acquisition_s`` (>= 0): the
    overhead of one pointing. Stop rules (None: none, the default; full completeness):

    - ``max_exposures``: at most that many exposures over the whole programme, split over
      its pointings by :func:`planner.programme.exposure_caps`; targets left out for it are
      reported ``beyond_max_exposures``;
    - ``min_priority_per_exposure`` / ``min_targets_per_exposure``: no exposure observes
      less summed priority / fewer targets; the targets of the exposures not opened are
      reported ``below_exposure_threshold``.
    """

    exposure_time_s: float = DEFAULT_EXPOSURE_TIME_S
    acquisition_s: float = DEFAULT_ACQUISITION_S
    max_exposures: int | None = None
    min_priority_per_exposure: int | None = None
    min_targets_per_exposure: int | None = None

    def __post_init__(self) -> None:
        _seconds("exposure_time_s", self.exposure_time_s, positive=True)
        _seconds("acquisition_s", self.acquisition_s, positive=False)
        _count("max_exposures", self.max_exposures, 1)
        _count("min_priority_per_exposure", self.min_priority_per_exposure, 1)
        _count("min_targets_per_exposure", self.min_targets_per_exposure, 1)

    def keeps(self, arm_yield: int, total_priority: int) -> bool:
        """Whether an exposure observing ``arm_yield`` targets of summed priority
        ``total_priority`` meets both thresholds."""
        return ((self.min_targets_per_exposure is None or arm_yield >= self.min_targets_per_exposure)
                and (self.min_priority_per_exposure is None
                     or total_priority >= self.min_priority_per_exposure))


@dataclass(frozen=True)
class TelescopeTime:
    """Telescope time of a pointing or of a whole plan, s.

    ``exposures``: configurations observed; ``acquisitions``: pointings visited (those with an
    exposure); ``exposure_s`` = exposures x exposure time; ``acquisition_s`` = acquisitions x
    the acquisition overhead; ``reconfiguration_s``: the summed makespans of the planned
    motion legs; ``total_s``: the three summed; ``unplanned_legs``: legs without a makespan
    (not counted: ``total_s`` is then a lower bound). Plans add up with ``+`` (:func:`total`).
    """

    exposures: int = 0
    acquisitions: int = 0
    exposure_s: float = 0.0
    acquisition_s: float = 0.0
    reconfiguration_s: float = 0.0
    unplanned_legs: int = 0
    total_s: float = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "total_s", self.exposure_s + self.acquisition_s + self.reconfiguration_s)

    def __add__(self, other: TelescopeTime) -> TelescopeTime:
        if not isinstance(other, TelescopeTime):
            return NotImplemented
        return TelescopeTime(self.exposures + other.exposures, self.acquisitions + other.acquisitions,
                             self.exposure_s + other.exposure_s, self.acquisition_s + other.acquisition_s,
                             self.reconfiguration_s + other.reconfiguration_s,
                             self.unplanned_legs + other.unplanned_legs)


def total(times: Iterable[TelescopeTime]) -> TelescopeTime:
    """The telescope time of a programme: the sum over its pointings (zero for none)."""
    out = TelescopeTime()
    for t in times:
        out = out + t
    return out


def pointing_time(exposures: int, leg_makespans_s: Sequence[float | None], exposure_time_s: float,
                  acquisition_s: float) -> TelescopeTime:
    """The telescope time of one pointing with ``exposures`` configurations whose motion legs
    park -> c1 -> ... -> cn -> park took ``leg_makespans_s`` (``exposures + 1`` of them; a
    leg not planned is None or NaN): ``exposures * exposure_time_s + acquisition_s`` plus the
    planned legs' makespans. A pointing with no exposure is not visited: zero."""
    _count("exposures", exposures, 0)
    _seconds("exposure_time_s", exposure_time_s, positive=True)
    _seconds("acquisition_s", acquisition_s, positive=False)
    if exposures == 0:
        return TelescopeTime()
    if len(leg_makespans_s) != exposures + 1:
        raise InputError("leg_makespans_s", f"expected {exposures + 1} legs (park -> c1 -> ... -> park), "
                                            f"got {len(leg_makespans_s)}")
    planned = [float(t) for t in leg_makespans_s if t is not None and math.isfinite(float(t))]
    if any(t < 0 for t in planned):
        raise InputError("leg_makespans_s", "a makespan is a duration >= 0")
    return TelescopeTime(exposures, 1, exposures * float(exposure_time_s), float(acquisition_s),
                         math.fsum(planned), len(leg_makespans_s) - len(planned))
