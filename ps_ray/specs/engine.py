"""The one validation engine of every spec: pydantic v2 dataclasses, checked as a user wrote them.

``@spec("zero_shot")`` makes a frozen pydantic dataclass that is strict (``"10"`` is not an integer,
``true`` not a number, an integer stays an integer), refuses unknown keys, and turns pydantic's
report into the one line ps_ray prints (:class:`SpecError`): the setting's dotted name, what it
must be, and the value given. A field says what it takes in its annotation:

- ``Positive``, ``NonNegative``, ``Number``, ``Seq[T]`` (a YAML list read as a tuple);
- ``ps_ray.errors.Words("an integer 0..99999")`` beside constraints, when a message should say more;
- ``between(low, high, "(]")`` for an interval; ``OneOf[Mode]`` for an enum spelt as its value;
- ``sub_spec(Cls, "resources.train")`` for a mapping read as a nested spec.

Checks across fields stay in the spec's ``__post_init__`` (run after the fields validate); they
raise :class:`SpecError` with their own line, or :class:`Invalid` to have it prefixed by the field.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import types
import typing
from collections.abc import Callable, Mapping
from typing import Annotated, Any, TypeVar

import pydantic.dataclasses
from pydantic import AfterValidator, BeforeValidator, ConfigDict, Field, ValidationError

from ps_ray.errors import UserError, describe, type_hints, words

CONFIG = ConfigDict(strict=True, extra="forbid", arbitrary_types_allowed=True)


class SpecError(UserError):
    """A spec that cannot run; the message is one line naming the bad key or value."""


class Invalid(ValueError):
    """A field's value is wrong; the message reads after the field's name ("must be ...")."""


class Unknown(Invalid):
    """A field's value is none of its choices; the message lists them."""


T = TypeVar("T")


