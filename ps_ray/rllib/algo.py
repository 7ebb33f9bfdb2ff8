"""AlgorithmConfig for one (robot, task, method, seed) TrainSpec, a co-trained grid, or a population."""

from __future__ import annotations

import numpy as np
from ray.rllib.algorithms.algorithm_config import TorchCompileWhatToCompile

from ps_ray.envs.registry import RLLIB_GRID_ENV, register
from ps_ray.rllib.grid_sac import GridSACConfig
from ps_ray.rllib.population_sac import PopulationSACConfig
from ps_ray.rllib.sac_her import TRAIN_SETTINGS, ModularSACConfig
from ps_ray.specs.grid import GridSpec
from ps_ray.specs.population import PopulationSpec
from ps_ray.specs.reset_seeds import run_block
from ps_ray.specs.resources import learner_device
from ps_ray.specs.train import TrainSpec


def algo_config(
    spec: TrainSpec, anchors: np.ndarray | None = None, *, gpu: float = 0, compile: bool = False
) -> ModularSACConfig:
    """``gpu``: the learner's GPU share (RLlib's num_gpus_per_learner); none without CUDA is an
    error. ``compile``: the learner's module forward passes compiled (RLlib's
    ``torch_compile_learner``, forward_train: the losses and backward follow through AOTAutograd)."""
    model_config = {"anchors": None if anchors is None else np.asarray(anchors, np.float32).tolist()}
    return configure(ModularSACConfig(), spec, spec.env_name, spec.env_config, model_config, gpu, compile)


def grid_algo_config(grid: GridSpec, anchors: list[np.ndarray | None]) -> GridSACConfig:
    """The config of a co-trained grid (:mod:`ps_ray.rllib.grid_sac`): ``anchors`` per task."""
    cells = grid.cells
    model_config = {
        "tasks": len(grid.tasks),
        "robots": len(grid.robots),
        "cells": [[grid.tasks.index(t), grid.robots.index(r)] for r, t in cells],
        "anchors": [None if a is None else np.asarray(a, np.float32).tolist() for a in anchors],
    }
    env_config = {"cells": [grid.cell_spec(c).env_config for c in cells]}
    return configure(GridSACConfig(), grid.base, RLLIB_GRID_ENV, env_config, model_config, 0, False)


def population_algo_config(
    population: PopulationSpec, anchors: list[np.ndarray | None], *, gpu: float = 0
) -> PopulationSACConfig:
    """The config of a population (:mod:`ps_ray.rllib.population_sac`): a grid of K tasks and K
    robots whose cells are (i, i); ``anchors`` per member; ``gpu``: the learner's GPU share (its
    members then update as one batched pass). Its own seed (the first member's) draws the
    initial weights, the exploration noise and the warm-up actions."""
    members = population.members
    model_config = {
        "tasks": len(members),
        "robots": len(members),
        "cells": [[i, i] for i in range(len(members))],
        "anchors": [None if a is None else np.asarray(a, np.float32).tolist() for a in anchors],
        "member_seeds": [m.seed for m in members],
    }
    env_config = {
        "cells": [m.env_config for m in members],
        "seed_offsets": [run_block(m.seed).start for m in members],
    }
    return configure(
        PopulationSACConfig(), population.base, RLLIB_GRID_ENV, env_config, model_config, gpu, False
    )


def configure(
    config, spec: TrainSpec, env: str, env_config: dict, model_config: dict, gpu: float, compile: bool
):
    """``config`` set up from ``spec`` for the env ``env`` and the module's ``model_config``."""
    learner_device(gpu)
    register()
    config = (
        config.framework(
            "torch",
            torch_compile_learner=compile,
            torch_compile_learner_what_to_compile=TorchCompileWhatToCompile.FORWARD_TRAIN,
        )
        .environment(env, env_config=env_config)
        .env_runners(num_env_runners=0, num_envs_per_env_runner=spec.num_envs)
        .learners(num_learners=0, num_gpus_per_learner=gpu)
        .rl_module(
            model_config={
                "method": spec.method,
                "interface_dim": spec.interface_dim,
                "hidden": spec.hidden,
                **model_config,
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
            target_entropy="auto" if spec.target_entropy is None else spec.target_entropy,
            **{name: getattr(spec, name) for name in TRAIN_SETTINGS},
        )
        .reporting(metrics_num_episodes_for_smoothing=1)
        .debugging(seed=spec.seed)
    )
    return config
