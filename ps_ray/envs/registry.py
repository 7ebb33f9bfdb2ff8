"""Explicit registration: gymnasium ids for every built-in pair, and the RLlib env ``"ps_ray"``.

Gymnasium ids are ``ps_ray/<Robot><Task>-v0`` with CamelCase names, e.g. ``ps_ray/PandaReach-v0``,
``ps_ray/PandaL3PushSlippery-v0``, ``ps_ray/PandaL5PickStick-v0``. They carry no TimeLimit
wrapper: the env truncates itself after ``max_episode_steps`` (50). Keyword arguments to
``gymnasium.make`` go to :func:`ps_ray.envs.make` (render_mode, task options).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium

from . import BUILTIN_PAIRS
from .core import RobotTaskEnv, make

RLLIB_ENV = "ps_ray"
RLLIB_GYM_ENV = "ps_ray_gym"  # any gymnasium env of ps_ray's observation layout, by id (TrainSpec.env)
RLLIB_GRID_ENV = "ps_ray_grid"  # the trained cells of a co-trained grid side by side (GridEnv)
NAMESPACE = "ps_ray"


def env_id(robot: str, task: str) -> str:
    camel = lambda name: "".join(part.capitalize() for part in name.split("_"))  # noqa: E731
    return f"{NAMESPACE}/{camel(robot)}{camel(task)}-v0"


def create_env(env_config: Mapping[str, Any]) -> RobotTaskEnv:
    """RLlib env creator: ``env_config = {"robot": ..., "task": ..., **options}``."""
    return make(**dict(env_config))


def register(rllib: bool = True) -> list[str]:
    """Register the gymnasium ids (idempotent) and, if ``rllib``, the Tune envs ``"ps_ray"``,
    ``"ps_ray_gym"`` and ``"ps_ray_grid"``."""
    ids = []
    for robot, task in BUILTIN_PAIRS:
        ids.append(env_id(robot, task))
        if ids[-1] not in gymnasium.registry:
            gymnasium.register(ids[-1], entry_point=RobotTaskEnv, kwargs={"robot": robot, "task": task})
    if rllib:
        from ray.tune.registry import register_env

        from .grid import GridEnv

        register_env(RLLIB_ENV, create_env)
        register_env(RLLIB_GYM_ENV, lambda env_config: gymnasium.make(env_config["id"]))
        register_env(
            RLLIB_GRID_ENV, lambda env_config: GridEnv(env_config["cells"], env_config.get("seed_offsets"))
        )
    return ids
