"""Names: a robot or task as a mapping, as an exact string and as a short one, and a trial's key
(its run folder, MLflow run and zoo entry). The one place that converts between them."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

from ps_ray.defaults import INTERFACE_DIM
from ps_ray.errors import UserError

# The unstitched controls and the oracle scored beside every stitched pair (ps_ray.stitching.stitch.controls)
# The latent translations a stitch may fit (ps_ray.nets.translation), by name.
TRANSLATIONS = ("orthogonal", "affine")
CONTROL_ROLES = ("robot_source", "task_source", "oracle")


def as_mapping(value: str | Mapping) -> dict:
    """A robot or task as a mapping: a name ``n`` becomes ``{"name": n}``."""
    return {"name": value} if isinstance(value, str) else dict(value)


def canonical(value: str | Mapping) -> str | dict:
    """A robot or task in one spelling, applied when a spec loads: a mapping that holds only a
    name is that name."""
    if isinstance(value, Mapping):
        return value["name"] if set(value) == {"name"} else dict(value)
    return value


def spec_text(value: str | Mapping) -> str:
    """A robot or task as one exact string (its name, or its mapping as sorted JSON), to key
    dicts by and to pass on a command line; :func:`parse_spec_text` gives the value back."""
    return value if isinstance(value, str) else json.dumps(value, sort_keys=True)


def parse_spec_text(text: str) -> str | dict:
    """The robot or task a :func:`spec_text` string (or a ``--robot/--task`` flag) stands for."""
    if not text.strip().startswith("{"):
        return text
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise UserError(f"{text!r} is neither a name nor a JSON mapping ({e})") from None


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
    dim = spec.get("interface_dim", INTERFACE_DIM)
    return key if dim == INTERFACE_DIM else f"{key}/i{dim}"
