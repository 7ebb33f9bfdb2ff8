"""RLlib SAC with hindsight replay: a numpy HER buffer and K learner updates per training step.

One `training_step`: the env runner(s) collect whole episodes with the module's exploration
forward pass, the episodes go into `HindsightReplay` in one vectorised write, K = updates_per_step
× new env steps minibatches are drawn in one gather and handed to the learner group in one
`update` call, then weights are synced to the env runners once.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import torch
from ray.rllib.algorithms.sac import SAC, SACConfig
from ray.rllib.core import DEFAULT_MODULE_ID
from ray.rllib.core.rl_module.rl_module import RLModuleSpec
from ray.rllib.policy.sample_batch import MultiAgentBatch, SampleBatch
from ray.rllib.utils.metrics import (
    ENV_RUNNER_SAMPLING_TIMER,
    LEARNER_RESULTS,
    LEARNER_UPDATE_TIMER,
    NUM_ENV_STEPS_SAMPLED_LIFETIME,
    TIMERS,
)
from safetensors.torch import load_file, save_file

from ps_ray.data.her import HindsightReplay, MarkerShift
from ps_ray.envs.goals import ROBOT_KEY, task_input
from ps_ray.errors import UserError
from ps_ray.nets.consolidate import consolidate_cells
from ps_ray.nets.from_signature import load_nets_state, nets_from_state, nets_state
from ps_ray.nets.modular import update_normalizers
from ps_ray.nets.obs import dims_from_spaces
from ps_ray.nets.policy_file import save_policy
from ps_ray.rllib.episodes import episode_stats, episodes_to_arrays, train_batch
from ps_ray.rllib.learner import ModularSACLearner
from ps_ray.rllib.module import ModularSACModule
from ps_ray.rllib.private import (
    NO_METRICS_REDUCE,
    mark_weights_changed,
    set_runner_seed,
    set_training_iteration,
)
from ps_ray.specs.methods import ConsolidateSpec, method_spec, spec_json
from ps_ray.specs.reset_seeds import RUNNER_STRIDE, run_episode_seed
from ps_ray.specs.train import TrainSpec, marker_columns
from ps_ray.store import checkpoint
from ps_ray.store import replay as replay_segments
from ps_ray.store.checkpoint import STATE_FILE
from ps_ray.store.signature import Signature

LEARNER_FILE = "learner.safetensors"
REPLAY_FILE = "replay.npz"
# The process's torch CPU generator (exploration noise, the actor's reparameterised samples on a
# CPU learner), kept in the learner file so that a resumed run draws what the uninterrupted one
# would have drawn. A GPU learner's samples come from the CUDA generator, which is not kept.
TORCH_RNG = "ps_ray.torch_rng_state"


# TrainSpec fields the training step reads; their defaults and docs live in TrainSpec alone.
TRAIN_SETTINGS = (
    "episodes_per_step",
    "updates_per_step",
    "random_episodes",
    "learning_starts",
    "action_l2",
    "critic_warmup_updates",
    "relabel_prob",
    "hindsight",
    "eval_every",
    "eval_episodes",
)


def read_learner_file(directory: Path) -> dict[str, torch.Tensor]:
    """The learner file's tensors as a version-2 checkpoint holds them, with torch's generator
    state: a version-1 checkpoint may have been written before it was kept, and then the
    restored run draws on from this process's own, as it did then."""
    tensors = load_file(directory / LEARNER_FILE)
    if checkpoint.version(directory) == 1:
        tensors.setdefault(TORCH_RNG, torch.get_rng_state())
    return tensors


def hindsight_replay(env, cfg, seed: int | None) -> HindsightReplay:
    """The replay of one env (a gymnasium env's own methods): its spaces, horizon and reward, the
    config's relabelling (``hindsight`` marker: a :class:`MarkerShift` of the env's named marker)."""
    space = env.observation_space
    marker = None
    if cfg.hindsight == "marker":
        columns, sign = marker_columns(env.task_spec)
        marker = MarkerShift("task_state", columns, sign)
    return HindsightReplay(
        {k: (s.shape, np.float32) for k, s in space.spaces.items()},
        action_dim=env.action_space.shape[0],
        horizon=env.max_episode_steps,
        capacity_episodes=cfg.buffer_episodes,
        reward_fn=lambda a, d: env.compute_reward(a, d, None),
        relabel_prob=cfg.relabel_prob,
        seed=seed,
        marker=marker,
    )


