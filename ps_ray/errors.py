"""Bad input from the user, told apart from bugs, and the one check of a value's type as a user
wrote it (:func:`fits`, :func:`describe`), shared by every typed spec and option.

A :class:`UserError` is a mistake in what the user gave (a name, a value, a flag, a file): the
CLI prints its message as one line and exits 2. Any other exception, a ``ValueError`` from numpy
or torch included, is a bug and keeps its traceback. ``UserError`` subclasses ``ValueError`` so
that library callers who catch ``ValueError`` keep working."""

from __future__ import annotations

import dataclasses
import functools
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Annotated, Any


class UserError(ValueError):
    """A bad name, value, flag or file given by the user; the message names it and the choices."""


def choice_error(kind: str, value: object, choices: Iterable[object], plural: str | None = None) -> UserError:
    """``UserError("unknown robot 'pandaa'; valid robots: panda, panda_l3, panda_l5")``."""
    listed = ", ".join(str(c) for c in choices)
    return UserError(f"unknown {kind} {value!r}; valid {plural or kind + 's'}: {listed}")


@dataclasses.dataclass(frozen=True)
class Words:
    """How messages say what an annotated field takes ("an integer 0..99999"), in place of the words
    of its type and constraints: ``Annotated[int, Field(ge=0), Words("...")]``."""

    text: str


@functools.cache
def type_hints(cls: type) -> dict[str, Any]:
    """``typing.get_type_hints(cls)`` with ``Annotated`` metadata kept, once per class: a spec is
    checked field by field many thousand times when a large sweep is planned."""
    return typing.get_type_hints(cls, include_extras=True)


def fits(value: Any, hint: Any) -> bool:
    """Whether a value as a user wrote it (YAML, JSON, a flag) has an annotation's type: true or
    false only for ``bool``, any number for ``float``, whole numbers for ``int``, a list or tuple
    for a tuple (of the annotation's length, or any length for ``tuple[T, ...]``), a mapping for a
    ``Mapping``, any member for a union. Other annotations are checked by their spec."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Annotated:
        return fits(value, args[0])
    if origin in (typing.Union, types.UnionType):
        return any(fits(value, a) for a in args)
    if hint is type(None):
        return value is None
    if hint in (int, float, str, bool):
        if isinstance(value, bool) and hint is not bool:
            return False
        return isinstance(value, (int, float) if hint is float else hint)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            return False
        items = args[:1] * len(value) if len(args) == 2 and args[1] is Ellipsis else args
        return len(items) == len(value) and all(fits(v, a) for v, a in zip(value, items, strict=True))
    if origin is not None and issubclass(origin, Mapping):
        return isinstance(value, Mapping)
    return True


def words(hint: Any) -> str | None:
    """The :class:`Words` an annotation (or a member of its union) carries, if any."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Annotated:
        given = [m.text for m in hint.__metadata__ if isinstance(m, Words)]
        return given[0] if given else words(args[0])
    if origin in (typing.Union, types.UnionType):
        return next((w for a in args if (w := words(a))), None)
    return None


def describe(hint: Any) -> str:
    """An annotation in words: "an integer", "a number or null", "a list of strings"; a number
    that may be an integer (``int | float``) is "a number"."""
    if (given := words(hint)) is not None:
        return given
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Annotated:
        return describe(args[0])
    if origin in (typing.Union, types.UnionType):
        return " or ".join(describe(a) for a in args if not (a is int and float in args))
    if origin is tuple:
        return f"a list of {describe(args[0]).removeprefix('a ').removeprefix('an ')}s"
    if (origin is not None and issubclass(origin, Mapping)) or dataclasses.is_dataclass(hint):
        return "a mapping"
    names = {int: "an integer", float: "a number", str: "a string", bool: "true or false", type(None): "null"}
    return names.get(hint, getattr(hint, "__name__", str(hint)))
