"""AlgorithmConfig for one (robot, task, method, seed) TrainSpec."""

from __future__ import annotations

import numpy as np
from ray.rllib.algorithms.algorithm_config import TorchCompileWhatToCompile

from ps_ray.envs.registry import register
from ps_ray.rllib.sac_her import TRAIN_SETTINGS, ModularSACConfig
from ps_ray.specs.resources import learner_device
from ps_ray.specs.train import TrainSpec


def algo_config(
    spec: TrainSpec, anchors: np.ndarray | None = None, *, gpu: float = 0, compile: bool = False
) -> ModularSACConfig:
    """``gpu``: the learner's GPU share (RLlib's num_gpus_per_learner); none without CUDA is an
    error. ``compile``: the learner's module forward passes compiled (RLlib's
    ``torch_compile_learner``, forward_train: the losses and backward follow through AOTAutograd)."""
    learner_device(gpu)
    register()
    config = (
        ModularSACConfig()
        .framework(
            "torch",
            torch_compile_learner=compile,
            torch_compile_learner_what_to_compile=TorchCompileWhatToCompile.FORWARD_TRAIN,
        )
        .environment(spec.env_name, env_config=spec.env_config)
        .env_runners(num_env_runners=0, num_envs_per_env_runner=spec.num_envs)
        .learners(num_learners=0, num_gpus_per_learner=gpu)
        .rl_module(
            model_config={
                "method": spec.method,
                "interface_dim": spec.interface_dim,
                "hidden": spec.hidden,
                "anchors": None if anchors is None else np.asarray(anchors, np.float32).tolist(),
            }
        )
        .training(
            train_batch_size=spec.batch_size,
            gamma=spec.gamma,
            tau=spec.tau,
            actor_lr=spec.lr,
            critic_lr=spec.lr,
            alpha_lr=spec.lr,
            initial_alpha=spec.initial_alpha,
            **{name: getattr(spec, name) for name in TRAIN_SETTINGS},
        )
        .reporting(metrics_num_episodes_for_smoothing=1)
        .debugging(seed=spec.seed)
    )
    return config
