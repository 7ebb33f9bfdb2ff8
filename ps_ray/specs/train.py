"""The training spec and the helpers every spec shares. Unknown keys and bad values fail with one
line naming them. The sweep spec is in ``ps_ray.specs.sweep``."""

from __future__ import annotations

import dataclasses
import functools
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ps_ray.envs.robots import resolve_robot
from ps_ray.envs.tasks import resolve_task
from ps_ray.errors import UserError, describe, fits, type_hints
from ps_ray.specs.defaults import HIDDEN, INTERFACE_DIM, MAX_WIDTH
from ps_ray.specs.methods import OPTIONS, PRESETS, MethodSpec, method_key, method_spec
from ps_ray.specs.names import EnvPart, plain_json, trial_key
from ps_ray.specs.reset_seeds import MAX_RUN_SEED

POINT_TASK = "point"  # the physics-free PointGoalEnv (robot is ignored), for fast checks


RESUMABLE_CHANGES = (
    "env_steps",
    "eval_every",
    "eval_episodes",
    "checkpoint_every",
    "target_success",
    "target_evals",
)


# Settings added after runs were recorded: written only where they differ from these defaults.
LATER_SETTINGS = {"target_entropy": None, "relabel_prob": 0.8}


class SpecError(UserError):
    """A spec that cannot run; the message is one line naming the bad key or value."""


def check_keys(data: Mapping[str, Any], cls: type, where: str) -> None:
    """The one unknown-key check: the first key that is not a field of ``cls`` fails, naming the
    valid keys."""
    valid = [f.name for f in dataclasses.fields(cls)]
    bad = [key for key in data if key not in valid]
    if bad:
        raise SpecError(f"{where}: unknown key {bad[0]!r}; valid keys: {', '.join(valid)}")


def check_types(spec: Any, where: str, skip: tuple[str, ...] = ()) -> None:
    """Every field of a spec dataclass against its annotation (``int``, ``float``, ``str``,
    ``bool``, ``None``, unions, ``tuple[T, ...]``, mappings): the first mismatch fails in one line."""
    hints = type_hints(type(spec))
    for field in dataclasses.fields(spec):
        value = getattr(spec, field.name)
        if field.name not in skip and not fits(value, hints[field.name]):
            raise SpecError(f"{where}.{field.name} must be {describe(hints[field.name])}, got {value!r}")


def require_same(stored: Mapping[str, Any], current: Mapping[str, Any], what: str, advice: str) -> None:
    """The one "same spec or refuse" check of a folder that already holds work: ``what`` names
    the folder's content, ``advice`` what to do instead."""
    changed = sorted(k for k in {*stored, *current} if stored.get(k) != current.get(k))
    if changed:
        raise SpecError(f"{what} (changed: {', '.join(changed)}); {advice}")


def setting(default: Any, help: str) -> Any:
    """A spec field with its documentation, read by the code and by ``ps-ray train --help``."""
    return dataclasses.field(default=default, metadata={"help": help})


