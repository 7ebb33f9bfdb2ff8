"""Argument types and the one-line-error parser shared by every command and benchmark. Imports
nothing of ps_ray, so a benchmark runs where only torch is installed (a GPU host without PyBullet)."""

from __future__ import annotations

import argparse


def positive_int(text: str) -> int:
    """argparse type of a size: a zero or negative count is refused in one line (exit 2)."""
    return _int_from(text, 1, "a positive integer")


def seed_int(text: str) -> int:
    """argparse type of a seed: gymnasium and numpy take 0 .. 2**32 - 1."""
    return _int_from(text, 0, "a seed in 0..4294967295", 2**32 - 1)


def _int_from(text: str, low: int, what: str, high: int | None = None) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if value < low or (high is not None and value > high):
        raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
    return value


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``ps-ray <command>: error: ...``, exit 2);
    ``--help`` shows the usage."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def flag_of(message: str, fields) -> str | None:
    """The field a spec error is about: the first field name the message mentions (None: none)."""
    words = message.replace("'", " ").replace(".", " ").replace(":", " ").split()
    return next((w for w in words if w in fields), None)
