"""The chance-level control: what a policy with no task knowledge scores on a pair's episodes.

A stitched pair's unstitched sources can fail at zero by construction (the robot source reaches the
wrong marker every time), so a stitched policy above them is not yet a policy that knows the task.
Chance is the level any purposeful mover of the target robot reaches without knowing what the task
means (docs/transfer.md, "Chance"). Two such policies are scored on the pair's own evaluation
episodes, and the higher is the control:

- ``random_point``: each episode, drive the end effector (inverse kinematics on the target robot)
  to one point drawn uniformly from the task's target region (``env.target_region()``: the box
  every target is drawn from; on the marker family the marker box, which reaches the named marker
  about 8% of the time);
- ``random_actions``: uniform random actions.

Both draw from the episode's seed alone, so they are deterministic and every pair with the same
target env and episodes gets the same figure. No torch, no Ray.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

_STREAM = 0x5EED_C4A7  # keeps these draws apart from the env's own use of the episode seed


class RandomPoint:
    """Each episode: one target point ~ U(target region); every step moves toward it."""

    def begin(self, envs: Sequence, seeds: Sequence[int]) -> None:
        """Called by :func:`ps_ray.stitching.evaluate.evaluate` once the batch's envs are reset."""
        self.envs = list(envs)
        self.points = []
        for env, seed in zip(envs, seeds):
            low, high = env.target_region()
            self.points.append(np.random.default_rng([_STREAM, seed]).uniform(low, high))

    def __call__(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        return np.stack([env.action_toward(point) for env, point in zip(self.envs, self.points)])


class RandomActions:
    """Uniform random actions in [-1, 1], drawn from the episode's seed."""

    def begin(self, envs: Sequence, seeds: Sequence[int]) -> None:
        self.rngs = [np.random.default_rng([_STREAM, 1, seed]) for seed in seeds]
        self.dim = envs[0].action_space.shape[0]

    def __call__(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        return np.stack([rng.uniform(-1.0, 1.0, self.dim) for rng in self.rngs])


POLICIES: dict[str, Callable[[], Any]] = {"random_point": RandomPoint, "random_actions": RandomActions}
CHANCE_POLICIES = tuple(POLICIES)


def chance(robot, task, settings: Mapping[str, Any]) -> dict[str, Any]:
    """Each chance policy's success on the episodes ``settings`` (``evaluate``'s episodes, repeats,
    seed) name, ``chance_success`` (the higher), ``chance_policy`` (which) and the episodes'
    digest (:func:`ps_ray.stitching.evaluate.episodes_digest`), to check a pair ran on the same ones."""
    from ps_ray.stitching.evaluate import evaluate

    out: dict[str, Any] = {}
    for name in CHANCE_POLICIES:
        result = evaluate(POLICIES[name](), robot, task, **settings)
        out[f"{name}_success"] = result["success_mean"]
        out["episodes_digest"] = result["episodes_digest"]
    best = max(CHANCE_POLICIES, key=lambda name: out[f"{name}_success"])
    return {**out, "chance_success": out[f"{best}_success"], "chance_policy": best}
