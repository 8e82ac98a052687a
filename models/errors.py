"""Errors shared by the models and solvers: invalid input that names the offending field."""

from __future__ import annotations


class InputError(ValueError):
    """Invalid input. ``field`` names the offending field, e.g. ``"targets[3].dec_deg"``.

    The service maps it to HTTP 422 with ``field`` in the error body.
    """

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


class TimeLimitExceeded(RuntimeError):
    """A domain stage ran out of its time budget before it had an answer.

    ``stage`` names the stage (e.g. ``"incompatibility"``), ``limit_s`` the budget it had.
    Callers that can answer partially (the allocator: targets left ``no_time``) catch it;
    the service maps an uncaught one to a timeout answer, never to an internal error.
    """

    def __init__(self, stage: str, limit_s: float | None = None) -> None:
        budget = f" of {limit_s:.3g} s" if limit_s is not None else ""
        super().__init__(f"{stage}: time limit{budget} exceeded")
        self.stage = stage
        self.limit_s = limit_s


class StructureTooLarge(InputError):
    """The incompatibility structure of a field would exceed its memory bound (a 422 on ``field``)."""
