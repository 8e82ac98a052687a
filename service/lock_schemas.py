"""The ``locked`` and ``excluded_targets`` fields of plan and allocation requests
(:mod:`service.schemas` uses them), and their translation to the domain's
:class:`models.locks.TargetLock`. The checks that need the targets or the geometry (an
unknown id, a lock no arm can honour) are the domain's (:func:`models.locks.check_locks`),
answered 422 naming ``locked[i]`` / ``excluded_targets[i]``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

from models.locks import N_BRANCHES, TargetLock

N_ARMS = 12
MAX_LOCKS = 100_000  # as many as a programme's targets

LOCKED_DOC = (
    "Locks: each target named here, whenever it is observed, is observed by that arm (and IK "
    "branch, when given) in every configuration, and by no other; every allocation engine and "
    "post-pass works on a structure without the target's other (arm, branch) locations. Locked "
    "targets take precedence: the engines weigh a locked target's priority plus the programme's "
    "largest. A lock that cannot be honoured (unknown target, arm disabled, the arm or branch "
    "cannot reach the target in its pointing or only beyond the park move limit, excluded too, "
    "a second lock of one target) is answered 422 naming `locked[i]` and why. A locked target "
    "left unobserved (no time, no room next to its arm's neighbours) is in `unallocated` with "
    "its reason prefixed 'locked_' (e.g. 'locked_no_time'). Default: none.")
EXCLUDED_DOC = (
    "Ids of targets never to observe: they are taken out before segmentation and allocation and "
    "reported in `unallocated` with reason 'excluded'. An unknown or repeated id is answered 422 "
    "naming `excluded_targets[i]`. Default: none.")


def _integral(v: object) -> object:
    """An integral float (``3.0``) is that integer (JSON has one number type)."""
    if isinstance(v, float) and v.is_integer():
        return int(v)
    return v


class TargetLockIn(BaseModel):
    """One lock: target ``target_id`` observed only by ``arm`` (through IK ``branch``, if given)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    target_id: Annotated[str, Field(min_length=1, max_length=128)] = Field(
        description="The locked target's id (a target of the request).")
    arm: Annotated[int, Field(ge=0, le=N_ARMS - 1, strict=True), BeforeValidator(_integral)] = Field(
        description="The arm 0..11 that observes it.")
    branch: Annotated[int, Field(ge=0, le=N_BRANCHES - 1, strict=True), BeforeValidator(_integral)] | None = Field(
        None, description="The IK branch 0..3 the arm reaches it through (as an assignment's "
        "`branch`); null: any branch of that arm.")


Locked = Annotated[list[TargetLockIn], Field(max_length=MAX_LOCKS)]
ExcludedTargets = Annotated[list[Annotated[str, Field(min_length=1, max_length=128)]],
                            Field(max_length=MAX_LOCKS)]


def target_locks(locked: Sequence[TargetLockIn] | None) -> tuple[TargetLock, ...]:
    """The request's locks as the domain's."""
    return tuple(TargetLock(lk.target_id, int(lk.arm), None if lk.branch is None else int(lk.branch))
                 for lk in locked or ())
