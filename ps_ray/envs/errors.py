"""One error format for every bad name or value in ps_ray.envs."""

from __future__ import annotations

from collections.abc import Iterable


def choice_error(
    kind: str, value: object, choices: Iterable[object], plural: str | None = None
) -> ValueError:
    """``ValueError("unknown robot 'pandaa'; valid robots: panda, panda_l3, panda_l5")``."""
    listed = ", ".join(str(c) for c in choices)
    return ValueError(f"unknown {kind} {value!r}; valid {plural or kind + 's'}: {listed}")
