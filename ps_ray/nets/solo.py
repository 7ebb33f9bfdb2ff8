"""One SAC learner alone, as the RLlib learner runs it: :func:`~ps_ray.nets.sac.sac_forward` and
:func:`~ps_ray.nets.sac.sac_losses`, one backward, an Adam per group (critic, actor,
temperature), then the Polyak step. The reference a population's members are checked against
(tests/test_population.py, ``ps-ray bench gpu``). ``capturable``: PyTorch's capturable Adam, the one
a population captured as a CUDA graph runs (its bias corrections are float32 tensors on the
device, ``1 - 0.999 ** t`` to about 1e-4 at the first steps, so its steps differ from the plain
Adam's by more than a rounding)."""

from __future__ import annotations

import torch
from torch import Tensor

from ps_ray.nets.population import DEFAULT_HYPER, DEFAULT_RATES, LearningRates
from ps_ray.nets.sac import SACHyper, SACNets, polyak, sac_forward, sac_losses, trained_loss


class SoloLearner:
    def __init__(
        self,
        nets: SACNets,
        *,
        hp: SACHyper = DEFAULT_HYPER,
        lrs: LearningRates = DEFAULT_RATES,
        tau: float = 0.005,
        initial_alpha: float = 1.0,
        capturable: bool = False,
    ) -> None:
        self.nets, self.hp, self.tau = nets, hp, tau
        device = next(nets.parameters()).device
        self.log_alpha = torch.full((1,), float(initial_alpha), device=device).log().requires_grad_()
        critics = [*nets.critic.parameters(), *nets.critic_twin.parameters()]
        groups = [(critics, lrs.critic), (nets.actor.parameters(), lrs.actor), ([self.log_alpha], lrs.alpha)]
        self.optimizers = [torch.optim.Adam(p, lr=lr, capturable=capturable) for p, lr in groups]

    def update(self, batch: dict[str, Tensor], rewards: Tensor, noise: tuple[Tensor, Tensor], warmup=False):
        """One update on ``batch`` (tensors ``[B, ...]``) with these standard normal draws of the
        next and the policy actions; ``warmup``: critics only. Returns the loss."""
        fwd = sac_forward(self.nets, batch, noise)
        losses = sac_losses(fwd, rewards, self.log_alpha, self.hp, self.nets.actor.dims.action_dim)
        total = trained_loss(losses, warmup)
        for optimizer in self.optimizers:
            optimizer.zero_grad()
        total.backward()
        for optimizer in self.optimizers:
            optimizer.step()
        polyak(self.nets, self.tau)
        return total.detach()
