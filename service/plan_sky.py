"""A plan's sky at the HTTP edge: the request's ``sky_positions`` and ``sky_radius_arcsec``
as the domain's :class:`planner.sky.SkyRequest`, a pointing task's
:class:`planner.sky.SkyField`, and a pointing's ``stats.sky``. The placement itself is
:func:`planner.sky.place_sky`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from models.instrument import Instrument
from planner.sky import SkyField, SkyRequest, sky_request
from service.schemas import PlanRequest

__all__ = ["plan_sky", "sky_stats", "task_sky"]


def plan_sky(req: PlanRequest) -> SkyRequest:
    """The request's sky (:func:`planner.sky.sky_request`): every target of the programme, its
    ``sky_positions`` and ``sky_radius_arcsec``."""
    given = req.sky_positions or []
    return sky_request([t.id for t in req.targets], [t.ra_deg for t in req.targets],
                       [t.dec_deg for t in req.targets], [s.ra_deg for s in given],
                       [s.dec_deg for s in given], req.sky_radius_arcsec)


def task_sky(task: Any, inst: Instrument) -> SkyField | None:
    """The :class:`planner.sky.SkyField` of a :class:`service.pointing_plans.PointingTask`'s pointing
    (None: no sky placement)."""
    if task.sky is None:
        return None
    p = task.pointing
    return task.sky.field(inst, p.ra_deg % 360.0, p.dec_deg, task.position_angle_deg)


def sky_stats(sky: SkyRequest, configurations: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """A pointing's ``stats.sky``: the radius, the sky positions given and usable, the notices
    of those dropped, and its arms on sky over all configurations."""
    return {"radius_arcsec": sky.radius_arcsec, "positions_given": sky.given,
            "positions_near": len(sky.sky_ra_deg), "notices": list(sky.notices),
            "sky_arms": sum(int(c["stats"].get("sky_arms", 0)) for c in configurations)}
