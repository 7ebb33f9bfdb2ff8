"""Task base: a family is a class, its variants are data (an options dataclass)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pybullet as p

from ps_ray.errors import UserError

from ..sim import Sim

PLANE_Z = -0.4
PLANE_RGBA = (0.15, 0.15, 0.15, 1.0)
TARGET_RGBA = (0.9, 0.2, 0.2, 0.5)  # goal marker; the tiny renderer ignores alpha


@dataclass(frozen=True)
class TaskOptions:
    """Scene options shared by every family: the table (panda-gym's create_table)."""

    table_length: float = 1.1
    table_width: float = 0.7
    table_height: float = 0.4
    table_x_offset: float = -0.3
    table_friction: float | None = None  # None: PyBullet's default (0.5)
    table_rgba: tuple[float, ...] = (0.95, 0.95, 0.95, 1.0)


class Task(ABC):
    """One task family in a :class:`Sim`.

    The constructor builds the static scene (floor, table, goal marker); ``reset`` samples the goal
    with the env's RNG and re-creates the moving bodies (see :class:`Sim` on determinism);
    ``observe`` returns ``(task_state, achieved_goal)`` given the end-effector position.
    """

    Options: ClassVar[type[TaskOptions]] = TaskOptions
    state_dim: ClassVar[int] = 0
    has_object: ClassVar[bool] = False  # whether the task moves an object (touching means something)
    default_gripper: ClassVar[bool] = False

    @classmethod
    def state_width(cls, options: TaskOptions) -> int:
        """Width of ``task_state`` for these options (a family may size it from its options)."""
        return cls.state_dim

    @classmethod
    def candidate_count(cls, options: TaskOptions) -> int:
        """How many candidate targets a scene holds (:meth:`candidate_targets`; 1: none to choose)."""
        return 1

    def __init__(self, sim: Sim, options: TaskOptions) -> None:
        self.sim, self.options = sim, options
        self.goal = np.zeros(3)
        self.object: int | None = None  # the body whose contact/touching is reported
        o = options
        sim.add_box((3.0, 3.0, 0.01), (0.0, 0.0, PLANE_Z - 0.01), rgba=PLANE_RGBA)  # floor, as panda-gym
        sim.add_box(
            (o.table_length / 2, o.table_width / 2, o.table_height / 2),
            (o.table_x_offset, 0.0, -o.table_height / 2),
            rgba=o.table_rgba,
            lateral_friction=o.table_friction,
        )
        self._build()
        self._marker = sim.add_shape(*self._marker_shape(), self.goal, rgba=TARGET_RGBA, ghost=True)

    def _build(self) -> None:  # noqa: B027 (optional hook: families without static bodies skip it)
        """Add the family's static bodies."""

    def _marker_shape(self) -> tuple[int, tuple[float, ...]]:
        """The goal marker (visual only): a 2 cm sphere."""
        return p.GEOM_SPHERE, (0.02,)

    @property
    def target_position(self) -> np.ndarray:
        """The world point the achieved goal must reach (the goal, unless the family says otherwise)."""
        return self.goal

    def reset(self, rng: np.random.Generator, task_input: np.ndarray | None = None) -> None:
        """Draw a scene, or set the one a task input (task state, then goal) describes."""
        if task_input is not None:
            task_input = self._settable(np.asarray(task_input, float))
        self._reset(rng)
        if task_input is not None:
            self._set(task_input)
        self.sim.move(self._marker, self.target_position)

    def _settable(self, task_input: np.ndarray) -> np.ndarray:
        """The task input checked before anything moves (a family that can set scenes says so)."""
        raise UserError(
            f"a {type(self).__name__.lower()} scene cannot be set from a task input; "
            f"valid: the marker families (reach_red, reach_blue, push_red, push_blue, ...)"
        )

    def _set(self, task_input: np.ndarray) -> None:  # noqa: B027 (only families that pass _settable)
        """Set the scene a checked task input describes."""

    def candidate_targets(self) -> np.ndarray | None:
        """Every target the scene holds for the tasks of its family (rows, world frame), the named
        one at :attr:`named_candidate`; None where the family's tasks do not share a scene (each
        task draws its own target), so a task-blind policy has nothing to choose between."""
        return None

    named_candidate: int = 0

    def object_position(self) -> np.ndarray | None:
        """Where the task's object was at the last :meth:`observe` (world frame); None for a task
        without one."""
        return None

    @abstractmethod
    def target_region(self) -> tuple[np.ndarray, np.ndarray]:
        """The axis-aligned box (world frame: low and high corners) that holds every target this
        task draws: what a policy that knows the task's kind but not its meaning aims at."""

    @abstractmethod
    def _reset(self, rng: np.random.Generator) -> None:
        """Sample ``self.goal`` and (re-)create the moving bodies."""

    @abstractmethod
    def observe(self, ee_position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(task_state, achieved_goal)``."""
