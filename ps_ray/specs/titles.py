"""How a run reads to people: its MLflow run name. One scheme for every stage: what tells a
stage's runs apart first (the env a run acts in, or a grid's held-out cells), then the method,
then the seed, then what else distinguishes it, joined by :data:`SEP`; never the stage, which
MLflow's nesting already shows, and variants as a reader writes them (``panda/reach q1``). The
exact key stays the run's ``ps_ray.trial_key`` tag."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ps_ray.specs.defaults import INTERFACE_DIM
from ps_ray.specs.names import readable, short_name

SEP = " · "
ANCHOR_POLICY = "plain policy for the anchor states"  # what an anchor policy's run name ends with
MAX_TITLE = 250  # MLflow's run-name limit


def title(*parts: Any) -> str:
    """The non-empty ``parts`` joined by :data:`SEP`, cut to MLflow's run-name limit."""
    return SEP.join(str(p) for p in parts if p not in ("", None))[:MAX_TITLE]


def env_title(robot: Any, task: Any) -> str:
    """``robot/task`` by short names, variants readable (``panda/reach q1``)."""
    return readable(f"{short_name(robot)}/{short_name(task)}")


def width_tag(dim: int) -> str:
    """``i16`` for an interface off the default width, else ""."""
    return "" if dim == INTERFACE_DIM else f"i{dim}"


def spec_title(spec: Mapping[str, Any], *more: Any) -> str:
    """A trained policy's run: ``panda_far/reach_blue · ablation · 431`` (+ ``more``)."""
    return title(
        env_title(spec["robot"], spec["task"]),
        short_name(spec["method"]),
        spec["seed"],
        width_tag(spec.get("interface_dim", INTERFACE_DIM)),
        *more,
    )
