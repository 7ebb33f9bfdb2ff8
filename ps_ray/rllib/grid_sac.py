"""GridSAC: ModularSAC over a co-trained grid (docs/transfer.md "Co-trained grids").

Each training step collects ``episodes_per_step`` episodes of every trained cell at once (one
:class:`ps_ray.envs.grid.GridEnv` episode), writes each cell's into its own hindsight replay and
its own task and robot modules' normalisers, then makes K = updates_per_step x the step's env steps
per cell updates, each on one minibatch of every cell (:mod:`ps_ray.rllib.grid_module`). Held-out
cells have no env, no replay and no view: nothing can sample them. Budgets and counters are per
cell (``env_steps`` counts one cell's steps, as a single source's would); the grid's greedy
success is its worst cell's, so the stopping rule waits for every cell.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch
from ray.rllib.algorithms.sac import SAC
from ray.rllib.core import DEFAULT_MODULE_ID
from ray.rllib.core.rl_module.rl_module import RLModuleSpec
from ray.rllib.utils.metrics import ENV_RUNNER_SAMPLING_TIMER, TIMERS
from torch import nn

from ps_ray.data.her import HindsightReplay
from ps_ray.errors import UserError
from ps_ray.nets.policy_file import save_policy
from ps_ray.rllib.grid_module import GridSACLearner, GridSACModule, grid_modules, grid_train_batch
from ps_ray.rllib.private import runner_envs
from ps_ray.rllib.sac_her import ModularSAC, ModularSACConfig, hindsight_replay
from ps_ray.specs.methods import method_spec
from ps_ray.store.signature import Signature


class GridSACConfig(ModularSACConfig):
    def __init__(self, algo_class=None):
        super().__init__(algo_class=algo_class or GridSAC)

    def get_default_learner_class(self):
        return GridSACLearner

    def get_default_rl_module_spec(self):
        return RLModuleSpec(module_class=GridSACModule)


def grid_arrays(episodes: list, keys: list[str], cuts: list[int]) -> dict[str, tuple[dict, np.ndarray]]:
    """Grid episodes -> per cell key: obs[k] (N, T+1, ...) and actions (N, T, A)."""
    observations = [ep.get_observations() for ep in episodes]
    actions = np.split(np.stack([ep.get_actions() for ep in episodes]).astype(np.float32), cuts, axis=-1)
    return {
        key: (
            {k: np.stack([o[key][k] for o in observations]).astype(np.float32) for k in observations[0][key]},
            np.ascontiguousarray(actions[i]),
        )
        for i, key in enumerate(keys)
    }


def cell_stats(episodes: list, key: str) -> dict[str, float]:
    """One cell's success at the last step and touching rate (as :func:`episode_stats`)."""
    infos = [[step[key] for step in ep.get_infos()] for ep in episodes]
    eligible = [i for i in infos if not i[0]["initially_successful"]]
    touching = np.mean([any(x["touching"] for x in i) for i in eligible]) if eligible else np.nan
    return {"success": float(np.mean([i[-1]["is_success"] for i in infos])), "touching": float(touching)}


