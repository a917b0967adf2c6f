"""Experiment parameters from text or JSON values, and the bounds they must keep.

One conversion serves the command line (``NAME=VALUE`` text) and the ground service (JSON
values), so both accept the same parameters and refuse the same mistakes with the same
:class:`~planner.errors.InvalidInput` messages. It knows the parameters dataclasses only by
their fields, so it imports no planner (``planner.schedule`` reads a robot's defaults with it
and ``planner.catalogue`` offers it beside the experiments).

    parse_assignments(...)   ["NAME=VALUE", ...] -> parameters (text, as on a command line)
    parameters_from_values   {NAME: JSON value} -> parameters (a string is read as text)

Durations (parameters named ``*_s``) are limited to :data:`MAX_DURATION_S`: nothing longer
fits one contact window (``PassParams.window_s`` <= 3600 s), and a larger value would only
allocate a plan that can never fly.

Work bounds: one plan must finish within a stated time (the ground service kills a plan
past its deadline, 60 s by default). Planning time grows with the plan's length and with
the solver's iteration counts, so a segment duration (every ``*_s`` but the pass's
``window_s``) is at most :data:`MAX_SEGMENT_S`, a speed (``*_mps``) at least
:data:`MIN_SPEED_MPS`, and the iteration counts at most :data:`WORK_LIMITS`. Within these,
the slowest plan measured on the 2-core reference machine (coordination at every bound,
with a test run beside it) takes about :data:`WORST_PLAN_S` seconds (docs/planning.md,
"Limits"); the defaults take 1-10 s.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping, Sequence
from typing import Any

from planner.errors import InvalidInput

__all__ = [
    "MAX_DURATION_S",
    "MAX_ITEMS",
    "MAX_SEGMENT_S",
    "MIN_SPEED_MPS",
    "WORK_LIMITS",
    "WORST_PLAN_S",
    "parameters_from_values",
    "parse_assignments",
    "show",
    "type_name",
]

#: The longest duration parameter accepted (s): one contact window at most.
MAX_DURATION_S = 3600.0
#: The most items a tuple parameter may hold.
MAX_ITEMS = 64
#: The longest segment duration (s): a settle, a pause, a tail, a leg.
MAX_SEGMENT_S = 300.0
#: The slowest speed parameter (m/s) above zero: a hand line of 0.5 m takes 167 s.
MIN_SPEED_MPS = 0.003
#: Iteration counts (nonholonomic): their upper bounds.
WORK_LIMITS = {"max_iterations": 200, "path_steps": 400, "max_corrections": 20}
#: The slowest plan the bounds allow, measured (s, 2 cores; see the module doc).
WORST_PLAN_S = 75.0


def type_name(hint: Any) -> str:
    return str(hint).replace("typing.", "").replace("<class '", "").replace("'>", "")


def show(value: Any) -> str:
    """``repr`` cut short: messages quote what a client sent, which may be long."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _finite(name: str, value: float) -> float:
    if not math.isfinite(value):
        raise InvalidInput(f"parameter {name}: not finite: {value!r}")
    return value


def _from_text(name: str, text: str, hint: Any) -> Any:
    """``text`` (command-line form: tuples comma-separated, ``none`` for an Optional) as
    ``hint``."""
    args = typing.get_args(hint)
    if type(None) in args:  # Optional[...]: "none" means the default derivation
        if text.strip().lower() in ("", "none"):
            return None
        hint = next(a for a in args if a is not type(None))
        args = typing.get_args(hint)
    try:
        if hint is bool:
            lowered = text.strip().lower()
            if lowered not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(f"not a boolean: {show(text)}")
            return lowered in ("true", "1", "yes")
        if hint is float:
            return _finite(name, float(text))
        if hint is int:
            return int(text)
        if hint is str:
            return text
        if typing.get_origin(hint) is tuple:
            parts = [p.strip() for p in text.split(",") if p.strip()]
            if len(parts) > MAX_ITEMS:
                raise ValueError(f"{len(parts)} items exceed the limit of {MAX_ITEMS}")
            return tuple(_from_text(name, p, args[0]) for p in parts)
    except ValueError as exc:
        if isinstance(exc, InvalidInput):
            raise
        raise InvalidInput(f"parameter {name}: {exc}") from None
    raise InvalidInput(f"parameter {name} has a type that cannot be set: {type_name(hint)}")