class ModularSACConfig(SACConfig):
    """SACConfig plus the HER / update-ratio settings of ps_ray, set through :meth:`training`."""

    def __init__(self, algo_class=None):
        super().__init__(algo_class=algo_class or ModularSAC)
        # One train() call = one training_step (RLlib would otherwise repeat it for a time/steps quota).
        self.min_time_s_per_iteration = None
        self.min_sample_timesteps_per_iteration = 0
        self.min_train_timesteps_per_iteration = 0
        defaults = {f.name: f.default for f in dataclasses.fields(TrainSpec)}
        for name in TRAIN_SETTINGS:
            setattr(self, name, defaults[name])
        self.buffer_episodes = 20_000  # replay capacity in whole episodes
        self.clip_targets = True  # critic targets clipped to the returns a -1/0 reward allows
        # Replay is HindsightReplay's: SAC's default prioritized buffer would be built and never
        # read (0.6 s and ~140 MB per trial; docs/reference.md, "Speed").
        self.replay_buffer_config = {"type": "EpisodeReplayBuffer", "no_local_replay_buffer": True}

    def training(self, **kwargs) -> ModularSACConfig:
        """``SACConfig.training`` that also takes :data:`TRAIN_SETTINGS`, ``buffer_episodes``,
        and ``clip_targets``."""
        for name in (*TRAIN_SETTINGS, "buffer_episodes", "clip_targets"):
            if name in kwargs:
                setattr(self, name, kwargs.pop(name))
        return super().training(**kwargs)

    def get_default_learner_class(self):
        return ModularSACLearner

    def get_default_rl_module_spec(self):
        return RLModuleSpec(module_class=ModularSACModule)


