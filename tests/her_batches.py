"""Replay batches for the HindsightReplay tests: episodes whose every value encodes (episode id, step)."""

from __future__ import annotations

import numpy as np

from ps_ray.data.her import HindsightReplay


def stack_episodes(episodes, action_key: str = "actions"):
    """Per-episode dicts ({key: (T+1, *shape)}, action_key: (T, A)) -> add_episodes input."""
    obs = {k: np.stack([ep[k] for ep in episodes]) for k in episodes[0] if k != action_key}
    return obs, np.stack([ep[action_key] for ep in episodes])


T, A = 6, 2
SPEC = {
    "robot_state": ((4,), np.float32),
    "task_state": ((2, 3), np.float32),  # a multi-dim key, to exercise the flat views
    "achieved_goal": ((3,), np.float32),
    "desired_goal": ((3,), np.float32),
}
ID0 = 100  # episode ids start here so untouched (zero) slots can never decode as an episode


def reward_fn(achieved: np.ndarray, desired: np.ndarray) -> np.ndarray:
    return -(np.linalg.norm(achieved - desired, axis=-1) > 0.05).astype(np.float32)


def episode(eid: int) -> dict[str, np.ndarray]:
    """Every value encodes (episode id, step); desired goal (eid, -1, 2) is never an achieved goal."""
    t = np.arange(T + 1, dtype=np.float32)
    e = np.full(T + 1, eid, np.float32)
    return {
        "robot_state": np.stack([e, t, t + 0.25, e + 0.5], -1),
        "task_state": np.stack([e, t, e, t, e, t], -1).reshape(T + 1, 2, 3),
        "achieved_goal": np.stack([e, t, np.ones_like(t)], -1),
        "desired_goal": np.stack([e, -np.ones_like(t), 2 * np.ones_like(t)], -1),
        "actions": np.stack([e[:T], t[:T]], -1),
    }


def batch(ids) -> tuple[dict[str, np.ndarray], np.ndarray]:
    return stack_episodes([episode(i) for i in ids])


def make(capacity: int = 50, p: float = 0.8, seed: int | None = 0) -> HindsightReplay:
    return HindsightReplay(SPEC, A, T, capacity, reward_fn, relabel_prob=p, seed=seed)
