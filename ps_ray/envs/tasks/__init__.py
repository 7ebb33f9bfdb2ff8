"""Task registry: built-in variants are a family plus option values.

A task is given as a name (``"push_slippery"``) or a mapping ``{"name": ..., **options}``; keyword
options are merged on top (``make(task="reach", goal_region="q2")``). Options are the fields of
the family's options dataclass (``Reach.Options``, ``Push.Options``, ``Pick.Options``).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ps_ray.errors import UserError, choice_error

from ..goals import GOAL_DIM
from .base import Task, TaskOptions
from .markers import Markers
from .pick import Pick
from .push import Push
from .reach import GOAL_REGIONS, Reach


@dataclass(frozen=True)
class TaskSpec:
    name: str
    family: type[Task]
    options: TaskOptions

    @property
    def input_dim(self) -> int:
        """Width of the task module's input (``task_state`` then ``desired_goal``)."""
        return self.family.state_width(self.options) + GOAL_DIM

    @property
    def has_object(self) -> bool:
        """Whether the task moves an object (so touching it means something)."""
        return self.family.has_object


_SLIPPERY_RGBA = (0.75, 0.85, 0.95, 1.0)  # recoloured table; the object carries the low friction

TASKS: dict[str, tuple[type[Task], dict[str, Any]]] = {
    "reach": (Reach, {}),
    "push": (Push, {}),  # Pu1
    "push_slippery": (Push, {"object_friction": 0.1, "table_rgba": _SLIPPERY_RGBA}),  # Pu2
    "push_rocks": (Push, {"rocks": True, "table_length": 1.1, "table_x_offset": -0.3}),  # Pu3
    "pick_cube": (Pick, {}),  # Pi1
    "pick_stick": (Pick, {"object_half_extents": (0.15, 0.02, 0.02)}),  # Pi2: 0.30 m bar along x
    # The transfer family (docs/transfer.md): one scene of two markers, the task names the marker.
    "reach_red": (Markers, {"target": 0}),
    "reach_blue": (Markers, {"target": 1}),
}


def resolve_task(task: str | Mapping | TaskSpec, **options: Any) -> TaskSpec:
    if isinstance(task, TaskSpec):
        if not options:
            return task
        task = {"name": task.name, **dataclasses.asdict(task.options)}
    if isinstance(task, Mapping):
        options = {**{k: v for k, v in task.items() if k != "name"}, **options}
        if "name" not in task:
            raise UserError(f"task mapping {dict(task)!r} needs a 'name'; valid tasks: {', '.join(TASKS)}")
        task = task["name"]
    if not isinstance(task, str) or task not in TASKS:
        raise choice_error("task", task, TASKS)
    family, preset = TASKS[task]
    valid = [f.name for f in dataclasses.fields(family.Options)]
    hints = typing.get_type_hints(family.Options)
    for key, value in options.items():
        if key not in valid:
            raise UserError(f"unknown option {key!r} for task {task!r}; valid options: {', '.join(valid)}")
        if not _fits(value, hints[key]):
            raise UserError(f"task {task!r} option {key}: expected {_describe(hints[key])}, got {value!r}")
    return TaskSpec(task, family, family.Options(**{**preset, **options}))


def _fits(value: Any, hint: Any) -> bool:
    """Whether an option value has its field's type (numbers for floats, a list or tuple of the
    right length for a tuple); a field of another kind checks its own values."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, a) for a in args) or not all(a in _SCALARS or a is type(None) for a in args)
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint in (int, float):
        return isinstance(value, (int, float) if hint is float else int) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            return False
        items = args[:1] * len(value) if len(args) == 2 and args[1] is Ellipsis else args
        return len(items) == len(value) and all(_fits(v, a) for v, a in zip(value, items, strict=True))
    return True


_SCALARS = (bool, int, float, str)


def _describe(hint: Any) -> str:
    text = hint.__name__ if isinstance(hint, type) else str(hint)
    return text.replace("typing.", "").replace("NoneType", "None")


__all__ = [
    "GOAL_REGIONS",
    "TASKS",
    "Markers",
    "Pick",
    "Push",
    "Reach",
    "Task",
    "TaskOptions",
    "TaskSpec",
    "resolve_task",
]
