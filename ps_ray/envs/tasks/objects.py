"""Tasks with one free object on the table (push, pick): shared object, surface and goal logic."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pybullet as p

from .base import Task, TaskOptions
from .rocks import rock_boxes, rocks_urdf, surface_height


@dataclass(frozen=True)
class ObjectOptions(TaskOptions):
    object_half_extents: tuple[float, float, float] = (0.02, 0.02, 0.02)
    object_mass: float = 1.0
    object_friction: float | None = None  # lateral; None: PyBullet's default (0.5)
    object_rgba: tuple[float, ...] = (0.1, 0.9, 0.1, 1.0)
    object_xy_range: float = 0.05  # start xy ~ U[-r/2, r/2]^2
    goal_xy_range: float = 0.3  # goal xy ~ U[-r/2, r/2]^2
    goal_z_range: float = 0.0  # goal height above the resting height ~ U[0, r] ...
    goal_on_table_prob: float = 0.0  # ... except this fraction of goals, put on the table
    rocks: bool = False  # 169 small fixed bumps on the table


class ObjectTask(Task):
    """Observation: object position, Euler angles, linear and angular velocity (12-D)."""

    Options = ObjectOptions
    state_dim = 12
    has_object = True
    options: ObjectOptions
    target_shape: ClassVar[str] = "box"  # goal marker: "box" (object-sized) or "sphere"

    def _build(self) -> None:
        if self.options.rocks:
            self.sim.load_urdf(rocks_urdf())

    def _marker_shape(self) -> tuple[int, tuple[float, ...]]:
        if self.target_shape == "box":
            return p.GEOM_BOX, tuple(self.options.object_half_extents)
        return super()._marker_shape()

    def target_region(self) -> tuple[np.ndarray, np.ndarray]:
        o, z = self.options, self.options.object_half_extents[2]
        return (
            np.array([-o.goal_xy_range / 2, -o.goal_xy_range / 2, z]),
            np.array([o.goal_xy_range / 2, o.goal_xy_range / 2, z + o.goal_z_range]),
        )

    def _reset(self, rng: np.random.Generator) -> None:
        o = self.options
        half = np.asarray(o.object_half_extents, dtype=float)
        goal = rng.uniform(
            (-o.goal_xy_range / 2, -o.goal_xy_range / 2, 0.0),
            (o.goal_xy_range / 2, o.goal_xy_range / 2, o.goal_z_range),
        )
        if o.goal_on_table_prob > 0 and rng.random() < o.goal_on_table_prob:
            goal[2] = 0.0
        goal[2] += half[2]
        self.goal = goal
        xy = rng.uniform(-o.object_xy_range / 2, o.object_xy_range / 2, size=2)
        z = half[2] + (surface_height(rock_boxes(), xy, half[:2]) if o.rocks else 0.0)  # rest on the bumps
        if self.object is not None:
            self.sim.remove(self.object)
        self.object = self.sim.add_box(
            half, (*xy, z), rgba=o.object_rgba, mass=o.object_mass, lateral_friction=o.object_friction
        )

    def object_position(self) -> np.ndarray:
        return self._object_state[:3]

    def observe(self, ee_position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._object_state = self.sim.base_state(self.object)  # read once per step
        return self._object_state, self._object_state[:3]
