"""Pick and place: lift the object to a goal up to 0.2 m above the table (30% on it), gripper on."""

from __future__ import annotations

from dataclasses import dataclass

from .objects import ObjectOptions, ObjectTask


@dataclass(frozen=True)
class PickOptions(ObjectOptions):
    object_xy_range: float = 0.3
    goal_z_range: float = 0.2
    goal_on_table_prob: float = 0.3


class Pick(ObjectTask):
    Options = PickOptions
    default_gripper = True
    target_shape = "sphere"