def _from_value(name: str, value: Any, hint: Any) -> Any:
    """A JSON value as ``hint``; a string for a non-string parameter is read as text."""
    args = typing.get_args(hint)
    if type(None) in args:
        if value is None:
            return None
        hint = next(a for a in args if a is not type(None))
        args = typing.get_args(hint)
    if isinstance(value, str) and hint is not str:
        return _from_text(name, value, hint)
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if hint is bool and isinstance(value, bool):
        return value
    if hint is float and number:
        try:
            return _finite(name, float(value))
        except OverflowError:  # an int beyond any float
            raise InvalidInput(f"parameter {name}: {show(value)} is out of range") from None
    if hint is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if hint is str and isinstance(value, str):
        return value
    if typing.get_origin(hint) is tuple and isinstance(value, list | tuple):
        if len(value) > MAX_ITEMS:
            raise InvalidInput(f"parameter {name}: {len(value)} items exceed {MAX_ITEMS}")
        return tuple(_from_value(name, item, args[0]) for item in value)
    raise InvalidInput(f"parameter {name}: expected {type_name(hint)}, got {show(value)}")


def _build(params_type: type[Any], values: dict[str, Any]) -> Any:
    for key, value in values.items():
        if key.endswith("_s") and isinstance(value, float) and abs(value) > MAX_DURATION_S:
            raise InvalidInput(
                f"parameter {key} = {value} s exceeds the limit of {MAX_DURATION_S} s"
            )
    try:
        params = params_type(**values)
    except TypeError as exc:
        raise InvalidInput(str(exc)) from None
    check = getattr(params, "check", None)
    if callable(check):
        check()
    _check_work(params)
    return params


def _check_work(params: Any) -> None:
    """The work bounds of the module doc, on the parameters as built (defaults included)."""
    for f in dataclasses.fields(params):
        value = getattr(params, f.name)
        if isinstance(value, bool) or not isinstance(value, int | float):
            continue
        if f.name.endswith("_s") and f.name != "window_s" and value > MAX_SEGMENT_S:
            raise InvalidInput(
                f"parameter {f.name} = {value} s exceeds the limit of {MAX_SEGMENT_S:g} s "
                "(one plan must finish within the planning deadline)"
            )
        if f.name.endswith("_mps") and 0 < value < MIN_SPEED_MPS:
            raise InvalidInput(
                f"parameter {f.name} = {value} m/s is below the limit of {MIN_SPEED_MPS:g} m/s "
                "(one plan must finish within the planning deadline)"
            )
        limit = WORK_LIMITS.get(f.name)
        if limit is not None and value > limit:
            raise InvalidInput(
                f"parameter {f.name} = {value} exceeds the limit of {limit} "
                "(one plan must finish within the planning deadline)"
            )


def _field_hints(params_type: type[Any]) -> dict[str, Any]:
    hints = typing.get_type_hints(params_type)
    return {f.name: hints[f.name] for f in dataclasses.fields(params_type)}


def _unknown(params_type: type[Any], key: str, known: Sequence[str]) -> InvalidInput:
    return InvalidInput(
        f"unknown parameter {show(key)} for {params_type.__name__}; known: {sorted(known)}"
    )


def _defaults(params_type: type[Any], defaults: Mapping[str, Any] | None) -> dict[str, Any]:
    """A robot's default values (JSON-like, as its description holds them), converted."""
    hints = _field_hints(params_type)
    converted: dict[str, Any] = {}
    for key, value in (defaults or {}).items():
        if key not in hints:
            raise _unknown(params_type, key, list(hints))
        converted[key] = _from_value(key, value, hints[key])
    return converted


def parse_assignments(
    params_type: type[Any],
    assignments: Sequence[str],
    *,
    defaults: Mapping[str, Any] | None = None,
) -> Any:
    """Parameters from ``NAME=VALUE`` strings; unset fields keep ``defaults`` (a robot's
    ``[experiments.NAME]`` table) or else the dataclass's own defaults."""
    hints = _field_hints(params_type)
    values: dict[str, Any] = _defaults(params_type, defaults)
    for assignment in assignments:
        if "=" not in assignment:
            raise InvalidInput(f"--set needs NAME=VALUE, got {show(assignment)}")
        key, text = assignment.split("=", 1)
        key = key.strip()
        if key not in hints:
            raise _unknown(params_type, key, list(hints))
        values[key] = _from_text(key, text, hints[key])
    return _build(params_type, values)


def parameters_from_values(
    params_type: type[Any],
    values: Mapping[str, Any],
    *,
    defaults: Mapping[str, Any] | None = None,
) -> Any:
    """Parameters from ``{NAME: value}`` as JSON carries them (numbers, booleans, strings,
    lists for tuples, ``null`` for an Optional); unset fields keep ``defaults`` (a robot's
    ``[experiments.NAME]`` table) or else the dataclass's own defaults."""
    hints = _field_hints(params_type)
    converted: dict[str, Any] = _defaults(params_type, defaults)
    for key, value in values.items():
        if key not in hints:
            raise _unknown(params_type, key, list(hints))
        converted[key] = _from_value(key, value, hints[key])
    return _build(params_type, converted)