@dataclass(frozen=True)
class TrainSpec:
    """One SAC + HER training run of one (robot, task, method, seed). Every field is a flag of
    ``ps-ray train`` and a key of a sweep's ``train:`` block; its help text is its doc."""

    robot: EnvPart = setting(EnvPart("panda"), "built-in robot name or a JSON mapping")
    task: EnvPart = setting(EnvPart("reach"), "built-in task name or a JSON mapping")
    method: str = setting(
        "ps",
        "a preset (" + ", ".join(PRESETS) + ") with +option=value overrides, e.g. ps+norm=layer; "
        "options: " + ", ".join(OPTIONS) + " (docs/methods.md)",
    )
    seed: int = setting(101, "seed of networks, env runner and replay sampling")
    interface_dim: int = setting(INTERFACE_DIM, "width of the task-robot interface (PS: number of anchors)")
    hidden: int = setting(HIDDEN, "hidden units per layer of every MLP")
    env_steps: int = setting(50_000, "training budget in env steps (a cap when target_success is set)")
    target_success: float | None = setting(None, "stop early at this greedy success (None: never)")
    target_evals: int = setting(2, "evaluations in a row at target_success that stop the run")
    episodes_per_step: int = setting(2, "whole episodes collected per training step")
    num_envs: int = setting(2, "vectorised envs in the env runner")
    updates_per_step: float = setting(0.4, "gradient updates per collected env step (authors: 0.4)")
    batch_size: int = setting(256, "transitions per gradient update")
    lr: float = setting(1e-3, "Adam learning rate of actor, critics and temperature")
    initial_alpha: float = setting(0.1, "entropy temperature at the start (auto-tuned after)")
    gamma: float = setting(0.98, "discount")
    tau: float = setting(0.005, "Polyak rate of the target critics")
    action_l2: float = setting(0.0, "weight of an L2 penalty on the actor's mean action")
    critic_warmup_updates: int = setting(
        0,
        "first gradient updates in which only the critics learn (actor and temperature frozen), so a "
        "stitched start's critics fit its actor before the actor follows them (few-shot)",
    )
    target_entropy: float | None = setting(
        None, "the policy entropy the temperature is tuned towards (None: minus the action dimension)"
    )
    relabel_prob: float = setting(0.8, "share of replayed transitions with a relabelled goal (HER k=4: 0.8)")
    random_episodes: int = setting(10, "warm-up episodes with uniform random actions")
    learning_starts: int = setting(1000, "transitions in the buffer before the first update")
    eval_every: int = setting(10, "training steps between greedy evaluations (0: never)")
    eval_episodes: int = setting(10, "episodes per greedy evaluation (the final one runs twice as many)")
    checkpoint_every: int = setting(50, "training steps between sealed checkpoints")
    anchors: str | None = setting(None, "PS: file of task states or an anchor set (None: random rollouts)")
    anchor_episodes: int = setting(200, "random-policy episodes collected for anchors when anchors is None")
    init_policy: str | None = setting(None, "start from these weights (a stitched policy: few-shot)")

    def __post_init__(self) -> None:
        for name in ("robot", "task"):  # a name or a mapping, as written, becomes one type
            if not isinstance(getattr(self, name), (str, Mapping)):
                raise SpecError(f"{name} must be a name or a mapping, got {getattr(self, name)!r}")
            object.__setattr__(self, name, EnvPart(getattr(self, name)))
        try:
            object.__setattr__(self, "method", method_key(self.method))
        except UserError as e:
            raise SpecError(str(e)) from None
        if self.task != POINT_TASK:
            try:
                resolve_robot(self.robot)
                resolve_task(self.task)
            except (ValueError, TypeError) as e:
                raise SpecError(str(e)) from None
        positive = (
            "interface_dim",
            "hidden",
            "env_steps",
            "episodes_per_step",
            "num_envs",
            "batch_size",
            "eval_episodes",
            "checkpoint_every",
            "anchor_episodes",
            "target_evals",
        )
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise SpecError(f"{name} must be a positive integer, got {value!r}")
        for name in ("interface_dim", "hidden"):
            if getattr(self, name) > MAX_WIDTH:
                raise SpecError(f"{name} must be at most {MAX_WIDTH}, got {getattr(self, name)}")
        seed_ok = isinstance(self.seed, int) and not isinstance(self.seed, bool)
        if not seed_ok or not 0 <= self.seed <= MAX_RUN_SEED:  # its reset seeds stay in its block
            raise SpecError(f"seed must be an integer 0..{MAX_RUN_SEED}, got {self.seed!r}")
        for name in ("random_episodes", "learning_starts", "eval_every"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise SpecError(f"{name} must be a non-negative integer, got {value!r}")
        if not isinstance(self.action_l2, (int, float)) or self.action_l2 < 0:
            raise SpecError(f"action_l2 must be a non-negative number, got {self.action_l2!r}")
        for name in ("updates_per_step", "lr", "tau", "initial_alpha"):
            if not isinstance(getattr(self, name), (int, float)) or getattr(self, name) <= 0:
                raise SpecError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        if not isinstance(self.relabel_prob, (int, float)) or not 0 <= self.relabel_prob <= 1:
            raise SpecError(f"relabel_prob must be in [0, 1], got {self.relabel_prob!r}")
        entropy = self.target_entropy
        if entropy is not None and (isinstance(entropy, bool) or not isinstance(entropy, (int, float))):
            raise SpecError(f"target_entropy must be a number or null, got {entropy!r}")
        if not 0 < self.gamma < 1:
            raise SpecError(f"gamma must be in (0, 1), got {self.gamma!r}")
        target = self.target_success
        if target is not None and (
            isinstance(target, bool) or not isinstance(target, (int, float)) or not 0 < target <= 1
        ):
            raise SpecError(f"target_success must be a number in (0, 1] or null, got {target!r}")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], where: str = "train spec") -> TrainSpec:
        check_keys(data, cls, where)
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data; a setting added after runs were recorded is left out at its
        default (:data:`LATER_SETTINGS`), so those runs keep their identity and resume."""
        data = json.loads(json.dumps(dataclasses.asdict(self), default=plain_json))
        for name, default in LATER_SETTINGS.items():
            if data[name] == default:
                del data[name]
        return data

    @property
    def env_config(self) -> dict[str, Any]:
        if self.task == POINT_TASK:
            return {}
        return {"robot": self.robot.spelling, "task": self.task.spelling}

    @functools.cached_property
    def resolved(self) -> MethodSpec:
        """The method's resolved settings (its key is parsed once per spec)."""
        return method_spec(self.method)

    @property
    def env_name(self) -> str:
        return "ps_ray_point" if self.task == POINT_TASK else "ps_ray"

    def identity(self) -> dict[str, Any]:
        """What defines the policy being trained; budget and reporting settings may change on resume."""
        return {k: v for k, v in self.to_dict().items() if k not in RESUMABLE_CHANGES}

    def label(self) -> str:
        return trial_key(self.to_dict())

    def slug(self) -> str:
        """The label as a directory name."""
        return re.sub(r"[^\w.-]+", "-", self.label()).strip("-")
