"""Building frozen config dataclasses from plain mappings with strict key checking."""

from __future__ import annotations

import dataclasses
import difflib
import functools
import numbers
from collections.abc import Mapping
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")


class UnknownKeyError(KeyError, ValueError):
    """A mapping names a field the target dataclass does not have."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0])


def check_keys(keys: Any, allowed: Any, where: str) -> None:
    """Raise :class:`UnknownKeyError` for the first key not in ``allowed``.

    The message names ``where`` (a file, a section or a class) and suggests the closest
    allowed key ("did you mean ...?").
    """
    allowed = list(allowed)
    for key in keys:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), [str(a) for a in allowed], n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise UnknownKeyError(
                f"{where}: unknown key {key!r}{hint} (allowed: {', '.join(sorted(allowed))})"
            )


def dataclass_from_dict(cls: type[T], data: Mapping[str, Any], where: str | None = None) -> T:
    """Build the dataclass ``cls`` from ``data``; unknown keys raise with a suggestion."""
    names = [f.name for f in dataclasses.fields(cls) if f.init]  # type: ignore[arg-type]
    check_keys(data.keys(), names, where or cls.__name__)
    return cls(**dict(data))


def nested_dataclass_from_dict(
    cls: type[T], data: Mapping[str, Any], where: str | None = None
) -> T:
    """:func:`dataclass_from_dict` that also builds nested config fields from mappings.

    A field whose default is itself a dataclass (a ``WallFollowerConfig`` inside a
    ``FrontierConfig``, say) takes a mapping of that class's fields, checked the same way
    and named ``where.field`` in errors. ``cls`` must be constructible without arguments.
    """
    where = where or cls.__name__
    if not isinstance(data, Mapping):
        raise ValueError(f"{where}: a mapping of fields is needed, got {data!r}")
    defaults = cls()
    built = {}
    for key, value in data.items():
        inner = getattr(defaults, key, None)
        if isinstance(value, Mapping) and dataclasses.is_dataclass(inner):
            value = nested_dataclass_from_dict(type(inner), value, f"{where}.{key}")
        built[key] = value
    return dataclass_from_dict(cls, built, where)


def check_integers(owner: Any, minimums: Mapping[str, int]) -> None:
    """Raise ``ValueError`` unless each named field of ``owner`` is an integer >= its minimum.

    ``minimums`` maps field names to their smallest allowed value. Booleans and
    non-integral numbers (``1.5``, NaN) are rejected; the message names the class, the
    field and the value.
    """
    for name, minimum in minimums.items():
        value = getattr(owner, name)
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
            raise ValueError(
                f"{type(owner).__name__}.{name} must be an integer >= {minimum}, got {value!r}"
            )


def check_intervals(owner: Any, intervals: Mapping[str, str]) -> None:
    """Raise ``ValueError`` unless each named field of ``owner`` lies in its interval.

    ``intervals`` maps field names to intervals written ``"[0, 1)"``, ``"(0, inf]"``
    and the like (a square bracket includes its end). NaN lies in none, and booleans are
    rejected; the message names the class, the field, the interval and the value.
    """
    for name, interval in intervals.items():
        value = getattr(owner, name)
        low, high = (float(end) for end in interval[1:-1].split(","))
        inside = isinstance(value, numbers.Real) and not isinstance(value, bool)
        if inside:
            above = value > low if interval[0] == "(" else value >= low
            below = value < high if interval[-1] == ")" else value <= high
            inside = bool(above and below)
        if not inside:
            raise ValueError(f"{type(owner).__name__}.{name} must lie in {interval}, got {value!r}")


class ConfigTypeError(TypeError, ValueError):
    """A config field holds a value of the wrong type (a string for a number, and the like)."""


@functools.cache
def _field_kinds(cls: type) -> tuple[tuple[str, str], ...]:
    """``(name, kind)`` of the fields of ``cls`` whose type :func:`check_field_types` checks.

    ``kind`` is ``bool``, ``int``, ``float`` or ``str``, with a ``?`` after it when
    ``None`` is allowed too; fields of other types (tuples, nested configs) are left out.
    """
    kinds = []
    for f in dataclasses.fields(cls):
        # the annotation as written (postponed: a string), or the type itself
        hint = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
        parts = [p.strip() for p in hint.replace("Optional[", "").rstrip("]").split("|")]
        optional = "None" in parts and len(parts) == 2
        base = next((p for p in parts if p != "None"), "") if optional else hint.strip()
        if base in ("bool", "int", "float", "str"):
            kinds.append((f.name, base + ("?" if optional else "")))
    return tuple(kinds)


_PLAIN = {"bool": (bool,), "int": (int,), "float": (float, int), "str": (str,)}
_PLAIN_OK = {**_PLAIN, **{k + "?": (*v, type(None)) for k, v in _PLAIN.items()}}
"""Exact types each field kind of :func:`check_field_types` passes at once."""


def check_field_types(owner: Any) -> None:
    """Raise :class:`ConfigTypeError` unless each scalar field of ``owner`` has its type.

    A dataclass's ``bool`` fields take ``True`` / ``False`` only (a JSON ``"false"`` would
    otherwise count as true), ``float`` fields any real number but a bool, ``int`` fields
    a number (integrality and minimum: :func:`check_integers`), ``str`` fields strings;
    ``X | None`` fields ``None`` too. The message names the class, the field and the
    value. Ranges are the class's own checks.
    """
    for name, kind in _field_kinds(type(owner)):
        value = getattr(owner, name)
        exact = type(value)
        if exact in _PLAIN_OK[kind]:  # the common case, without the abstract checks
            continue
        if kind.endswith("?"):
            if value is None:
                continue
            kind = kind[:-1]
        if kind == "bool":
            ok = isinstance(value, bool | np.bool_)
        elif kind == "str":
            ok = isinstance(value, str)
        elif kind == "int":  # integrality and minimum: check_integers, with its message
            ok = isinstance(value, numbers.Real)
        else:
            ok = isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)
        if not ok:
            expected = {"bool": "a bool", "int": "an integer", "float": "a number"}
            raise ConfigTypeError(
                f"{type(owner).__name__}.{name} must be {expected.get(kind, 'a string')}, "
                f"got {value!r}"
            )
