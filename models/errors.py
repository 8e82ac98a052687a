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
