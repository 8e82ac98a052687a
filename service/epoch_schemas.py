"""The epoch fields of the v1 schemas (:mod:`service.schemas` uses them): a target's space
motion, a plan's observation date and the answer's ``epoch`` summary. The propagation itself
is :mod:`models.epochs`."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from models.epochs import (
    DEFAULT_REF_EPOCH_YR,
    FIRST_YEAR,
    LAST_YEAR,
    MAX_REF_EPOCH_YR,
    MIN_REF_EPOCH_YR,
    MOTION_LIMITS,
    parse_date,
)


def _number(lo: float, hi: float, description: str) -> object:
    return Annotated[float, Field(ge=lo, le=hi, strict=True, allow_inf_nan=False,
                                  description=description)]


_PM, _PLX, _RV = (MOTION_LIMITS[k] for k in ("pmra_mas_yr", "parallax_mas", "radial_velocity_km_s"))
PmMasYr = _number(-_PM, _PM, "Proper motion, mas/yr.")
ParallaxMas = _number(-_PLX, _PLX, "Parallax, mas.")
RadialVelocityKmS = _number(-_RV, _RV, "Radial velocity, km/s.")
RefEpochYr = _number(MIN_REF_EPOCH_YR, MAX_REF_EPOCH_YR, "Catalogue epoch, Julian year.")

#: An ISO date ``YYYY-MM-DD``; the document states its form, :func:`check_obs_date` its range.
ObsDate = Annotated[str, Field(max_length=10, json_schema_extra={"pattern": r"^\d{4}-\d{2}-\d{2}$",
                                                                  "format": "date"})]

PMRA_DOC = ("Proper motion in RA, mu_alpha* = mu_alpha cos(dec), mas/yr (Gaia `pmra`, VizieR "
            "`pmRA`); null: none.")
PMDEC_DOC = "Proper motion in Dec, mas/yr (Gaia `pmdec`, VizieR `pmDE`); null: none."
PARALLAX_DOC = "Parallax, mas; null or not positive: none (a star at infinity)."
RV_DOC = "Radial velocity, km/s; null: none (0)."
REF_EPOCH_DOC = (f"Epoch of `ra_deg`/`dec_deg`, Julian year (Gaia DR3: 2016.0); null: "
                 f"J{DEFAULT_REF_EPOCH_YR:.1f} when the target has proper motions.")
OBS_DATE_DOC = (f"Observation date, ISO `YYYY-MM-DD` (years {FIRST_YEAR}..{LAST_YEAR}): every "
                "target is moved by its proper motion, parallax and radial velocity from its "
                "`ref_epoch_yr` to 00:00 UTC of that date (astropy `apply_space_motion`) before "
                "anything else; `epoch` and `notices` say how many moved and the largest "
                "shift. null (the default): the positions are used as given, and when targets "
                "have proper motions a notice gives their largest shift a year after today.")


def check_obs_date(v: str | None) -> str | None:
    """``v`` as a normalised ISO date (None stays None); a ValueError (422 naming the field)
    when it is no date or outside the years accepted."""
    if v is None:
        return None
    return parse_date(v).isoformat()


class EpochOut(BaseModel):
    """What the epoch step did (:class:`models.epochs.EpochReport`)."""

    model_config = ConfigDict(extra="allow")

    obs_date: str | None = Field(description="The request's observation date; null: none given "
                                 "(positions used as given).")
    shift_date: str = Field(description="The date the shifts are measured at: `obs_date`, or a "
                            "year after the server's today without one.")
    targets_with_motion: int = Field(ge=0, description="Targets with a non-zero proper motion "
                                     "or radial velocity (moved when `obs_date` is given).")
    max_shift_arcsec: float = Field(ge=0.0, description="The largest shift of a target from its "
                                    "given position by `shift_date`, arcsec.")
    default_epoch_targets: int = Field(ge=0, description="Targets with proper motions and no "
                                       f"`ref_epoch_yr`, taken at J{DEFAULT_REF_EPOCH_YR:.1f}.")
