"""The sparse goal reward shared by every env and by hindsight relabelling."""

import numpy as np

SUCCESS_DISTANCE = 0.05


def goal_reward(achieved, desired, threshold: float = SUCCESS_DISTANCE) -> np.ndarray:
    """-1 where the goal is farther than `threshold`, else 0; vectorised over leading axes."""
    distance = np.linalg.norm(np.asarray(achieved) - np.asarray(desired), axis=-1)
    return -(distance > threshold).astype(np.float32)
