"""A population's RLModule and learner: its members' SAC passes and losses as one batched pass.

A population is a grid of cells (i, i) that share nothing (:mod:`ps_ray.rllib.population_sac`),
so the grid's loop over cells, one set of kernels each, can become one pass over stacked members
(:func:`ps_ray.nets.population.members_forward` and :func:`~ps_ray.nets.population.members_losses`):
on a GPU one small update is bound by kernel launches, so K members cost about what one does.
Each member keeps its own parameters, temperature and Adam slots (its gradient reaches them through
the stack), so checkpoints, policy files and the stopping rule are the grid's; a stopped member's
columns are not in the batch and it is left out of the stack.

On a CPU the batched pass buys nothing (a core's kernels are busy either way; measured here it
cost 10-25 % more per member at K = 2-4), so there the module runs the grid's loop; model_config
``batched_update`` (None: on a GPU) says which. Both paths draw each member's noise in the same
order from the same stream, so a population trains alike on either, to float rounding.
"""

from __future__ import annotations

from typing import Any

import torch

from ps_ray.nets.population import members_forward, members_losses
from ps_ray.nets.sac import trained_loss
from ps_ray.rllib.grid_module import GridSACLearner, GridSACModule
from ps_ray.rllib.learner import sac_hyper
from ps_ray.rllib.private import learner_module

FORWARD_COLUMNS = ("task_in", "robot_in", "actions", "next_task_in", "next_robot_in")
STACKED = "members/"  # the forward's outputs, [members in the batch, ...]


class PopulationSACModule(GridSACModule):
    def members_in(self, batch: dict[str, Any]) -> list[int]:
        """The members this batch holds, in cell order (a stopped member's columns are left out)."""
        return [i for i, key in enumerate(self.keys) if f"{key}/rewards" in batch]

    def stacked(self, batch: dict[str, Any], column: str, members: list[int]) -> torch.Tensor:
        return torch.stack([batch[f"{self.keys[i]}/{column}"] for i in members])

    def forward_members(self, batch: dict[str, Any], noise: tuple[torch.Tensor, torch.Tensor]) -> dict:
        """The SAC pass of every member in ``batch``; ``noise``: ``[members, B, A]`` each."""
        members = self.members_in(batch)
        columns = {column: self.stacked(batch, column, members) for column in FORWARD_COLUMNS}
        fwd = members_forward([self.cells[i] for i in members], columns, noise)
        return {STACKED + k: v for k, v in fwd.items()}

    @property
    def batched_update(self) -> bool:
        chosen = self.model_config.get("batched_update")
        return next(self.parameters()).is_cuda if chosen is None else bool(chosen)

    def _forward_train(self, batch: dict[str, Any], **kwargs) -> dict[str, Any]:
        if not self.batched_update:
            return super()._forward_train(batch, **kwargs)
        # each member's next-action then policy noise, member by member: the grid loop's order
        draws = [
            (torch.randn_like(a), torch.randn_like(a))
            for a in (batch[f"{self.keys[i]}/actions"] for i in self.members_in(batch))
        ]
        return self.forward_members(
            batch, (torch.stack([n for n, _ in draws]), torch.stack([p for _, p in draws]))
        )


class PopulationSACLearner(GridSACLearner):
    """The grid's optimisers and temperature vector; each member's losses from the batched pass."""

    def compute_loss_for_module(self, *, module_id, config, batch, fwd_out) -> torch.Tensor:
        if STACKED + "q" not in fwd_out:  # the grid's loop ran (on a CPU)
            return super().compute_loss_for_module(
                module_id=module_id, config=config, batch=batch, fwd_out=fwd_out
            )
        module = learner_module(self, module_id)
        members = module.members_in(batch)
        log_alpha = self.curr_log_alpha[module_id][members]
        fwd = {k[len(STACKED) :]: v for k, v in fwd_out.items() if k.startswith(STACKED)}
        losses = members_losses(
            fwd,
            module.stacked(batch, "rewards", members),
            log_alpha,
            sac_hyper(config),
            module.dims.action_dim,
        )
        for j, index in enumerate(members):
            self.log_cell(module_id, module.keys[index], {k: v[j] for k, v in losses.items()}, log_alpha[j])
        return trained_loss(losses, self.updates_done(module_id) < config.critic_warmup_updates).sum()
