"""Benchmarks behind ``ps-ray bench <what>``: each prints figures, none is imported by the library."""

from __future__ import annotations

import argparse


def positive_int(text: str) -> int:
    """argparse type of a size: a zero or negative count is refused in one line (exit 2)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value
