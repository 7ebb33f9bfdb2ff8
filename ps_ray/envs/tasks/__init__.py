"""Task registry: built-in variants are a family plus option values.

A task is given as a name (``"push_slippery"``) or a mapping ``{"name": ..., **options}``; keyword
options are merged on top (``make(task="reach", goal_region="q2")``). Options are the fields of
the family's options dataclass (``Reach.Options``, ``Push.Options``, ``Pick.Options``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ps_ray.errors import UserError, choice_error, describe, fits, type_hints

from ..goals import GOAL_DIM
from .base import Task, TaskOptions
from .markers import Markers
from .pick import Pick
from .push import Push
from .push_markers import PushMarkers
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
    def candidate_count(self) -> int:
        """Candidate targets per scene: above 1, the family's tasks share a scene and differ in
        which target they name (a task-blind floor exists)."""
        return self.family.candidate_count(self.options)

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
    # Its manipulation member: one object, two goal markers on the table, the task names the marker.
    "push_red": (PushMarkers, {"target": 0}),
    "push_blue": (PushMarkers, {"target": 1}),
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
    hints = type_hints(family.Options)
    for key, value in options.items():
        if key not in valid:
            raise UserError(f"unknown option {key!r} for task {task!r}; valid options: {', '.join(valid)}")
        if not fits(value, hints[key]):
            raise UserError(f"task {task!r} option {key}: expected {describe(hints[key])}, got {value!r}")
    return TaskSpec(task, family, family.Options(**{**preset, **options}))


__all__ = [
    "GOAL_REGIONS",
    "TASKS",
    "Markers",
    "Pick",
    "Push",
    "PushMarkers",
    "Reach",
    "Task",
    "TaskOptions",
    "TaskSpec",
    "resolve_task",
]
