"""Push: slide the object to a goal on the table, gripper blocked by default."""

from __future__ import annotations

from dataclasses import dataclass

from .objects import ObjectOptions, ObjectTask


@dataclass(frozen=True)
class PushOptions(ObjectOptions):
    # The authors' PandaPush-v2/v3 table (1.4 long, x_offset -0.1); push_rocks uses 1.1 / -0.3.
    table_length: float = 1.4
    table_x_offset: float = -0.1


class Push(ObjectTask):
    Options = PushOptions
    default_gripper = False
    target_shape = "box"
