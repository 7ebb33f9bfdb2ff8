"""Bad input from the user, told apart from bugs.

A :class:`UserError` is a mistake in what the user gave (a name, a value, a flag, a file): the
CLI prints its message as one line and exits 2. Any other exception, a ``ValueError`` from numpy
or torch included, is a bug and keeps its traceback. ``UserError`` subclasses ``ValueError`` so
that library callers who catch ``ValueError`` keep working."""

from __future__ import annotations

from collections.abc import Iterable


class UserError(ValueError):
    """A bad name, value, flag or file given by the user; the message names it and the choices."""


def choice_error(kind: str, value: object, choices: Iterable[object], plural: str | None = None) -> UserError:
    """``UserError("unknown robot 'pandaa'; valid robots: panda, panda_l3, panda_l5")``."""
    listed = ", ".join(str(c) for c in choices)
    return UserError(f"unknown {kind} {value!r}; valid {plural or kind + 's'}: {listed}")