class ModularSAC(SAC):
    @classmethod
    def get_default_config(cls) -> ModularSACConfig:
        return ModularSACConfig()

    def setup(self, config) -> None:
        super().setup(config)
        cfg = self.config
        # A driver-side env instance supplies spaces, horizon and compute_reward for relabelling.
        self._reward_env = self.env_creator(cfg.env_config).unwrapped  # a gymnasium env's own methods
        space = self._reward_env.observation_space
        self.replay = hindsight_replay(self._reward_env, cfg, cfg.seed)
        self.method = method_spec(cfg.model_config["method"])
        self.counters = {"env_steps": 0, "episodes": 0, "updates": 0}
        # Where replay segments go (ps_ray.store.replay); None: each checkpoint holds the whole buffer.
        self.replay_store: Path | None = None
        self._replay_manifest: dict | None = None  # the segments of the last checkpoint saved or loaded
        dims = dims_from_spaces(space, self._reward_env.action_space)
        self.replay_dims = {
            "task_dim": dims.task_dim,
            "robot_dim": dims.robot_dim,
            "action_dim": dims.action_dim,
        }

    def learner_state(self) -> dict[str, torch.Tensor]:
        """The full module's tensors (actor, critics, targets) from the (first) learner."""
        return (
            self.learner_group.foreach_learner(lambda learner: nets_state(learner.module[DEFAULT_MODULE_ID]))
            .result_or_errors[0]
            .get()
        )

    def load_policy_weights(self, path) -> None:
        """Start from a policy file (e.g. a stitched one): actor, critics and targets, strictly."""
        from ps_ray.nets.policy_file import load_policy

        nets, signature = load_policy(path)
        if signature.translation:
            raise UserError(
                f"{path}: a stitch aligned at stitch time ({signature.translation}: a fitted "
                f"latent map or re-anchored task modules) is for zero-shot use; fine-tune an "
                f"unaligned stitch instead"
            )
        ours = {k: self.replay_dims[k] for k in ("task_dim", "robot_dim", "action_dim")}
        theirs = {k: getattr(signature, k) for k in ours}
        if ours != theirs:
            raise UserError(f"{path}: policy dims {theirs} do not fit this env {ours}")
        state = nets_state(nets)

        self.learner_group.foreach_learner(
            lambda learner: load_nets_state(learner.module[DEFAULT_MODULE_ID], state)
        )
        self.env_runner_group.sync_weights(
            from_worker_or_learner_group=self.learner_group, inference_only=True
        )

    def consolidate_actor(self, spec: ConsolidateSpec) -> dict[str, float]:
        """The method's consolidation (:mod:`ps_ray.nets.consolidate`) of the learner's actors
        (one; a grid's cells together), each on HER replay states of its own replay (goals
        relabelled as in training); the env runners get the result."""
        batches = [
            train_batch(r.sample_many(spec.updates, spec.batch_size)) for r in self.consolidation_replays()
        ]
        task_ins, robot_ins = [b["task_in"] for b in batches], [b["robot_in"] for b in batches]
        actors_of = self.module_actors

        def on_learner(learner):
            actors = actors_of(learner.module[DEFAULT_MODULE_ID])
            stats = consolidate_cells(actors, task_ins, robot_ins, spec)
            mark_weights_changed(learner)
            return stats

        stats = self.learner_group.foreach_learner(on_learner).result_or_errors[0].get()
        self.env_runner_group.sync_weights(
            from_worker_or_learner_group=self.learner_group, inference_only=True
        )
        return stats

    def consolidation_replays(self) -> list[HindsightReplay]:
        """The replays consolidation reads, one per actor of :meth:`module_actors`."""
        return [self.replay]

    @staticmethod
    def module_actors(module) -> list:
        """The actors a consolidation moves, in the order of :meth:`consolidation_replays`."""
        return [module.actor]

    def export_policy(self, path, signature, extra: dict[str, str] | None = None) -> Signature:
        """Write the learner's nets as a policy file; returns its signature, which records whether
        a deferred relative projection is still off (``Signature.projection_off``)."""
        nets = nets_from_state(self.learner_state(), signature)
        signature = dataclasses.replace(
            signature, projection_off=nets.actor.task.projection_off, settings=spec_json(nets.actor.spec)
        )
        save_policy(path, nets, signature, extra)
        return signature

    def evaluate_greedy(self, episodes: int, *, final: bool = False) -> dict[str, float]:
        """Greedy success on the periodic evaluations' episodes, or with ``final`` on episodes of
        their own, which the stopping rule (it reads the periodic ones) never saw."""
        return episode_stats(self.collect_episodes(explore=False, random=False, n=episodes, final=final))

    @property
    def run_seed(self) -> int | None:
        """The seed whose reset-seed block the run draws its episodes' scenes from
        (ps_ray.specs.reset_seeds); its warm-up random actions always come from its own seed's."""
        return self.config.seed

    def collect_episodes(self, *, explore: bool, random: bool, n: int, final: bool = False) -> list:
        """n whole episodes per env runner. Training episodes get fresh reset seeds (derived from
        the run's seed and episode count, so a resumed run does not replay old goals); greedy
        evaluations reuse one fixed seed, so every evaluation sees the same episodes; the final
        evaluation (``final``) another fixed seed, so its episodes are none of those."""
        seed = run_episode_seed(self.run_seed, self.counters["episodes"], explore=explore, final=final)
        actions = run_episode_seed(self.config.seed, self.counters["episodes"], explore=explore, final=final)

        def sample(runner):
            # RLlib re-seeds the envs with its config seed on every num_episodes call, which
            # would replay the same goals forever: set the seed of this call instead.
            offset = RUNNER_STRIDE * runner.worker_index
            set_runner_seed(runner, seed + offset, actions + offset)
            return runner.sample(num_episodes=n, explore=explore, random_actions=random)

        results = self.env_runner_group.foreach_env_runner(
            sample, local_env_runner=self.env_runner_group.num_remote_env_runners() == 0
        )
        return [ep for eps in results for ep in eps]

    def training_step(self) -> None:
        cfg = self.config
        steps = self.gather()
        if self.ready_to_learn():
            n_updates = max(1, round(steps * cfg.updates_per_step))
            self.learn(self.sample_batch(n_updates), n_updates)
        # Normaliser statistics change every step, so env runners are synced even before learning.
        self.env_runner_group.sync_weights(
            from_worker_or_learner_group=self.learner_group, inference_only=True
        )
        if cfg.eval_every and self.iteration % cfg.eval_every == 0:
            self.log_evaluation()
        for key, value in self.counters.items():
            self.metrics.log_value(("ps_ray", key), value, reduce="item")

    def gather(self) -> int:
        """Collect the step's episodes into replay and the normalisers; returns the env steps."""
        cfg = self.config
        with self.metrics.log_time((TIMERS, ENV_RUNNER_SAMPLING_TIMER)):
            episodes = self.collect_episodes(
                explore=True, n=cfg.episodes_per_step, random=self.counters["episodes"] < cfg.random_episodes
            )
        obs, actions = episodes_to_arrays(episodes)
        self.replay.add_episodes(obs, actions)
        steps = actions.shape[0] * actions.shape[1]
        self.counters["env_steps"] += steps
        self.counters["episodes"] += actions.shape[0]
        self._log_episode_stats("train", episodes)
        self.see(self.replay, obs, lambda module: module)
        return steps

    def see(self, replay: HindsightReplay, obs: dict[str, np.ndarray], nets) -> None:
        """The normalisers of ``nets(learner module)`` see new steps as training reads them:
        hindsight goals included (unless the method asks for the collected steps only:
        MethodSpec.hindsight_norm)."""
        steps_seen = replay.relabelled(obs) if self.method.hindsight_norm else obs
        task_t = torch.from_numpy(task_input(steps_seen))
        robot_t = torch.from_numpy(steps_seen[ROBOT_KEY])
        self.learner_group.foreach_learner(
            lambda learner: update_normalizers(nets(learner.module[DEFAULT_MODULE_ID]), task_t, robot_t)
        )

    def ready_to_learn(self) -> bool:
        return self.replay.num_transitions >= self.config.learning_starts

    def sample_batch(self, n_updates: int) -> dict[str, torch.Tensor]:
        return train_batch(self.replay.sample_many(n_updates, self.config.train_batch_size))

    def log_evaluation(self) -> None:
        self._log_episode_stats(
            "eval", self.collect_episodes(explore=False, random=False, n=self.config.eval_episodes)
        )

    def learn(self, batch: dict[str, torch.Tensor], n_updates: int) -> None:
        """n_updates minibatch updates of the learner, in one ``update`` call, on ``batch``."""
        cfg = self.config
        with self.metrics.log_time((TIMERS, LEARNER_UPDATE_TIMER)):
            self.learner_group.update(
                batch=MultiAgentBatch(
                    {DEFAULT_MODULE_ID: SampleBatch(batch)}, env_steps=n_updates * cfg.train_batch_size
                ),
                timesteps={NUM_ENV_STEPS_SAMPLED_LIFETIME: self.counters["env_steps"]},
                num_epochs=1,
                minibatch_size=cfg.train_batch_size,
                **NO_METRICS_REDUCE,
            )
        self.counters["updates"] += n_updates
        reduced = self.learner_group.foreach_learner(lambda learner: learner.metrics.reduce())
        self.metrics.aggregate([r.get() for r in reduced], key=LEARNER_RESULTS)

    def _log_episode_stats(self, prefix: str, episodes: list) -> None:
        for key, value in episode_stats(episodes).items():
            self.metrics.log_value(("ps_ray", f"{prefix}_{key}"), value, reduce="item")

    # -- checkpoints: ps_ray's own files, never RLlib's pickles (ps_ray/store/checkpoint.py) -------------
    def save_checkpoint(self, checkpoint_dir: str) -> None:
        directory = Path(checkpoint_dir)
        directory.mkdir(parents=True, exist_ok=True)
        tensors = self.learner_group.foreach_learner(lambda learner: learner.training_state())
        tensors = {**tensors.result_or_errors[0].get(), TORCH_RNG: torch.get_rng_state()}
        save_file(tensors, directory / LEARNER_FILE)
        self.save_replay(directory)
        state = {"counters": self.counters, "iteration": self.iteration}
        (directory / STATE_FILE).write_text(json.dumps(state))

    def save_replay(self, directory: Path) -> None:
        if self.replay_store is None:
            self.replay.save(directory / REPLAY_FILE)
        else:  # only the segments the last checkpoint does not hold yet; then what neither names goes
            manifest = replay_segments.write(self.replay, self.replay_store, self._replay_manifest)
            replay_segments.save_manifest(manifest, directory)
            replay_segments.prune(self.replay_store, self._replay_manifest, manifest)
            self._replay_manifest = manifest

    def load_checkpoint(self, checkpoint_dir: str) -> None:
        """Restore from a checkpoint folder that :func:`ps_ray.store.checkpoint.verify` accepted."""
        directory = Path(checkpoint_dir)
        tensors = read_learner_file(directory)
        rng = tensors.pop(TORCH_RNG)
        self.learner_group.foreach_learner(lambda learner: learner.load_training_state(tensors))
        self.env_runner_group.sync_weights(
            from_worker_or_learner_group=self.learner_group, inference_only=True
        )
        self.load_replay(directory)
        state = json.loads((directory / STATE_FILE).read_text())
        self.counters = {k: int(state["counters"][k]) for k in self.counters}
        set_training_iteration(self, int(state["iteration"]))
        torch.set_rng_state(rng)  # last: nothing of the restore may draw after it

    def load_replay(self, directory: Path) -> None:
        if (directory / replay_segments.MANIFEST_FILE).is_file():
            if self.replay_store is None:
                raise UserError(f"{directory}: its replay buffer is in segment files; give their store")
            self._replay_manifest = replay_segments.load(self.replay, directory, self.replay_store)
        else:  # a checkpoint that holds the whole buffer (no store, or an earlier ps_ray)
            self.replay.load(directory / REPLAY_FILE)
