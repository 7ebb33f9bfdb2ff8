"""SAC update math in plain torch, shared by the RLlib learner and the bare-torch benchmark loop.

Choices (see docs/authors_code.md §0 and §5 for the authors' variant):
- twin critics with a min over the *target* critics (standard SAC; the authors' per-critic targets and
  target actor are not used);
- the return part of the target clipped to [-1/(1-gamma), 0], the range of a -1/0 sparse return
  (authors' trick), the entropy bonus added outside the clip;
- optional action L2 penalty on the squashed action (authors: 1.0);
- no done mask: 50-step episodes are truncated, never terminated;
- target entropy -|A| (the authors' expression is a bug).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from ps_ray.nets.modular import Actor, Critic, build_actor, build_critic
from ps_ray.specs.defaults import HIDDEN, INTERFACE_DIM
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import MethodSpec

LOG_2 = math.log(2.0)


@dataclass(frozen=True)
class SACHyper:
    gamma: float = 0.98
    clip_targets: bool = True
    action_l2: float = 0.0
    target_entropy: float | None = None  # None: -|A|


def squashed_sample(mean: Tensor, log_std: Tensor, noise: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Reparameterised tanh-Gaussian sample and its log-probability (summed over action dims);
    ``noise``: the standard normal draw to use (default: a fresh one)."""
    std = log_std.exp()
    pre = mean + std * (torch.randn_like(mean) if noise is None else noise)
    logp = (-0.5 * ((pre - mean) / std).pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
    # log|d tanh(u)/du| = 2 (log 2 - u - softplus(-2u)), numerically stable
    logp = logp - (2.0 * (LOG_2 - pre - nn.functional.softplus(-2.0 * pre))).sum(-1)
    return torch.tanh(pre), logp


NET_NAMES = ("actor", "critic", "critic_twin", "target_critic", "target_critic_twin")


class SACNets(nn.Module):
    """Actor, twin critics and their targets: the unit that is trained, saved and stitched.

    The SAC functions below take any module with these five attributes (the RLlib module too).
    """

    def __init__(self, actor: Actor, critic: Critic, critic_twin: Critic):
        super().__init__()
        self.actor, self.critic, self.critic_twin = actor, critic, critic_twin
        self.target_critic = _frozen_copy(critic)
        self.target_critic_twin = _frozen_copy(critic_twin)


def critic_pairs(nets: nn.Module) -> list[tuple[nn.Module, nn.Module]]:
    return [(nets.critic, nets.target_critic), (nets.critic_twin, nets.target_critic_twin)]


def polyak(nets: nn.Module, tau: float) -> None:
    """target <- tau * online + (1 - tau) * target for the critics of ``nets``."""
    polyak_pairs(critic_pairs(nets), tau)


@torch.no_grad()
def polyak_pairs(pairs: list[tuple[nn.Module, nn.Module]], tau: float) -> None:
    """target <- tau * online + (1 - tau) * target for parameters; buffers (normaliser statistics,
    anchors) are copied, as they are not trained."""
    targets, onlines = [], []
    for online, target in pairs:
        targets += target.parameters()
        onlines += online.parameters()
        for t, o in zip(target.buffers(), online.buffers()):
            t.copy_(o)
    torch._foreach_lerp_(targets, onlines, tau)


def build_sac_nets(
    method: str | MethodSpec,
    dims: NetDims,
    *,
    interface_dim: int = INTERFACE_DIM,
    hidden: int = HIDDEN,
    anchors: np.ndarray | None = None,
) -> SACNets:
    """Actor and twin critics of one method from the one network builder."""
    anchor_t = None if anchors is None else torch.as_tensor(anchors, dtype=torch.float32)
    kwargs = dict(interface_dim=interface_dim, hidden=hidden, anchors=anchor_t)
    return SACNets(
        build_actor(method, dims, **kwargs),
        build_critic(method, dims, **kwargs),
        build_critic(method, dims, **kwargs),
    )


def _frozen_copy(module: nn.Module) -> nn.Module:
    target = copy.deepcopy(module)
    target.requires_grad_(False)
    return target


def sac_forward(
    nets: SACNets, batch: dict[str, Tensor], noise: tuple[Tensor, Tensor] | None = None
) -> dict[str, Tensor]:
    """Every network output the SAC losses need, for one batch.

    batch: task_in, robot_in, actions, next_task_in, next_robot_in (float tensors, batch-first);
    noise: the standard normal draws of the next action and of the policy's action (default:
    fresh ones; given, a population's members and a solo learner draw alike).
    """
    task, robot, next_task, next_robot = (
        batch["task_in"],
        batch["robot_in"],
        batch["next_task_in"],
        batch["next_robot_in"],
    )
    next_noise, policy_noise = noise or (None, None)
    # Each trained net's own penalties (RelativeSpec.norm_reg, ref_weight) come from its pass over
    # the batch's task states, on its own parameters.
    out: dict[str, Tensor] = {}
    out["q"], critic_penalty = nets.critic.penalized(task, robot, batch["actions"])
    out["q_twin"], twin_penalty = nets.critic_twin.penalized(task, robot, batch["actions"])
    with torch.no_grad():
        next_action, out["logp_next"] = squashed_sample(*nets.actor(next_task, next_robot), next_noise)
        out["q_target_next"] = torch.min(
            nets.target_critic(next_task, next_robot, next_action),
            nets.target_critic_twin(next_task, next_robot, next_action),
        )
    policy, actor_penalty = nets.actor.penalized(task, robot)
    action, out["logp"] = squashed_sample(*policy, policy_noise)
    out["action"] = action
    # The actor's gradient passes through the critics without reaching their parameters.
    out["q_policy"] = torch.min(
        _fixed(nets.critic, task, robot, action), _fixed(nets.critic_twin, task, robot, action)
    )
    out["penalty"] = critic_penalty + twin_penalty + actor_penalty
    return out


def _fixed(module: nn.Module, *args: Tensor) -> Tensor:
    """``module(*args)`` with its parameters held fixed: gradients reach the inputs only. (Done
    functionally, not by switching ``requires_grad``, so that a population's stacked members,
    ``ps_ray.nets.population``, pass through it too.)"""
    state = {name: p.detach() for name, p in module.named_parameters()}
    return torch.func.functional_call(module, {**state, **dict(module.named_buffers())}, args)


def sac_losses(
    fwd: dict[str, Tensor], rewards: Tensor, log_alpha: Tensor, hp: SACHyper, action_dim: int
) -> dict[str, Tensor]:
    """Critic, actor and temperature losses; their sum gives each parameter group its own gradient."""
    alpha = log_alpha.exp().detach()
    # The return part is clipped to its possible range; the entropy bonus is added outside the clip.
    target = rewards + hp.gamma * fwd["q_target_next"]
    if hp.clip_targets:
        target = target.clamp(-1.0 / (1.0 - hp.gamma), 0.0)
    target = (target - hp.gamma * alpha * fwd["logp_next"]).detach()
    critic = (fwd["q"] - target).pow(2).mean() + (fwd["q_twin"] - target).pow(2).mean()
    actor = (alpha * fwd["logp"] - fwd["q_policy"]).mean()
    if hp.action_l2:
        actor = actor + hp.action_l2 * fwd["action"].pow(2).mean()
    target_entropy = -float(action_dim) if hp.target_entropy is None else hp.target_entropy
    alpha_loss = -(log_alpha * (fwd["logp"].detach() + target_entropy)).mean()
    total = critic + actor + alpha_loss + fwd.get("penalty", 0.0)
    return {
        "total": total,
        "critic": critic,
        "actor": actor,
        "alpha": alpha_loss,
        "q_mean": fwd["q"].detach().mean(),
        "entropy": -fwd["logp"].detach().mean(),
    }


def trained_loss(losses: dict[str, Tensor], warmup: bool) -> Tensor:
    """What the backward pass differentiates: every SAC loss, or during the critics' warm-up the
    critics' only (zero gradients leave a fresh Adam's actor and temperature exactly still).
    Element-wise, so a population's per-member losses pass too."""
    return losses["critic"] + 0.0 * (losses["actor"] + losses["alpha"]) if warmup else losses["total"]
