"""K independent SAC learners of one method and widths, updated as one.

Each member keeps its own weights, targets, temperature, Adam slots and batch; nothing is shared
but the kernels. Their tensors are stacked along a leading member axis
(``torch.func.stack_module_state``), the losses of all members come from one batched pass
(``torch.func.vmap`` over ``functional_call`` of :func:`ps_ray.nets.sac.sac_forward` and
:func:`~ps_ray.nets.sac.sac_losses`), and one backward of their sum gives each member the gradient
a solo learner would get (members are independent, so the sum's gradient splits by member; there
is no clipping across members). Adam and the Polyak step are element-wise, so one optimiser over
the stacks is K optimisers. On a GPU, one small update is bound by kernel launches rather than
arithmetic, so K members cost about what one does (docs/cost.md "Populations").

A member that stops (its target reached) or fails leaves with :meth:`Population.export` and
:meth:`Population.keep`; the others go on exactly as before.

:func:`members_forward` and :func:`members_losses` are the same batched pass for members that
keep their own parameters (the RLlib population learner, :mod:`ps_ray.rllib.population_module`):
their tensors are stacked differentiably on every pass, so each member's gradient lands on its
own parameters and its own optimiser slots, and a stopped member is simply left out.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ps_ray.nets.sac import SACHyper, SACNets, sac_forward, sac_losses, trained_loss

TRAINED = ("actor.", "critic.", "critic_twin.")  # parameter names the optimiser moves
TARGETS = (("target_critic.", "critic."), ("target_critic_twin.", "critic_twin."))


@dataclass(frozen=True)
class LearningRates:
    """One rate per optimiser group, as the RLlib learner has them (critic, actor, temperature)."""

    critic: float = 3e-4
    actor: float = 3e-4
    alpha: float = 3e-4


DEFAULT_HYPER, DEFAULT_RATES = SACHyper(), LearningRates()


class _Losses(nn.Module):
    """A member's SAC losses as one module call, so ``functional_call`` can run it on stacked state."""

    def __init__(self, nets: SACNets, hp: SACHyper, action_dim: int) -> None:
        super().__init__()
        self.nets, self.hp, self.action_dim = nets, hp, action_dim

    def forward(self, batch, rewards, log_alpha, next_noise, policy_noise, warmup: bool) -> Tensor:
        fwd = sac_forward(self.nets, batch, (next_noise, policy_noise))
        return trained_loss(sac_losses(fwd, rewards, log_alpha, self.hp, self.action_dim), warmup)


class _Forward(nn.Module):
    """A member's :func:`sac_forward` as one module call (for ``functional_call`` on stacked state)."""

    def __init__(self, nets: nn.Module) -> None:
        super().__init__()
        self.nets = nets

    def forward(self, batch, next_noise, policy_noise) -> dict[str, Tensor]:
        return sac_forward(self.nets, batch, (next_noise, policy_noise))


def members_forward(
    members: Sequence[nn.Module], batch: Mapping[str, Tensor], noise: tuple[Tensor, Tensor]
) -> dict[str, Tensor]:
    """:func:`sac_forward` of each member on its own batch, as one batched pass: batch tensors
    ``[K, B, ...]``, noise ``[K, B, A]`` each; outputs ``[K, ...]``. Members built alike (the
    modules of a :class:`~ps_ray.nets.sac.SACNets` or a grid cell's view); their parameters are
    stacked with ``torch.stack``, so gradients flow back to each member's own."""
    template = _Forward(members[0])  # its own tensors are swapped for the stacks during the call
    named = [dict(m.named_parameters()) | dict(m.named_buffers()) for m in members]
    state = {f"nets.{name}": torch.stack([n[name] for n in named]) for name in named[0]}

    def one(member_state, member_batch, next_noise, policy_noise):
        return torch.func.functional_call(template, member_state, (member_batch, next_noise, policy_noise))

    return torch.func.vmap(one)(state, dict(batch), *noise)


def members_losses(
    fwd: Mapping[str, Tensor], rewards: Tensor, log_alpha: Tensor, hp: SACHyper, action_dim: int
) -> dict[str, Tensor]:
    """:func:`sac_losses` of each member (``fwd`` from :func:`members_forward`, rewards ``[K, B]``,
    ``log_alpha`` ``[K]``): every loss ``[K]``, each member's from its own outputs only."""

    def one(member_fwd, member_rewards, member_log_alpha):
        return sac_losses(member_fwd, member_rewards, member_log_alpha, hp, action_dim)

    return torch.func.vmap(one)(dict(fwd), rewards, log_alpha)