class GridSAC(ModularSAC):
    _stopped: frozenset[str] = frozenset()

    @property
    def stopped(self) -> frozenset[str]:
        """Cells that left (a population's stopped members): their envs are stepped no more
        (:meth:`ps_ray.envs.grid.GridEnv.freeze`; the last to stop is left live, as the run ends
        with it), nothing of theirs goes to a replay or normaliser, and their minibatches leave the
        updates (no gradient, so Adam leaves their parameters be)."""
        return self._stopped

    @stopped.setter
    def stopped(self, keys: frozenset[str]) -> None:
        self._stopped = frozenset(keys)
        frozen = [self.keys.index(k) for k in self._stopped]
        if frozen and len(frozen) < len(self.keys):
            self.env_runner_group.foreach_env_runner(
                lambda runner: [env.freeze(frozen) for env in runner_envs(runner)],
                local_env_runner=self.env_runner_group.num_remote_env_runners() == 0,
            )

    @classmethod
    def get_default_config(cls) -> GridSACConfig:
        return GridSACConfig()

    def setup(self, config) -> None:
        SAC.setup(self, config)  # not ModularSAC's: a grid has a replay per cell, not one
        cfg = self.config
        self._grid_env = self.env_creator(cfg.env_config)  # each cell's spaces and compute_reward
        self.keys = list(self._grid_env.keys)
        self.cuts = list(np.cumsum(self._grid_env.action_dims)[:-1])
        self.replays = {
            key: hindsight_replay(env.unwrapped, cfg, seed)
            for key, env, seed in zip(self.keys, self._grid_env.envs, self.replay_seeds())
        }
        self.method = method_spec(cfg.model_config["method"])
        self.counters = {"env_steps": 0, "episodes": 0, "updates": 0}  # per cell, but updates
        self.replay_store = None  # a grid checkpoint holds its buffers whole

    def replay_seeds(self) -> list[int | None]:
        """Each cell's replay seed: a grid's from its own seed."""
        seed = self.config.seed
        return [None if seed is None else seed * 1_000 + i for i in range(len(self.keys))]

    def gather(self) -> int:
        cfg = self.config
        with self.metrics.log_time((TIMERS, ENV_RUNNER_SAMPLING_TIMER)):
            episodes = self.collect_episodes(
                explore=True, n=cfg.episodes_per_step, random=self.counters["episodes"] < cfg.random_episodes
            )
        for index, (key, (obs, actions)) in enumerate(grid_arrays(episodes, self.keys, self.cuts).items()):
            if key in self.stopped:
                continue
            self.replays[key].add_episodes(obs, actions)
            self.see(self.replays[key], obs, lambda module, i=index: module.cells[i])
        self._log_cell_stats("train", episodes)
        self.counters["env_steps"] += len(episodes) * self._grid_env.max_episode_steps
        self.counters["episodes"] += len(episodes)
        return len(episodes) * self._grid_env.max_episode_steps

    def ready_to_learn(self) -> bool:
        return min(r.num_transitions for r in self.replays.values()) >= self.config.learning_starts

    def sample_batch(self, n_updates: int) -> dict[str, torch.Tensor]:
        size = self.config.train_batch_size
        live = {k: r for k, r in self.replays.items() if k not in self.stopped}
        return grid_train_batch({k: r.sample_many(n_updates, size) for k, r in live.items()})

    def log_evaluation(self) -> None:
        self._log_cell_stats(
            "eval", self.collect_episodes(explore=False, random=False, n=self.config.eval_episodes)
        )

    def evaluate_greedy(self, episodes: int, *, final: bool = False) -> dict[str, float]:
        """Each cell's greedy success and touching (``<cell key>_success``), and the worst live
        cell's (a stopped member's figures are those it stopped with, kept by its run)."""
        runs = self.collect_episodes(explore=False, random=False, n=episodes, final=final)
        return self._cell_figures(runs)

    def _cell_figures(self, episodes: list) -> dict[str, float]:
        figures: dict[str, float] = {}
        for key in self.keys:
            figures.update({f"{key}_{k}": v for k, v in cell_stats(episodes, key).items()})
        live = [key for key in self.keys if key not in self.stopped] or self.keys  # frozen: stale
        figures["success"] = min(figures[f"{key}_success"] for key in live)
        touching = [figures[f"{key}_touching"] for key in live]
        figures["touching"] = float("nan") if np.isnan(touching).all() else float(np.nanmin(touching))
        return figures

    def _log_cell_stats(self, prefix: str, episodes: list) -> None:
        for key, value in self._cell_figures(episodes).items():
            self.metrics.log_value(("ps_ray", f"{prefix}_{key}"), value, reduce="item")

    def consolidation_replays(self) -> list[HindsightReplay]:
        """Each trained cell's replay: a grid's cells are consolidated together
        (:func:`ps_ray.nets.consolidate.consolidate_cells`)."""
        return list(self.replays.values())

    @staticmethod
    def module_actors(module) -> list:
        return [cell.actor for cell in module.cells]

    # -- what a grid does not do (yet) ----------------------------------------------------------
    def load_policy_weights(self, path) -> None:
        raise UserError(f"{path}: a grid starts from fresh modules; fine-tune one exported cell instead")

    # -- export: each trained cell as an ordinary policy file ----------------------------------
    def cell_nets(self) -> list[nn.Module]:
        """The grid's modules as of the learner, rebuilt on the driver: one view per trained cell."""
        cfg = self.config.model_config
        owner = nn.Module()
        learner = self.learner_group.foreach_learner(
            lambda learner: GridSACLearner.module_tensors(learner.module[DEFAULT_MODULE_ID])
        )
        state = learner.result_or_errors[0].get()
        module_dims = self.learner_group.foreach_learner(
            lambda learner: learner.module[DEFAULT_MODULE_ID].dims
        )
        with torch.random.fork_rng(devices=[]):  # throw-away initial weights: not from the run's stream
            views = grid_modules(owner, cfg, module_dims.result_or_errors[0].get())
        GridSACLearner.load_module_tensors(owner, state)
        return views

    def export_cells(self, paths: list[Path], signatures: list[Signature]) -> None:
        """Write each trained cell's policy file (paths and signatures in cell order)."""
        for view, path, signature in zip(self.cell_nets(), paths, signatures):
            task = view.actor.task  # a consolidated grid's projection is on (Signature.projection_off)
            save_policy(path, view, dataclasses.replace(signature, projection_off=task.projection_off))

    # -- checkpoints: ModularSAC's, with one whole replay file per cell ------------------------
    def save_replay(self, directory: Path) -> None:
        for key, replay in self.replays.items():
            replay.save(directory / f"replay_{key}.npz")

    def load_replay(self, directory: Path) -> None:
        for key, replay in self.replays.items():
            replay.load(directory / f"replay_{key}.npz")
