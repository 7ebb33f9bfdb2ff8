"""The SAC RLModule (new API stack): maps ps_ray's plain-torch nets onto RLlib.

The module takes the env's Dict observation directly. Its actor, twin critics and target critics
are built together in `setup`, so a checkpoint always carries the targets. Acting returns actions
(and their log-probabilities) itself, so the module declares no RLlib action distribution.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from ray.rllib.core.columns import Columns
from ray.rllib.core.rl_module.apis import InferenceOnlyAPI, QNetAPI, TargetNetworkAPI
from ray.rllib.core.rl_module.torch.torch_rl_module import TorchRLModule

from ps_ray.nets.obs import dims_from_spaces, split_obs
from ps_ray.nets.sac import NET_NAMES, build_sac_nets, critic_pairs, sac_forward, squashed_sample

CRITIC_ATTRS = [name for name in NET_NAMES if name != "actor"]


class ModularSACModule(TorchRLModule, InferenceOnlyAPI, TargetNetworkAPI, QNetAPI):
    """model_config keys: method, interface_dim, hidden, anchors (array or None)."""

    def setup(self) -> None:
        cfg = self.model_config
        self.dims = dims_from_spaces(self.observation_space, self.action_space)
        anchors = cfg.get("anchors")
        nets = build_sac_nets(
            cfg["method"],
            self.dims,
            interface_dim=cfg["interface_dim"],
            hidden=cfg["hidden"],
            anchors=None if anchors is None else np.asarray(anchors, np.float32),
        )
        # The nets become attributes of the module itself: RLlib removes the critics from an
        # inference-only copy (env runners) by top-level attribute name.
        for name in NET_NAMES:
            setattr(self, name, getattr(nets, name))

    # -- acting -------------------------------------------------------------------------------
    def _forward_inference(self, batch: dict[str, Any], **kwargs) -> dict[str, Any]:
        mean, _ = self.actor(*split_obs(batch[Columns.OBS]))
        return {Columns.ACTIONS: torch.tanh(mean)}

    def _forward_exploration(self, batch: dict[str, Any], **kwargs) -> dict[str, Any]:
        with torch.no_grad():
            action, logp = squashed_sample(*self.actor(*split_obs(batch[Columns.OBS])))
        return {Columns.ACTIONS: action, Columns.ACTION_LOGP: logp}

    # -- learning -----------------------------------------------------------------------------
    def _forward_train(self, batch: dict[str, Any], **kwargs) -> dict[str, Any]:
        return sac_forward(self, batch)

    def compute_q_values(self, batch: dict[str, Any]) -> torch.Tensor:
        task, robot = split_obs(batch[Columns.OBS])
        actions = batch[Columns.ACTIONS]
        return torch.min(self.critic(task, robot, actions), self.critic_twin(task, robot, actions))

    def make_target_networks(self) -> None:
        """Targets are built with the critics in `setup`, so checkpoints always hold them."""

    def get_target_network_pairs(self):
        return critic_pairs(self)

    def forward_target(self, batch: dict[str, Any]) -> torch.Tensor:
        task, robot = split_obs(batch[Columns.OBS])
        actions = batch[Columns.ACTIONS]
        return torch.min(
            self.target_critic(task, robot, actions), self.target_critic_twin(task, robot, actions)
        )

    def get_non_inference_attributes(self) -> list[str]:
        return list(CRITIC_ATTRS)
