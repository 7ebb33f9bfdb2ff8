"""The paper's eight few-shot stitching combinations E1-E8 (docs/authors_code.md §10), with
ps_ray's task and robot names: data, no code to run."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from ps_ray.specs.defaults import INTERFACE_DIM
from ps_ray.specs.names import EnvPart, trial_key

PANDA_L3_GRIPPER = {"name": "panda_l3", "gripper": True}  # R2 with the gripper, on push (Push-v4)
PAPER_TASKS = {
    "Pu1": "push",
    "Pu2": "push_slippery",
    "Pu3": "push_rocks",
    "Pi1": "pick_cube",
    "Pi2": "pick_stick",
}
PAPER_ROBOTS = {"R1": "panda", "R2": "panda_l3", "R3": "panda_l5"}


@dataclass(frozen=True)
class Source:
    task: EnvPart
    robot: EnvPart  # a name, or a mapping such as PANDA_L3_GRIPPER

    def __post_init__(self) -> None:
        object.__setattr__(self, "task", EnvPart(self.task))
        object.__setattr__(self, "robot", EnvPart(self.robot))


@dataclass(frozen=True)
class PaperCombo:
    """E1-E8 of the paper's few-shot figure, with ps_ray's task and robot names."""

    name: str
    label: str  # as in the figure: "t: <task>-<robot> & r: <task>-<robot>"
    task_from: Source
    robot_from: Source
    target: Source  # (task of task_from, robot of robot_from)
    epochs: int  # few-shot epochs shown in the figure (1 epoch = 35,000 env steps)

    def keys(self, method: str, seed: int, interface_dim: int = INTERFACE_DIM) -> tuple[str, str]:
        """Zoo keys (trial keys) of the task-module and robot-module sources."""
        task_key, robot_key = (
            trial_key(
                {
                    "method": method,
                    "robot": s.robot,
                    "task": s.task,
                    "seed": seed,
                    "interface_dim": interface_dim,
                }
            )
            for s in (self.task_from, self.robot_from)
        )
        return task_key, robot_key


def _paper(
    name: str,
    label: str,
    target: tuple[str, str | Mapping],
    epochs: int,
    robot_from: str | Mapping | None = None,
) -> PaperCombo:
    (t_task, t_robot), (r_task, r_robot) = (
        part.split("-") for part in label.removeprefix("t: ").split(" & r: ")
    )
    return PaperCombo(
        name,
        label,
        Source(PAPER_TASKS[t_task], PAPER_ROBOTS[t_robot]),
        Source(PAPER_TASKS[r_task], robot_from or PAPER_ROBOTS[r_robot]),
        Source(PAPER_TASKS[target[0]], target[1]),
        epochs,
    )


# E5: the robot module comes from push, so its robot has the gripper (8-D actions, like pick).
# E6: the robot module comes from pick (gripper on), so the target push robot has the gripper.
# For plain (one MLP cut in the middle) E6 also needs the task source trained with the gripper
# ({"name": "panda_l5", "gripper": true} on push): its bottom half sees the critic's action.
PAPER_COMBOS: tuple[PaperCombo, ...] = (
    _paper("E1", "t: Pu1-R1 & r: Pu2-R2", ("Pu1", "panda_l3"), 30),
    _paper("E2", "t: Pu2-R1 & r: Pu1-R2", ("Pu2", "panda_l3"), 90),
    _paper("E3", "t: Pu1-R3 & r: Pu3-R1", ("Pu1", "panda"), 30),
    _paper("E4", "t: Pu3-R1 & r: Pu1-R2", ("Pu3", "panda_l3"), 70),
    _paper("E5", "t: Pi1-R1 & r: Pu1-R2", ("Pi1", "panda_l3"), 190, robot_from=PANDA_L3_GRIPPER),
    _paper("E6", "t: Pu1-R3 & r: Pi1-R2", ("Pu1", PANDA_L3_GRIPPER), 40),
    _paper("E7", "t: Pi2-R1 & r: Pi1-R3", ("Pi2", "panda_l5"), 40),
    _paper("E8", "t: Pi1-R3 & r: Pi2-R1", ("Pi1", "panda"), 190),
)


# The paper's zero-shot table ("Success rates and touching rates of zero-shot transfer"): per
# combination and method, touching and success in %, each mean and ± as printed.
PAPER_ZERO_SHOT: dict[str, dict[str, tuple[float, float, float, float]]] = {
    "E1": {
        "ps": (73.0, 1.4, 26.9, 3.6),
        "ablation": (75.8, 4.4, 13.9, 3.5),
        "devin": (44.8, 3.1, 11.7, 2.6),
        "plain": (0.0, 0.0, 6.5, 2.5),
    },
    "E2": {
        "ps": (99.9, 0.2, 24.4, 1.5),
        "ablation": (93.5, 2.0, 6.8, 0.7),
        "devin": (78.3, 5.4, 10.0, 0.9),
        "plain": (17.9, 2.7, 9.3, 2.1),
    },
    "E3": {
        "ps": (90.8, 2.3, 16.5, 1.9),
        "ablation": (95.6, 0.8, 7.2, 1.5),
        "devin": (82.6, 1.6, 9.8, 2.5),
        "plain": (0.0, 0.0, 8.4, 3.7),
    },
    "E4": {
        "ps": (95.4, 1.9, 13.2, 1.1),
        "ablation": (88.7, 1.1, 14.9, 1.0),
        "devin": (49.6, 1.1, 11.8, 2.4),
        "plain": (1.6, 1.0, 9.0, 1.4),
    },
    "E5": {
        "ps": (14.7, 2.7, 2.1, 0.4),
        "ablation": (9.6, 1.6, 4.0, 1.9),
        "devin": (8.6, 0.3, 2.9, 1.0),
        "plain": (2.8, 0.9, 3.8, 1.6),
    },
    "E6": {
        "ps": (55.6, 2.4, 8.8, 1.9),
        "ablation": (80.8, 3.4, 11.6, 2.0),
        "devin": (30.5, 4.2, 10.5, 2.1),
        "plain": (0.1, 0.2, 9.0, 0.7),
    },
    "E7": {
        "ps": (41.8, 1.7, 4.7, 1.6),
        "ablation": (13.1, 2.9, 3.6, 0.8),
        "devin": (9.8, 1.3, 3.0, 1.6),
        "plain": (0.0, 0.0, 3.2, 1.4),
    },
    "E8": {
        "ps": (18.4, 1.3, 5.3, 1.7),
        "ablation": (18.8, 2.6, 3.0, 0.7),
        "devin": (13.6, 1.1, 3.1, 0.5),
        "plain": (0.0, 0.0, 3.0, 0.7),
    },
}
