"""Goal-conditioned helpers shared by the env, HER and evaluation: pure numpy, any batch shape."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

SUCCESS_DISTANCE = 0.05  # metres, the paper's threshold for reward and success
GOAL_DIM = 3  # achieved_goal and desired_goal: a position in metres
TASK_KEYS = ("task_state", "desired_goal")  # the task module's input, in this order
ROBOT_KEY = "robot_state"  # the robot module's input (7 joint angles, then the finger width)


def goal_distance(achieved: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """Euclidean distance over the last axis."""
    return np.linalg.norm(np.asarray(achieved) - np.asarray(desired), axis=-1)


def goal_reward(achieved: np.ndarray, desired: np.ndarray, threshold: float = SUCCESS_DISTANCE) -> np.ndarray:
    """Sparse reward: -1 where ``||achieved - desired|| > threshold``, else 0 (float32, batch shape)."""
    return (goal_distance(achieved, desired) <= threshold).astype(np.float32) - np.float32(1.0)


def task_input(obs: Mapping[str, np.ndarray], prefix: str = "") -> np.ndarray:
    """The task module's input: ``task_state`` then ``desired_goal`` (single or batched obs;
    ``prefix`` reads flat replay keys such as ``"obs/task_state"``)."""
    return np.concatenate([np.asarray(obs[prefix + key]) for key in TASK_KEYS], axis=-1)
