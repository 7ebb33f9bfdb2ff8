"""Typed, validated specs. Unknown keys and bad values fail with one line naming them."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ps_ray.envs.robots import resolve_robot
from ps_ray.envs.tasks import resolve_task
from ps_ray.nets.modular import METHODS

POINT_TASK = "point"  # the physics-free PointGoalEnv (robot is ignored), for fast checks


class SpecError(ValueError):
    """A spec that cannot run; the message is one line naming the bad key or value."""


@dataclass(frozen=True)
class TrainSpec:
    """One SAC + HER training run of one (robot, task, method, seed)."""

    robot: str | Mapping = "panda"
    task: str | Mapping = "reach"
    method: str = "ps"
    seed: int = 101
    interface_dim: int = 128
    hidden: int = 256
    env_steps: int = 50_000          # training budget
    episodes_per_step: int = 2       # whole episodes collected per training step
    num_envs: int = 2                # vectorised envs in the env runner
    updates_per_step: float = 0.4    # gradient updates per collected env step (authors: 0.4)
    batch_size: int = 256
    lr: float = 1e-3
    gamma: float = 0.98
    tau: float = 0.005
    action_l2: float = 0.0
    random_episodes: int = 10        # warm-up episodes with uniform random actions
    learning_starts: int = 1000      # transitions before the first update
    eval_every: int = 10             # training steps between greedy evaluations
    eval_episodes: int = 10
    checkpoint_every: int = 50       # training steps between checkpoints
    anchors: str | None = None       # file of task states / an anchor set (PS); None: random rollouts
    anchor_episodes: int = 200       # random-policy episodes collected for anchors when anchors=None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise SpecError(f"unknown method {self.method!r}; valid methods: {', '.join(METHODS)}")
        if self.task != POINT_TASK:
            try:
                resolve_robot(self.robot)
                resolve_task(self.task)
            except (ValueError, TypeError) as e:
                raise SpecError(str(e)) from None
        positive = ("interface_dim", "hidden", "env_steps", "episodes_per_step", "num_envs",
                    "batch_size", "eval_episodes", "checkpoint_every", "anchor_episodes")
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise SpecError(f"{name} must be a positive integer, got {value!r}")
        for name in ("updates_per_step", "lr", "tau"):
            if not isinstance(getattr(self, name), (int, float)) or getattr(self, name) <= 0:
                raise SpecError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        if not 0 < self.gamma < 1:
            raise SpecError(f"gamma must be in (0, 1), got {self.gamma!r}")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], where: str = "train spec") -> TrainSpec:
        valid = [f.name for f in dataclasses.fields(cls)]
        for key in data:
            if key not in valid:
                raise SpecError(f"unknown key {key!r} in {where}; valid keys: {', '.join(valid)}")
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @property
    def env_config(self) -> dict[str, Any]:
        if self.task == POINT_TASK:
            return {}
        return {"robot": _plain(self.robot), "task": _plain(self.task)}

    @property
    def env_name(self) -> str:
        return "ps_ray_point" if self.task == POINT_TASK else "ps_ray"

    def digest(self) -> str:
        """Stable hash of the spec: a run directory belongs to exactly one spec."""
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]

    def label(self) -> str:
        name = lambda x: x if isinstance(x, str) else x.get("name", "custom")  # noqa: E731
        return f"{self.method}/{name(self.robot)}/{name(self.task)}/{self.seed}"


def _plain(value: Any) -> Any:
    return dict(value) if isinstance(value, Mapping) else value


__all__ = ["POINT_TASK", "SpecError", "TrainSpec"]