class Population:
    """Members built alike (one method, widths and anchor count), each with its own state."""

    def __init__(
        self,
        members: Sequence[SACNets],
        *,
        hp: SACHyper = DEFAULT_HYPER,
        lrs: LearningRates = DEFAULT_RATES,
        tau: float = 0.005,
        initial_alpha: float = 1.0,
        capturable: bool = False,
    ) -> None:
        if not members:
            raise ValueError("a population needs at least one member")
        self.hp, self.lrs, self.tau, self.capturable = hp, lrs, tau, capturable
        self.action_dim = members[0].actor.dims.action_dim
        self._loss = _Losses(copy.deepcopy(members[0]).to("meta"), hp, self.action_dim)
        params, buffers = torch.func.stack_module_state(list(members))
        self.trained = {k: v for k, v in params.items() if k.startswith(TRAINED)}
        # targets are not trained: held with the buffers, moved only by the Polyak step
        self.fixed = {**{k: v.detach() for k, v in params.items() if k not in self.trained}, **buffers}
        device = next(iter(self.trained.values())).device
        alpha = torch.full((len(members),), float(initial_alpha), device=device).log()
        self.log_alpha = alpha.requires_grad_()
        self.optimizer = self._optimizer()
        self._batched = torch.func.vmap(self._member_loss, in_dims=(0, 0, 0, 0, 0, 0, 0, None))

    def __len__(self) -> int:
        return self.log_alpha.shape[0]

    def _optimizer(self) -> torch.optim.Adam:
        groups = {"critic": [], "actor": []}
        for name, tensor in self.trained.items():
            groups["actor" if name.startswith("actor.") else "critic"].append(tensor)
        return torch.optim.Adam(
            [
                {"params": groups["critic"], "lr": self.lrs.critic},
                {"params": groups["actor"], "lr": self.lrs.actor},
                {"params": [self.log_alpha], "lr": self.lrs.alpha},
            ],
            capturable=self.capturable,
        )

    def _member_loss(self, trained, fixed, log_alpha, batch, rewards, next_noise, policy_noise, warmup):
        state = {**{f"nets.{k}": v for k, v in trained.items()}, **{f"nets.{k}": v for k, v in fixed.items()}}
        args = (batch, rewards, log_alpha, next_noise, policy_noise, warmup)
        return torch.func.functional_call(self._loss, state, args)

    def update(
        self,
        batch: Mapping[str, Tensor],
        rewards: Tensor,
        noise: tuple[Tensor, Tensor] | None = None,
        warmup: bool = False,
    ) -> Tensor:
        """One gradient update of every member on its own batch (tensors ``[K, B, ...]``; rewards
        ``[K, B]``), then the Polyak step; returns each member's loss. ``noise``: the standard
        normal draws of the next and the policy actions, ``[K, B, A]`` each (default: fresh);
        ``warmup``: critics only."""
        if noise is None:
            shape = (*rewards.shape, self.action_dim)
            noise = (torch.randn(shape, device=rewards.device), torch.randn(shape, device=rewards.device))
        losses = self._batched(self.trained, self.fixed, self.log_alpha, dict(batch), rewards, *noise, warmup)
        self.optimizer.zero_grad(set_to_none=False)
        losses.sum().backward()  # members are independent: the sum's gradient is each one's own
        self.optimizer.step()
        self._polyak()
        return losses.detach()

    def captured(
        self,
        batch: Mapping[str, Tensor],
        rewards: Tensor,
        noise: tuple[Tensor, Tensor] | None = None,
        warmups: int = 3,
    ) -> Callable[[], None]:
        """The whole update (passes, losses, backward, Adam, Polyak, and fresh noise unless
        ``noise`` is given) on these tensors, captured as one CUDA graph; returns its replay, one
        update of every member per call. The tensors are the graph's inputs: refill them in place
        between replays. First ``warmups`` ordinary updates on them, off the capture (gradients and
        Adam slots allocated). Needs CUDA tensors and ``capturable=True`` (Adam's step counts on
        the GPU)."""
        if not self.capturable:
            raise ValueError("a captured update needs Population(..., capturable=True)")
        if warmups < 1:  # Adam's slots made inside the capture would start afresh on every replay
            raise ValueError(f"a captured update needs at least one warm-up update, got {warmups}")
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            for _ in range(warmups):
                self.update(batch, rewards, noise)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            self.update(batch, rewards, noise)
        members, inputs = self.log_alpha, (batch, rewards, noise)  # the graph's tensors, kept alive

        def replay() -> None:
            if self.log_alpha is not members:  # keep() replaced the tensors the graph writes
                raise RuntimeError("the population changed members since this update was captured")
            graph.replay()

        replay.inputs = inputs
        return replay

    @torch.no_grad()
    def _polyak(self) -> None:
        targets, onlines = [], []
        for target_prefix, online_prefix in TARGETS:
            for name, target in self.fixed.items():
                if not name.startswith(target_prefix):
                    continue
                online_name = online_prefix + name[len(target_prefix) :]
                if online_name in self.trained:
                    targets.append(target)
                    onlines.append(self.trained[online_name])
                else:  # a buffer (normaliser statistics, anchors): copied, not trained
                    target.copy_(self.fixed[online_name])
        torch._foreach_lerp_(targets, [o.detach() for o in onlines], self.tau)

    def export(self, index: int, into: SACNets) -> tuple[SACNets, Tensor]:
        """Member ``index``'s nets (loaded into ``into``, a member built alike) and log alpha."""
        state = {k: v[index].detach().clone() for k, v in {**self.trained, **self.fixed}.items()}
        into.load_state_dict(state)
        return into, self.log_alpha[index].detach().clone()

    def keep(self, indices: Sequence[int]) -> None:
        """Go on with only these members (the others stopped or failed): their weights, targets,
        temperatures and Adam slots are kept as they are, so they update on as if never grouped.
        A captured update reads the old tensors: capture again."""
        index = torch.as_tensor(list(indices), dtype=torch.long, device=self.log_alpha.device)
        if index.numel() == 0:
            raise ValueError("a population keeps at least one member")
        old = self.optimizer
        slots = {id(p): old.state[p] for group in old.param_groups for p in group["params"] if p in old.state}
        pick = {}  # old tensor -> new tensor
        for table in (self.trained,):
            for name, tensor in table.items():
                table[name] = tensor.detach()[index].clone().requires_grad_()
                pick[id(tensor)] = table[name]
        for name, tensor in self.fixed.items():
            self.fixed[name] = tensor[index].clone()
        alpha = self.log_alpha
        self.log_alpha = alpha.detach()[index].clone().requires_grad_()
        pick[id(alpha)] = self.log_alpha
        self.optimizer = self._optimizer()
        for old_id, new in pick.items():
            if old_id in slots:
                self.optimizer.state[new] = {
                    k: v if k == "step" else v[index].clone() for k, v in slots[old_id].items()
                }
