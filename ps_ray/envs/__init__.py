"""PyBullet environments of Policy Stitching: Panda variants x reach / push / pick tasks.

No torch or Ray here; gymnasium and RLlib registration live in :mod:`ps_ray.envs.registry`.
"""

from .core import EPISODE_STEPS, RobotTaskEnv, make
from .goals import SUCCESS_DISTANCE, goal_distance, goal_reward, task_input
from .robots import ROBOTS, RobotSpec
from .tasks import GOAL_REGIONS, TASKS

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
