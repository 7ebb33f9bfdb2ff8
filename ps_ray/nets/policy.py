"""The one greedy policy: a trained actor as a plain callable, Dict observation(s) -> tanh(mean).

``fast=True`` (used by batched evaluation) embeds a PS actor's anchors once instead of at every
forward and traces and freezes the forward with TorchScript (about half the eager per-op overhead
at evaluation batch sizes). Weights and normaliser statistics are fixed in a greedy policy, so
both paths give the actor's own actions up to float rounding (``tests/test_evaluate.py``)."""

from __future__ import annotations

import copy
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ps_ray.nets.modular import Actor
from ps_ray.nets.obs import split_obs
from ps_ray.nets.relative import AnchorReference
from ps_ray.specs.dims import NetDims


class _GreedyNet(nn.Module):
    """tanh(mean) of an actor; with ``reference`` the relative projection's anchor side is given
    (computed once) instead of re-embedded at every forward. Whether a deferred projection is on
    is settled here, once, so that a trace holds no branch on a tensor."""

    def __init__(self, actor: Actor, reference: AnchorReference | None) -> None:
        super().__init__()
        self.actor, self.reference = actor, reference
        self.projection_off = actor.task.projection_off

    def forward(self, task_in: torch.Tensor, robot_in: torch.Tensor) -> torch.Tensor:
        task = self.actor.task
        if self.reference is not None:
            latent = task.relative.project(task.encode(task_in), self.reference)
        elif self.projection_off:
            latent = task.encode(task_in)
        else:
            mean, _ = self.actor(task_in, robot_in)
            return torch.tanh(mean)
        mean, _ = self.actor.robot(self.actor.to_robot(latent), robot_in)
        return torch.tanh(mean)


def _traced(net: nn.Module, example: tuple[torch.Tensor, ...]) -> nn.Module:
    """TorchScript trace + freeze. torch.jit is deprecated (still working in the pinned torch);
    without it, the eager module."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            # no check_trace: it runs the net again and costs more than the trace (0.5 s per policy);
            # tests/test_evaluate.py checks the traced actions against the actor's
            return torch.jit.freeze(torch.jit.trace(net, example, check_trace=False))
    except (AttributeError, RuntimeError):
        return net


class GreedyPolicy:
    """Deterministic policy of an actor on one observation or a batch (leading axis). The actor is
    copied, so the caller's module keeps its mode and later training does not change the policy."""

    def __init__(self, actor: Actor, fast: bool = False) -> None:
        actor = copy.deepcopy(actor).eval()
        self.dims: NetDims = actor.dims
        reference = None
        with torch.no_grad():
            if fast and actor.task.projection is not None:
                relative = actor.task.projection
                reference = relative.reference(actor.task.encode(relative.anchors))
            self.net: nn.Module = _GreedyNet(actor, reference).eval()
            if fast:
                example = (torch.zeros(2, self.dims.task_dim), torch.zeros(2, self.dims.robot_dim))
                self.net = _traced(self.net, example)

    @classmethod
    def from_file(cls, path: str | Path, fast: bool = False) -> GreedyPolicy:
        from ps_ray.nets.policy_file import load_policy

        nets, _ = load_policy(path)
        return cls(nets.actor, fast)

    @torch.inference_mode()
    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return self.net(*split_obs(obs)).numpy()
