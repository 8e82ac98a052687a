"""The cross-field rules of the request schemas, both sides in one place: the checks the
server runs (pydantic validators of :mod:`service.schemas`) and the JSON Schema (OpenAPI
3.1, JSON Schema 2020-12) that states each rule in the contract, so that what a client or a
fuzzer generates from the document is what the server accepts:

- exactly one of ``targets`` and ``target_list_id`` (a non-null one): ``if`` targets are
  given ``then`` no list, ``else`` a list (:data:`ONE_TARGET_SOURCE`; an ``if``, not a
  ``oneOf``, so that client generators do not read the model as a union);
- each arm at most once in ``start``, ``goal`` and ``disabled_arms``: for every arm, an
  array ``contains`` at most one item naming it (``maxContains``), and ``uniqueItems``
  (:func:`unique_arms`);
- sky targets in an allocation need its ``pointing``: ``if``/``then``
  (:data:`SKY_NEEDS_POINTING`);
- every target list has at least one target: ``minItems`` on the field itself.

What JSON Schema cannot state (unique target ids, sky geometry, this server's limits) is
said in the operations' descriptions and answered 422 naming the field.
"""

from __future__ import annotations

from typing import Any, Protocol, TypeVar

from pydantic import ValidationError, ValidationInfo


class _OnArm(Protocol):
    """An item naming its arm (:class:`service.schemas.ArmState`)."""

    arm: int


A = TypeVar("A", bound=_OnArm)

ONE_TARGET_SOURCE: dict[str, Any] = {
    "if": {"required": ["targets"], "properties": {"targets": {"type": "array"}}},
    "then": {"properties": {"target_list_id": {"type": "null"}}},
    "else": {"required": ["target_list_id"], "properties": {"target_list_id": {"type": "string"}}},
}
SKY_NEEDS_POINTING: dict[str, Any] = {
    "if": {"required": ["targets"],
           "properties": {"targets": {"type": "array", "items": {"required": ["ra_deg"]}}}},
    "then": {"required": ["pointing"], "properties": {"pointing": {"type": "object"}}},
}


def unique_arms(n_arms: int) -> dict[str, Any]:
    """JSON Schema of an array of arm states naming each of arms 0..n_arms-1 at most once."""
    return {"uniqueItems": True, "allOf": [
        {"contains": {"required": ["arm"], "properties": {"arm": {"const": k}}},
         "minContains": 0, "maxContains": 1} for k in range(n_arms)]}


def unique_ids(targets: list[Any]) -> list[Any]:
    """``targets`` when their ids are unique (else a ValueError naming both)."""
    seen: dict[str, int] = {}
    for i, t in enumerate(targets):
        if t.id in seen:
            raise ValueError(f"targets[{i}].id: duplicate target id {t.id!r} (also targets[{seen[t.id]}])")
        seen[t.id] = i
    return targets


def one_target_source(target_list_id: str | None, info: ValidationInfo) -> str | None:
    """Exactly one of ``targets`` and ``target_list_id`` (nothing to say when ``targets``
    itself failed: its own error names it)."""
    if "targets" not in info.data:
        return target_list_id
    given = info.data["targets"] is not None
    if given and target_list_id is not None:
        raise ValueError("give either targets or target_list_id, not both")
    if not given and target_list_id is None:
        raise ValueError("give targets (an array) or target_list_id (a stored target list, "
                         "POST /v1/target-lists)")
    return target_list_id


def unique_arms_check(states: list[A] | None, field: str) -> list[A] | None:
    """``states`` when no arm is listed twice (else a ValueError naming the item)."""
    if states is None:
        return None
    seen: set[int] = set()
    for i, s in enumerate(states):
        if s.arm in seen:
            raise ValueError(f"{field}[{i}].arm: arm {s.arm} listed twice")
        seen.add(s.arm)
    return states


def branch_errors(exc: ValidationError, v: Any) -> ValidationError:
    """``exc`` of the ``list[PlaneTarget] | list[SkyTarget]`` union reduced to the branch the
    input is meant for, with the branch's name taken out of each ``loc``."""
    first = v[0] if isinstance(v, list) and v else None
    sky = isinstance(first, dict) and ("ra_deg" in first or "dec_deg" in first)
    branch = "list[SkyTarget]" if sky else "list[PlaneTarget]"
    errors = [e for e in exc.errors() if e["loc"] and e["loc"][0] == branch]
    if not errors:
        return exc
    try:
        return ValidationError.from_exception_data(exc.title, [
            {"type": e["type"], "loc": e["loc"][1:], "input": e.get("input"),
             **({"ctx": e["ctx"]} if "ctx" in e else {})} for e in errors])
    except (TypeError, KeyError, ValueError):  # an error type that cannot be rebuilt
        return exc


def _number_branch(prop: dict[str, Any]) -> dict[str, Any] | None:
    """The number schema of a (possibly nullable) numeric property."""
    for branch in [prop, *prop.get("anyOf", [])]:
        if branch.get("type") == "number":
            return branch
    return None


def served_limits(doc: dict[str, Any], max_time_limit_s: float, fov_diameter_mm: float) -> None:
    """State this server's numeric limits in its OpenAPI document ``doc`` (in place): every
    ``time_limit_s`` at most ``max_time_limit_s`` (``MXS_MAX_TIME_LIMIT_S``), every
    ``threshold_mm`` at most the instrument's FOV diameter."""
    limits = {"time_limit_s": max_time_limit_s, "threshold_mm": fov_diameter_mm}
    for schema in doc.get("components", {}).get("schemas", {}).values():
        for name, most in limits.items():
            number = _number_branch(schema.get("properties", {}).get(name, {}))
            if number is not None:
                number["maximum"] = min(float(number.get("maximum", most)), float(most))


def describe_limits(app: Any, max_time_limit_s: float, fov_diameter_mm: float) -> None:
    """The served OpenAPI document of ``app`` states this server's limits
    (:func:`served_limits`), as the committed one states the default server's."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            served_limits(build(), max_time_limit_s, fov_diameter_mm)
        return app.openapi_schema  # type: ignore[no-any-return]

    app.openapi = openapi
