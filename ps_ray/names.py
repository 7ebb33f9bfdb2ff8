"""Names of trials: a robot or task as a short string, and a trial's key (its run folder,
MLflow run and zoo entry)."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

DEFAULT_INTERFACE_DIM = 128


def short_name(value: Any, limit: int = 64) -> str:
    """A robot/task: its name; a mapping ``{"name": base, ...}`` as ``base{json of the rest}``,
    or ``base#<hash>`` when that is longer than ``limit`` characters."""
    if not isinstance(value, Mapping):
        return str(value)
    rest = {k: v for k, v in value.items() if k != "name"}
    base = str(value.get("name", "custom"))
    if not rest:
        return base
    text = json.dumps(rest, sort_keys=True, separators=(",", ":"), default=str)
    if len(base) + len(text) <= limit:
        return base + text
    return f"{base}#{hashlib.sha256(text.encode()).hexdigest()[:8]}"


def trial_key(spec: Mapping[str, Any]) -> str:
    """``method/robot/task/seed``, plus ``/i<dim>`` for a non-default interface dim: the name of
    a trial's run directory, MLflow run and zoo entry."""
    key = "/".join(short_name(spec.get(k)) for k in ("method", "robot", "task", "seed"))
    dim = spec.get("interface_dim", DEFAULT_INTERFACE_DIM)
    return key if dim == DEFAULT_INTERFACE_DIM else f"{key}/i{dim}"
