"""How an env's Dict observation feeds the two halves of a modular network."""

from __future__ import annotations

import numpy as np
import torch

from ps_ray.envs.goals import ROBOT_KEY, TASK_KEYS
from ps_ray.specs.dims import NetDims


def dims_from_spaces(observation_space, action_space) -> NetDims:
    spaces = observation_space.spaces
    return NetDims(
        task_dim=sum(spaces[key].shape[0] for key in TASK_KEYS),
        robot_dim=spaces[ROBOT_KEY].shape[0],
        action_dim=action_space.shape[0],
    )


def split_obs(obs: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """Dict observation (tensors or arrays, any batch shape) -> (task input, robot input) tensors."""
    as_t = lambda x: torch.as_tensor(np.asarray(x, np.float32)) if not torch.is_tensor(x) else x  # noqa: E731
    task = torch.cat([as_t(obs[key]) for key in TASK_KEYS], dim=-1)
    return task, as_t(obs[ROBOT_KEY])
