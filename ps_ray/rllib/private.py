"""Every use of RLlib internals, in one place. Each was checked against Ray ``RAY_CHECKED``; a Ray
upgrade that changes one breaks it here, and `tests/test_rllib.py` exercises them all."""

from __future__ import annotations

from typing import Any

from ray.rllib.core.learner.learner import Learner
from ray.rllib.core.learner.torch.torch_learner import TorchLearner

RAY_CHECKED = "2.60.0"

# LearnerGroup.update(..., _no_metrics_reduce=True): leave the learner's metrics unreduced, so the
# K minibatch updates of one training step are reduced once, not K times.
NO_METRICS_REDUCE: dict[str, Any] = {"_no_metrics_reduce": True}


def set_runner_seed(runner, seed: int, action_seed: int | None = None) -> None:
    """SingleAgentEnvRunner re-seeds its envs from the private ``_seed`` on every
    ``sample(num_episodes=...)`` call; without this each call would replay the same goals.
    Its ``random_actions`` come from ``env.action_space.sample()``, which nothing seeds (gymnasium
    draws OS entropy): seeding it here (from ``action_seed``, default ``seed``) makes the warm-up
    episodes, and so a run, repeatable."""
    runner._seed = seed
    runner.env.action_space.seed(seed if action_seed is None else action_seed)


def runner_envs(runner) -> list:
    """The env runner's own envs, unwrapped (SingleAgentEnvRunner holds a gymnasium vector env,
    wrapped: ``DictInfoToList`` over a ``SyncVectorEnv`` of ``OrderEnforcing`` envs)."""
    return [env.unwrapped for env in runner.env.unwrapped.envs]


def mark_weights_changed(learner: Learner) -> None:
    """A change to the learner's weights outside ``Learner.update`` (consolidation): an env runner
    loads synced weights only when their ``_weights_seq_no`` is newer than its own (or 0), and only
    ``update`` advances it, so without this the next sync would be skipped."""
    learner._weights_seq_no += 1


def set_training_iteration(algo, iteration: int) -> None:
    """Trainable's iteration counter, restored from ps_ray's own checkpoint state."""
    algo._iteration = iteration


def learner_module(learner: Learner, module_id: str):
    """The learner's own (non-inference) copy of an RLModule."""
    return learner._module[module_id]


def gradients_in_one_backward(learner: TorchLearner, loss_per_module, **kwargs):
    """TorchLearner's gradient step, skipping SACTorchLearner's one backward per optimizer: the
    SAC loss terms are detached from each other's parameters, so one backward serves all."""
    return TorchLearner.compute_gradients(learner, loss_per_module, **kwargs)


def after_update_without_target_sync(learner: Learner, timesteps: dict[str, Any]) -> None:
    """Learner's bookkeeping after an update, skipping DQN's once-per-call target-network sync
    (ps_ray updates the targets by Polyak after every minibatch)."""
    Learner.after_gradient_based_update(learner, timesteps=timesteps)
