"""The co-trained grid on RLlib: one RLModule that holds every task and robot module of a grid
(:mod:`ps_ray.nets.grid`), and its learner, whose update sums the cells' SAC losses, each cell with
its own temperature (Devin et al. 2017's joint training; docs/transfer.md "Co-trained grids").

The module acts on :class:`ps_ray.envs.grid.GridEnv`'s observation (a Dict of the cells' own) and
returns the cells' actions side by side. Its learner batch holds each cell's columns under
``"<cell key>/"`` (:func:`grid_train_batch`), one minibatch of every cell per update.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from ray.rllib.core.columns import Columns
from ray.rllib.core.rl_module.apis import InferenceOnlyAPI
from ray.rllib.core.rl_module.torch.torch_rl_module import TorchRLModule

from ps_ray.envs.goals import ROBOT_KEY, TASK_KEYS
from ps_ray.nets.grid import ACTOR_TABLES, GRID_TABLES, add_grid_modules, grid_critic_pairs
from ps_ray.nets.obs import split_obs
from ps_ray.nets.sac import polyak_pairs, sac_forward, sac_losses, squashed_sample, trained_loss
from ps_ray.rllib.episodes import train_batch
from ps_ray.rllib.learner import ModularSACLearner, sac_hyper
from ps_ray.rllib.private import learner_module
from ps_ray.specs.dims import NetDims


def grid_train_batch(samples: dict[str, dict[str, np.ndarray]]) -> dict[str, torch.Tensor]:
    """Each cell's HER sample (by cell key) -> one flat batch of ``"<key>/<column>"`` tensors."""
    return {f"{key}/{k}": v for key, sample in samples.items() for k, v in train_batch(sample).items()}


def grid_modules(owner: torch.nn.Module, model_config: dict[str, Any], dims: NetDims) -> list:
    """The grid's module tables on ``owner`` as the module's ``model_config`` describes them;
    returns each trained cell's view (:func:`ps_ray.nets.grid.add_grid_modules`)."""
    return add_grid_modules(
        owner,
        model_config["method"],
        dims,
        tasks=model_config["tasks"],
        robots=model_config["robots"],
        cells=[tuple(c) for c in model_config["cells"]],
        interface_dim=model_config["interface_dim"],
        hidden=model_config["hidden"],
        anchors=[None if a is None else np.asarray(a, np.float32) for a in model_config["anchors"]],
    )


class GridSACModule(TorchRLModule, InferenceOnlyAPI):
    """model_config keys: method, interface_dim, hidden, tasks and robots (counts), cells
    ((task index, robot index) per trained cell, in the env's cell order), anchors (per task: an
    array or None)."""

    def setup(self) -> None:
        cfg = self.model_config
        self.keys = list(self.observation_space.spaces)
        first = self.observation_space[self.keys[0]].spaces
        self.dims = NetDims(
            task_dim=sum(first[k].shape[0] for k in TASK_KEYS),
            robot_dim=first[ROBOT_KEY].shape[0],
            action_dim=self.action_space.shape[0] // len(self.keys),
        )
        self.cells = grid_modules(self, cfg, self.dims)

    # -- acting: every cell's actor on its own observation, actions side by side ---------------
    def _forward_inference(self, batch: dict[str, Any], **kwargs) -> dict[str, Any]:
        obs = batch[Columns.OBS]
        means = [cell.actor(*split_obs(obs[key]))[0] for key, cell in zip(self.keys, self.cells)]
        return {Columns.ACTIONS: torch.tanh(torch.cat(means, -1))}

    def _forward_exploration(self, batch: dict[str, Any], **kwargs) -> dict[str, Any]:
        obs = batch[Columns.OBS]
        with torch.no_grad():
            samples = [
                squashed_sample(*cell.actor(*split_obs(obs[key]))) for key, cell in zip(self.keys, self.cells)
            ]
        return {
            Columns.ACTIONS: torch.cat([a for a, _ in samples], -1),
            Columns.ACTION_LOGP: torch.stack([logp for _, logp in samples]).sum(0),
        }

    # -- learning ------------------------------------------------------------------------------
    def _forward_train(self, batch: dict[str, Any], **kwargs) -> dict[str, Any]:
        """Each cell the batch holds (a population's stopped members are left out of it)."""
        out = {}
        for key, cell in zip(self.keys, self.cells):
            prefix = key + "/"
            cell_batch = {k[len(prefix) :]: v for k, v in batch.items() if k.startswith(prefix)}
            if cell_batch:
                out.update({prefix + k: v for k, v in sac_forward(cell, cell_batch).items()})
        return out

    def get_non_inference_attributes(self) -> list[str]:
        return [name for name in GRID_TABLES if name not in ACTOR_TABLES]


class GridSACLearner(ModularSACLearner):
    """One critic, one actor and one temperature optimiser for the whole grid (a shared module is
    stepped once per update, with the sum of its cells' gradients); the temperature is a vector,
    one per cell."""

    def configure_optimizers_for_module(self, module_id, config=None) -> None:
        module = learner_module(self, module_id)
        self.curr_log_alpha[module_id] = self._get_tensor_variable(
            [float(np.log(config.initial_alpha))] * len(module.cells), trainable=True
        )
        super().configure_optimizers_for_module(module_id, config)

    @staticmethod
    def net_groups(module) -> dict[str, list[torch.nn.Parameter]]:
        tables = lambda names: [p for n in names for p in getattr(module, n).parameters()]  # noqa: E731
        return {
            "critic": tables(["critic_tasks", "critic_robots", "critic_twin_tasks", "critic_twin_robots"]),
            "actor": tables(["actor_tasks", "actor_robots"]),
        }

    def compute_loss_for_module(self, *, module_id, config, batch, fwd_out) -> torch.Tensor:
        module = learner_module(self, module_id)
        hp = sac_hyper(config)
        log_alpha = self.curr_log_alpha[module_id]
        warm = self.updates_done(module_id) < config.critic_warmup_updates
        total = 0.0
        for index, key in enumerate(module.keys):
            prefix = key + "/"
            if prefix + "rewards" not in batch:
                continue  # not in this update: its parameters get no gradient, Adam leaves them be
            fwd = {k[len(prefix) :]: v for k, v in fwd_out.items() if k.startswith(prefix)}
            losses = sac_losses(fwd, batch[prefix + "rewards"], log_alpha[index], hp, module.dims.action_dim)
            total = total + trained_loss(losses, warm)
            self.log_cell(module_id, key, losses, log_alpha[index])
        return total

    def log_cell(self, module_id, key: str, losses: dict[str, torch.Tensor], log_alpha: torch.Tensor) -> None:
        """One cell's losses, temperature and entropy, logged as-is (window 1)."""
        self.metrics.log_dict(
            {
                f"{key}_critic_loss": losses["critic"],
                f"{key}_actor_loss": losses["actor"],
                f"{key}_alpha": log_alpha.detach().exp(),
                f"{key}_entropy": losses["entropy"],
            },
            key=module_id,
            window=1,
        )

    @staticmethod
    def update_targets(module, tau: float) -> None:
        polyak_pairs(grid_critic_pairs(module), tau)

    @staticmethod
    def module_tensors(module) -> dict[str, torch.Tensor]:
        return {k: v.detach().cpu().clone() for k, v in module.state_dict().items()}

    @staticmethod
    def load_module_tensors(module, state: dict[str, torch.Tensor]) -> None:
        module.load_state_dict(
            {k: v for k, v in state.items() if k.split(".")[0] in GRID_TABLES}, strict=True
        )
