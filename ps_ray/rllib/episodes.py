"""RLlib episodes -> fixed-length arrays for the HER buffer, episode metrics, learner batches."""

from __future__ import annotations

import numpy as np
import torch

from ps_ray.envs.goals import ROBOT_KEY, task_input

OBS_PREFIX, NEXT_PREFIX = "obs/", "next_obs/"


def episodes_to_arrays(episodes: list) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Stack complete, equal-length episodes: obs[k] (N, T+1, ...), actions (N, T, A)."""
    observations = [ep.get_observations() for ep in episodes]
    obs = {k: np.stack([o[k] for o in observations]).astype(np.float32, copy=False) for k in observations[0]}
    actions = np.stack([ep.get_actions() for ep in episodes]).astype(np.float32, copy=False)
    return obs, actions


def episode_stats(episodes: list) -> dict[str, float]:
    """Success at the last step; touching rate over episodes that did not start successful."""
    infos = [ep.get_infos() for ep in episodes]
    success = np.mean([float(i[-1]["is_success"]) for i in infos])
    eligible = [i for i in infos if not i[0]["initially_successful"]]
    touching = np.mean([float(any(x["touching"] for x in i)) for i in eligible]) if eligible else float("nan")
    return {
        "success": float(success),
        "touching": float(touching),
        "return": float(np.mean([ep.get_return() for ep in episodes])),
    }


def train_batch(sample: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """HER sample (flat 'obs/<key>' arrays) -> the tensors `sac_forward` reads."""

    def halves(prefix: str) -> tuple[torch.Tensor, torch.Tensor]:
        task = task_input(sample, prefix)
        return torch.from_numpy(task), torch.from_numpy(sample[prefix + ROBOT_KEY])

    task_in, robot_in = halves(OBS_PREFIX)
    next_task_in, next_robot_in = halves(NEXT_PREFIX)
    return {
        "task_in": task_in,
        "robot_in": robot_in,
        "next_task_in": next_task_in,
        "next_robot_in": next_robot_in,
        "actions": torch.from_numpy(sample["actions"]),
        "rewards": torch.from_numpy(sample["rewards"]),
    }