def _tuple(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


Seq = Annotated[tuple[T, ...], BeforeValidator(_tuple)]  # a list as written in YAML, held as a tuple
Positive = Annotated[int, Field(gt=0)]
NonNegative = Annotated[int, Field(ge=0)]
Number = int | float  # strict: ``true`` and ``"1"`` are refused, an integer stays an integer


def finite(value: float) -> float:
    if not math.isfinite(value):
        raise Invalid("must be a finite number")
    return value


def between(low: float, high: float, ends: str = "()") -> AfterValidator:
    """A number in an interval, ends ``"()"``, ``"(]"``, ``"[)"`` or ``"[]"``: "must be in (0, 1]"."""

    def check(value: float) -> float:
        above = value >= low if ends[0] == "[" else value > low
        below = value <= high if ends[1] == "]" else value < high
        if not (above and below):
            raise Invalid(f"must be in {ends[0]}{low:g}, {high:g}{ends[1]}")
        return value

    return AfterValidator(check)


class OneOf:
    """``OneOf[Pairing]``: an enum (:class:`ps_ray.specs.modes.Mode`) spelt as one of its values."""

    def __class_getitem__(cls, mode: type) -> Any:
        def read(value: Any) -> Any:
            if isinstance(value, mode):
                return value
            if isinstance(value, str) and value in mode._value2member_map_:
                return mode(value)
            raise Unknown(", ".join(mode))

        return Annotated[mode, BeforeValidator(read)]


def sub_spec(cls: type, prefix: str) -> BeforeValidator:
    """A nested spec written as a mapping (or left out: null), its errors named under ``prefix``."""
    return BeforeValidator(lambda v: v if isinstance(v, cls) else parse(cls, v, prefix, prefix))


def spec(prefix: str = "", where: str | None = None) -> Callable[[type], type]:
    """The decorator of every spec: field errors are named ``prefix.field`` (``field`` without a
    prefix), unknown and missing keys ``where: unknown key ...`` (default: the prefix)."""

    def wrap(cls: type) -> type:
        cls = pydantic.dataclasses.dataclass(frozen=True, config=CONFIG)(cls)
        validated = cls.__init__

        @functools.wraps(validated)
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            try:
                validated(self, *args, **kwargs)
            except ValidationError as e:
                raise failure(e, type(self), None) from None

        cls.__validated_init__, cls.__init__ = validated, __init__
        cls.__spec_prefix__, cls.__spec_where__ = prefix, where or prefix or cls.__name__
        return cls

    return wrap


def parse(cls: type, data: Any, where: str | None = None, prefix: str | None = None) -> Any:
    """A spec from a mapping as written (``None``: every default); one line for anything else."""
    where = where or cls.__spec_where__
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise SpecError(f"{where}: expected a mapping, got {data!r}")
    bad = [k for k in data if not isinstance(k, str)]
    if bad:
        raise _unknown(cls, where, bad[0])
    instance = object.__new__(cls)
    try:
        cls.__validated_init__(instance, **data)
    except ValidationError as e:
        raise failure(e, cls, where, prefix) from None
    return instance


def _unknown(cls: type, where: str, key: Any) -> SpecError:
    valid = ", ".join(f.name for f in dataclasses.fields(cls))
    return SpecError(f"{where}: unknown key {key!r}; valid keys: {valid}")


_CONSTRAINTS = {"greater_than": "gt", "greater_than_equal": "ge", "less_than": "lt", "less_than_equal": "le"}


_RELATIONS = {"gt": ">", "ge": ">=", "lt": "<", "le": "at most"}


def _bound(kind: str, ctx: Mapping[str, Any], hint: Any) -> str:
    """A bound in words: "a positive integer", "a non-negative number", "at most 8192", ">= 2"."""
    bound = ctx[kind]
    if bound == 0 and kind in ("gt", "ge"):
        sign = "positive" if kind == "gt" else "non-negative"
        return f"a {sign} {'integer' if describe(hint).startswith('an integer') else 'number'}"
    return f"{_RELATIONS[kind]} {bound:g}"


def failure(error: ValidationError, cls: type, where: str | None, prefix: str | None = None) -> SpecError:
    """Pydantic's first error as ps_ray's one line."""
    first = error.errors(include_url=False)[0]
    kind, loc, value, ctx = first["type"], first["loc"], first.get("input"), first.get("ctx") or {}
    cause = ctx.get("error")
    if isinstance(cause, UserError):  # a nested spec or a resolver: its own line already
        return SpecError(str(cause))
    where = where or cls.__spec_where__
    if kind in ("unexpected_keyword_argument", "extra_forbidden"):
        return _unknown(cls, where, loc[0])
    if kind in ("missing", "missing_argument"):
        return SpecError(f"{where}: missing key {loc[0]!r}")
    prefix = cls.__spec_prefix__ if prefix is None else prefix
    field = str(loc[0]) if loc else ""
    name = ".".join(p for p in (prefix, field) if p)
    hint = type_hints(cls).get(field, Any)
    if isinstance(cause, Unknown):
        return SpecError(f"unknown {name} {value!r}; valid: {cause}")
    if isinstance(cause, Invalid):  # of a field, or (no field) of the spec's __post_init__
        return SpecError(f"{name} {cause}, got {value!r}" if field else f"{name}: {cause}")
    if kind in _CONSTRAINTS:
        said = words(hint) or _bound(_CONSTRAINTS[kind], ctx, hint)
        return SpecError(f"{name} must be {said}, got {value!r}")
    if cause is not None:  # a validator's own ValueError
        return SpecError(f"{name}: {cause}")
    return SpecError(f"{name} must be {describe(hint)}, got {value!r}")


def base_types(hint: Any) -> set[Any]:
    """The plain types an annotation holds: ``{int}`` for ``Positive``, ``{int, float, NoneType}``
    for ``Number | None``, ``{tuple[str, ...]}`` for ``Seq[str]``."""
    if typing.get_origin(hint) is Annotated:
        return base_types(hint.__origin__)
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return set().union(*(base_types(a) for a in typing.get_args(hint)))
    return {hint}


def read_number(text: str) -> int | float:
    """A command-line number as a spec holds it: ``"3"`` an integer, ``"3.0"`` and ``"1e-3"`` floats."""
    try:
        return int(text)
    except ValueError:
        return float(text)


def flag_kwargs(hint: Any) -> dict[str, Any]:
    """How an ``argparse`` flag reads a field (``type``, ``nargs``, ``choices``), from its annotation:
    an integer, a number, a list (of words or numbers), one of a mode's words, or the text itself."""
    held = base_types(hint) - {type(None)}
    items = [typing.get_args(h)[0] for h in held if typing.get_origin(h) is tuple]
    if items:
        return {"nargs": "+", **flag_kwargs(items[0])}
    modes = [h for h in held if isinstance(h, type) and issubclass(h, enum.Enum)]
    if modes:
        return {"choices": [m.value for m in modes[0]]}
    return {"type": read_number if float in held else int if int in held else str}
