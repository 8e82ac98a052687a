"""Typed options of the sequencing driver (thesis 5.5), one frozen dataclass per concern.

Each dataclass checks its fields once, in ``__post_init__``, and raises
:class:`~models.errors.InputError` naming the field (``repair.time_limit_s``, ...).  A field
left at ``None`` takes the default of the caller's mode: :func:`SequencingOptions.resolved`
fills it (the allocation entry point first applies the defaults of the chosen method and
of the "one configuration" mode, see :mod:`solvers.allocation.options`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from models.errors import InputError

__all__ = ["DEFAULTS", "PackingOptions", "RepairOptions", "RescueOptions", "SequenceOptions",
           "SequencingOptions", "check_bool", "check_int", "check_seconds"]

TIE_BREAKS = (True, False, "reach")


def check_seconds(name: str, v, *, allow_zero: bool = False, allow_none: bool = True) -> None:
    """A positive (or, with ``allow_zero``, non-negative) finite number of seconds."""
    if v is None and allow_none:
        return
    ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and (
        v >= 0 if allow_zero else v > 0)
    if not ok:
        raise InputError(name, "must be a finite number of seconds >= 0" if allow_zero
                         else "must be a positive finite number of seconds")


def check_int(name: str, v, lo: int, *, allow_none: bool = False) -> None:
    if v is None and allow_none:
        return
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise InputError(name, f"must be an integer >= {lo}, got {v!r}")


def check_bool(name: str, v, *, allow_none: bool = False) -> None:
    if v is None and allow_none:
        return
    if not isinstance(v, bool):
        raise InputError(name, f"must be true or false, got {v!r}")


@dataclass(frozen=True)
class SequenceOptions:
    """The greedy loop: one configuration after another (thesis 5.5).

    ``max_configurations``: stop after that many (1 is the "one configuration" mode);
    ``config_time_limit_s``: cap of each single solve (None: 5 s); ``adaptive_limits``:
    each solve gets at most twice its share of the time left (None: on); ``mip_rel_gap``,
    ``threads``: passed to every solve; ``tie_break``: favour hard-to-place targets among
    equal solutions (True: reach and crowding, "reach": reach only, False: none; None: on);
    ``lower_bound_flow``: report the b-matching lower bound; ``blank_per_arm``: sampled
    blank-sky rest locations per arm in the structure (None: 0, park only);
    ``reserve_fraction``: the part of the call's limit the adaptive shares hold back for the
    post-passes (None: 0.1; the HiGHS and CP-SAT back-ends declare 0.25, see
    :data:`solvers.allocation.options.ENGINE_SEQUENCING`); ``park_move_limit_s``: every
    location an arm takes is reached from park within this time turning theta2 the positive
    way (:func:`models.incompatibility.build_assignments`; None: no limit); the plan
    pipeline sets the thesis' configuration time, 120 s.
    """

    max_configurations: int | None = None
    config_time_limit_s: float | None = None
    adaptive_limits: bool | None = None
    mip_rel_gap: float = 0.0
    threads: int = 2
    tie_break: bool | str | None = None
    lower_bound_flow: bool = True
    blank_per_arm: int | None = None
    reserve_fraction: float | None = None
    park_move_limit_s: float | None = None

    def __post_init__(self) -> None:
        check_int("max_configurations", self.max_configurations, 1, allow_none=True)
        check_seconds("config_time_limit_s", self.config_time_limit_s)
        check_bool("adaptive_limits", self.adaptive_limits, allow_none=True)
        g = self.mip_rel_gap
        if isinstance(g, bool) or not isinstance(g, int | float) or not (0 <= g < 1):
            raise InputError("mip_rel_gap", f"must be a number in [0, 1), got {g!r}")
        check_int("threads", self.threads, 1)
        if self.tie_break is not None and self.tie_break not in TIE_BREAKS:
            raise InputError("tie_break", f"must be true, false or 'reach', got {self.tie_break!r}")
        check_bool("lower_bound_flow", self.lower_bound_flow)
        check_int("blank_per_arm", self.blank_per_arm, 0, allow_none=True)
        r = self.reserve_fraction
        if r is not None and (isinstance(r, bool) or not isinstance(r, int | float) or not (0 <= r < 1)):
            raise InputError("reserve_fraction", f"must be a number in [0, 1), got {r!r}")
        check_seconds("park_move_limit_s", self.park_move_limit_s)


@dataclass(frozen=True)
class RescueOptions:
    """The conflict rescue: targets left ``conflict`` get configurations where idle arms
    may rest on already observed sky.  ``tail_fraction``: end the greedy loop early, for the
    rescue, once an under-filled configuration leaves at most this fraction of the
    reachable targets (0: never)."""

    enabled: bool = True
    tail_fraction: float = 0.0

    def __post_init__(self) -> None:
        check_bool("rescue.enabled", self.enabled)
        f = self.tail_fraction
        if isinstance(f, bool) or not isinstance(f, int | float) or not (0 <= f <= 1):
            raise InputError("rescue.tail_fraction", f"must be a number in [0, 1], got {f!r}")


@dataclass(frozen=True)
class RepairOptions:
    """Ejection-chain repair over the whole sequence (no solver calls).
    ``time_limit_s``: its budget (None: 5 s; at most half the time left)."""

    enabled: bool = True
    time_limit_s: float | None = None

    def __post_init__(self) -> None:
        check_bool("repair.enabled", self.enabled)
        check_seconds("repair.time_limit_s", self.time_limit_s)


@dataclass(frozen=True)
class PackingOptions:
    """Repacking by multi-configuration models, and the lower bounds that stop it.
    ``enabled`` (None: on); ``max_window``: scales the repacking budget; ``attempt_time_limit_s``:
    one packing attempt; ``lp_bound_time_limit_s``: the configuration LP bound (0: none)."""

    enabled: bool | None = None
    max_window: int = 6
    attempt_time_limit_s: float = 2.0
    lp_bound_time_limit_s: float = 10.0

    def __post_init__(self) -> None:
        check_bool("packing.enabled", self.enabled, allow_none=True)
        check_int("packing.max_window", self.max_window, 1)
        check_seconds("packing.attempt_time_limit_s", self.attempt_time_limit_s, allow_none=False)
        check_seconds("packing.lp_bound_time_limit_s", self.lp_bound_time_limit_s, allow_zero=True,
                      allow_none=False)


@dataclass(frozen=True)
class SequencingOptions:
    """Everything the sequencing driver reads: the greedy loop and its post-passes."""

    sequence: SequenceOptions = field(default_factory=SequenceOptions)
    rescue: RescueOptions = field(default_factory=RescueOptions)
    repair: RepairOptions = field(default_factory=RepairOptions)
    packing: PackingOptions = field(default_factory=PackingOptions)

    def __post_init__(self) -> None:
        for name, cls in (("sequence", SequenceOptions), ("rescue", RescueOptions), ("repair", RepairOptions),
                          ("packing", PackingOptions)):
            if not isinstance(getattr(self, name), cls):
                raise InputError(name, f"must be a {cls.__name__}")

    def with_defaults(self, defaults: SequencingOptions) -> SequencingOptions:
        """Every ``None`` field replaced by the one of ``defaults``."""
        parts = {}
        for name in ("sequence", "rescue", "repair", "packing"):
            mine, theirs = getattr(self, name), getattr(defaults, name)
            fill = {f.name: getattr(theirs, f.name) for f in dataclasses.fields(mine)
                    if getattr(mine, f.name) is None}
            parts[name] = dataclasses.replace(mine, **fill) if fill else mine
        return SequencingOptions(**parts)

    def resolved(self) -> SequencingOptions:
        """Every ``None`` field at the driver's own default (:data:`DEFAULTS`)."""
        return self.with_defaults(DEFAULTS)


#: The driver's defaults, the exact allocator's sequence (thesis 5.5 plus repair and repacking).
DEFAULTS = SequencingOptions(
    SequenceOptions(config_time_limit_s=5.0, adaptive_limits=True, tie_break=True, blank_per_arm=0,
                    reserve_fraction=0.1),
    RescueOptions(),
    RepairOptions(time_limit_s=5.0),
    PackingOptions(enabled=True),
)
