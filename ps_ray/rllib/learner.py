"""SAC learner for ModularSACModule: ps_ray's loss math, one backward, Polyak after every update."""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import torch
from ray.rllib.algorithms.sac.torch.sac_torch_learner import SACTorchLearner
from ray.rllib.core import DEFAULT_MODULE_ID
from ray.rllib.core.rl_module.torch.torch_compile_config import TorchCompileConfig

from ps_ray.nets.from_signature import load_nets_state, nets_state
from ps_ray.nets.sac import SACHyper, polyak, sac_losses, trained_loss
from ps_ray.rllib.private import after_update_without_target_sync, gradients_in_one_backward, learner_module

OPTIMIZER_PREFIX = "optimizer."
LOG_ALPHA = "log_alpha"


def sac_hyper(config) -> SACHyper:
    """The loss settings of an algorithm config (RLlib's ``target_entropy="auto"``: minus |A|)."""
    entropy = None if config.target_entropy == "auto" else float(config.target_entropy)
    return SACHyper(
        gamma=config.gamma,
        clip_targets=config.clip_targets,
        action_l2=config.action_l2,
        target_entropy=entropy,
    )


class ModularSACLearner(SACTorchLearner):
    def build(self) -> None:
        super().build()
        # Ray 2.60 asks for a compiled forward_train but skips the modules of a MultiRLModule
        # (TorchLearner.build tests the container, not each module): compile them here.
        if self.config.torch_compile_learner:
            compile_config = TorchCompileConfig(
                torch_dynamo_backend=self.config.torch_compile_learner_dynamo_backend,
                torch_dynamo_mode=self.config.torch_compile_learner_dynamo_mode,
            )
            for module_id in self.module.keys():
                learner_module(self, module_id).compile(compile_config)

    def configure_optimizers_for_module(self, module_id, config=None) -> None:
        nets = self.net_groups(learner_module(self, module_id))
        groups = {
            "critic": (nets["critic"], config.critic_lr),
            "actor": (nets["actor"], config.actor_lr),
            "alpha": ([self.curr_log_alpha[module_id]], config.alpha_lr),
        }
        for name, (params, lr) in groups.items():
            self.register_optimizer(
                module_id=module_id,
                optimizer_name=name,
                optimizer=torch.optim.Adam(params),
                params=params,
                lr_or_lr_schedule=lr,
            )

    @staticmethod
    def net_groups(module) -> dict[str, list[torch.nn.Parameter]]:
        """The parameters of the critic and the actor optimiser."""
        return {
            "critic": list(module.critic.parameters()) + list(module.critic_twin.parameters()),
            "actor": list(module.actor.parameters()),
        }

    def compute_loss_for_module(
        self, *, module_id, config, batch: dict[str, Any], fwd_out: dict[str, torch.Tensor]
    ) -> torch.Tensor:
        hp = sac_hyper(config)
        action_dim = batch["actions"].shape[-1]
        losses = sac_losses(fwd_out, batch["rewards"], self.curr_log_alpha[module_id], hp, action_dim)
        total = trained_loss(losses, self.updates_done(module_id) < config.critic_warmup_updates)
        # Tensors are logged as-is (window 1) and reduced once per training step.
        self.metrics.log_dict(
            {
                "critic_loss": losses["critic"],
                "actor_loss": losses["actor"],
                "alpha_loss": losses["alpha"],
                "q_mean": losses["q_mean"],
                "entropy": losses["entropy"],
                "alpha": self.curr_log_alpha[module_id].detach().exp(),
            },
            key=module_id,
            window=1,
        )
        return total

    def updates_done(self, module_id) -> int:
        """Gradient updates applied so far: the critic optimiser's step count (restored with the
        checkpoint, so a resumed run keeps counting)."""
        optimizer = self.get_optimizer(module_id, "critic")
        # the most any parameter has had (a population's stopped members are updated no more)
        return max((int(slots["step"]) for slots in optimizer.state.values()), default=0)

    def compute_gradients(self, loss_per_module, **kwargs):
        return gradients_in_one_backward(self, loss_per_module, **kwargs)

    def apply_gradients(self, gradients_dict) -> None:
        super().apply_gradients(gradients_dict)
        for module_id in self.module.keys():
            self.update_targets(
                learner_module(self, module_id), self.config.get_config_for_module(module_id).tau
            )

    @staticmethod
    def update_targets(module, tau: float) -> None:
        polyak(module, tau)

    def after_gradient_based_update(self, *, timesteps: dict[str, Any]) -> None:
        after_update_without_target_sync(self, timesteps)

    # -- checkpoint state as plain tensors (no pickle): nets, log alpha, every Adam slot -----------
    def training_state(self) -> dict[str, torch.Tensor]:
        module_id = DEFAULT_MODULE_ID
        state = self.module_tensors(learner_module(self, module_id))
        state[LOG_ALPHA] = self.curr_log_alpha[module_id].detach().clone()
        for name, optimizer in self.get_optimizers_for_module(module_id):
            for index, slots in optimizer.state_dict()["state"].items():
                for slot, value in slots.items():
                    state[f"{OPTIMIZER_PREFIX}{name}.{index}.{slot}"] = (
                        torch.as_tensor(value).detach().clone()
                    )
        return state

    # the module's own tensors in the learner state: its five nets (a grid learner: its tables)
    module_tensors = staticmethod(nets_state)
    load_module_tensors = staticmethod(load_nets_state)

    def load_training_state(self, state: dict[str, torch.Tensor]) -> None:
        module_id = DEFAULT_MODULE_ID
        self.load_module_tensors(learner_module(self, module_id), state)
        with torch.no_grad():
            self.curr_log_alpha[module_id].copy_(state[LOG_ALPHA])
        for name, optimizer in self.get_optimizers_for_module(module_id):
            prefix = f"{OPTIMIZER_PREFIX}{name}."
            slots: dict[int, dict[str, torch.Tensor]] = defaultdict(dict)
            for key, value in state.items():
                if key.startswith(prefix):
                    index, slot = key[len(prefix) :].rsplit(".", 1)
                    slots[int(index)][slot] = value
            groups = optimizer.state_dict()["param_groups"]  # hyper-parameters come from the config
            optimizer.load_state_dict({"state": dict(slots), "param_groups": groups})
