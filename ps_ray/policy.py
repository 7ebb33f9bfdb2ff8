"""A trained actor as a plain callable: Dict observation(s) -> greedy action(s) tanh(mean)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from ps_ray.nets.obs import split_obs


class GreedyPolicy:
    """Deterministic policy of an actor; works on one observation or a batch (leading axis)."""

    def __init__(self, actor: nn.Module):
        self.actor = actor.eval()

    @classmethod
    def from_file(cls, path: str | Path) -> GreedyPolicy:
        from ps_ray.weights import load_policy

        nets, _ = load_policy(path)
        return cls(nets.actor)

    @torch.no_grad()
    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        mean, _ = self.actor(*split_obs(obs))
        return torch.tanh(mean).numpy()
