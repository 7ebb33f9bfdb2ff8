"""PyBullet environments of Policy Stitching: Panda variants x reach / push / pick tasks.

No torch or Ray here; gymnasium and RLlib registration live in :mod:`ps_ray.envs.registry`.
"""

from ._quiet import import_pybullet

import_pybullet()  # before any module here imports it: its banner would precede every message

from .core import EPISODE_STEPS, RobotTaskEnv, make  # noqa: E402
from .goals import SUCCESS_DISTANCE, goal_distance, goal_reward, task_input  # noqa: E402
from .robots import ROBOTS, RobotSpec  # noqa: E402
from .tasks import GOAL_REGIONS, TASKS  # noqa: E402

BUILTIN_PAIRS: list[tuple[str, str]] = [(robot, task) for robot in ROBOTS for task in TASKS]

__all__ = [
    "BUILTIN_PAIRS",
    "EPISODE_STEPS",
    "GOAL_REGIONS",
    "ROBOTS",
    "SUCCESS_DISTANCE",
    "TASKS",
    "RobotSpec",
    "RobotTaskEnv",
    "goal_distance",
    "goal_reward",
    "make",
    "task_input",
]
