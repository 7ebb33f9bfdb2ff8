"""The training spec: every field a flag of ``ps-ray train`` and a key of a sweep's ``train:``
block, checked by the spec engine (:mod:`ps_ray.specs.engine`). The sweep spec is in
``ps_ray.specs.sweep``."""

from __future__ import annotations

import dataclasses
import functools
import json
import re
from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import AfterValidator, Field

from ps_ray.envs.registry import RLLIB_ENV, RLLIB_GYM_ENV
from ps_ray.envs.robots import resolve_robot
from ps_ray.envs.tasks import resolve_task
from ps_ray.errors import Words
from ps_ray.specs.defaults import HIDDEN, INTERFACE_DIM, MAX_WIDTH
from ps_ray.specs.engine import (
    NonNegative,
    Number,
    Positive,
    SpecError,
    between,
    parse,
    spec,
)
from ps_ray.specs.methods import OPTIONS, PRESETS, MethodSpec, method_key, method_spec
from ps_ray.specs.names import EnvPart, Part, plain_json, trial_key
from ps_ray.specs.old_methods import upgrade_name
from ps_ray.specs.reset_seeds import MAX_RUN_SEED

Width = Annotated[int, Field(gt=0, le=MAX_WIDTH)]
PositiveNumber = Annotated[Number, Field(gt=0)]
NonNegativeNumber = Annotated[Number, Field(ge=0)]
Share = Annotated[Number, between(0, 1, "[]")]
# a run's reset seeds stay in its own block (ps_ray.specs.reset_seeds)
RunSeed = Annotated[int, Field(ge=0, le=MAX_RUN_SEED), Words(f"an integer 0..{MAX_RUN_SEED}")]


RESUMABLE_CHANGES = (
    "env_steps",
    "eval_every",
    "eval_episodes",
    "checkpoint_every",
    "target_success",
    "target_evals",
)


# Settings added after runs were recorded: written only where they differ from these defaults.
LATER_SETTINGS = {"target_entropy": None, "relabel_prob": 0.8, "env": None, "hindsight": "goal"}
HINDSIGHT = ("goal", "marker")


def marker_columns(task) -> tuple[slice, float] | None:
    """The named marker's task-state columns and their sign (``MarkerScene.hindsight_marker``) of
    a resolved task; None for a task whose goals are not said in a marker's frame."""
    find = getattr(task.family, "hindsight_marker", None)
    return None if find is None else find(task.options)


def require_same(stored: Mapping[str, Any], current: Mapping[str, Any], what: str, advice: str) -> None:
    """The one "same spec or refuse" check of a folder that already holds work: ``what`` names
    the folder's content, ``advice`` what to do instead."""
    changed = sorted(k for k in {*stored, *current} if stored.get(k) != current.get(k))
    if changed:
        raise SpecError(f"{what} (changed: {', '.join(changed)}); {advice}")


def setting(default: Any, help: str) -> Any:
    """A spec field with its documentation, read by the code and by ``ps-ray train --help``."""
    return dataclasses.field(default=default, metadata={"help": help})


def _check_gym_id(env: str) -> None:
    """A gymnasium id this Python can make (``module:Name-v0`` imports the module that registers it)."""
    import importlib

    import gymnasium

    module, _, name = env.rpartition(":")
    try:
        if module:
            importlib.import_module(module)
        gymnasium.spec(name)
    except (gymnasium.error.Error, ImportError) as e:
        raise SpecError(f"env {env!r} is not a gymnasium id this Python can make ({e})") from None


@spec(where="train spec")
class TrainSpec:
    """One SAC + HER training run of one (robot, task, method, seed). Every field is a flag of
    ``ps-ray train`` and a key of a sweep's ``train:`` block; its help text is its doc."""

    robot: Part = setting(EnvPart("panda"), "built-in robot name or a JSON mapping")
    task: Part = setting(EnvPart("reach"), "built-in task name or a JSON mapping")
    method: Annotated[str, AfterValidator(method_key)] = setting(
        "ps",
        "a preset (" + ", ".join(PRESETS) + ") with +option=value overrides, e.g. ps+norm=layer; "
        "options: " + ", ".join(OPTIONS) + " (docs/methods.md)",
    )
    seed: RunSeed = setting(101, "seed of networks, env runner and replay sampling")
    interface_dim: Width = setting(INTERFACE_DIM, "width of the task-robot interface (PS: number of anchors)")
    hidden: Width = setting(HIDDEN, "hidden units per layer of every MLP")
    env_steps: Positive = setting(50_000, "training budget in env steps (a cap when target_success is set)")
    target_success: Annotated[Number, between(0, 1, "(]")] | None = setting(
        None, "stop early at this greedy success (None: never)"
    )
    target_evals: Positive = setting(2, "evaluations in a row at target_success that stop the run")
    episodes_per_step: Positive = setting(2, "whole episodes collected per training step")
    num_envs: Positive = setting(2, "vectorised envs in the env runner")
    updates_per_step: PositiveNumber = setting(0.4, "gradient updates per collected env step (authors: 0.4)")
    batch_size: Positive = setting(256, "transitions per gradient update")
    lr: PositiveNumber = setting(1e-3, "Adam learning rate of actor, critics and temperature")
    initial_alpha: PositiveNumber = setting(0.1, "entropy temperature at the start (auto-tuned after)")
    gamma: Annotated[Number, between(0, 1)] = setting(0.98, "discount")
    tau: PositiveNumber = setting(0.005, "Polyak rate of the target critics")
    action_l2: NonNegativeNumber = setting(0.0, "weight of an L2 penalty on the actor's mean action")
    critic_warmup_updates: NonNegative = setting(
        0,
        "first gradient updates in which only the critics learn (actor and temperature frozen), so a "
        "stitched start's critics fit its actor before the actor follows them (few-shot)",
    )
    target_entropy: Number | None = setting(
        None, "the policy entropy the temperature is tuned towards (None: minus the action dimension)"
    )
    relabel_prob: Share = setting(0.8, "share of replayed transitions with a relabelled goal (HER k=4: 0.8)")
    hindsight: str = setting(
        "goal",
        "how a transition is relabelled: goal (the goal becomes a later achieved goal) or marker (a task "
        "said in a marker's frame keeps its goal and the named marker moves to where the later outcome "
        "puts it, so relabelled goals look like real ones: docs/transfer.md)",
    )
    random_episodes: NonNegative = setting(10, "warm-up episodes with uniform random actions")
    learning_starts: NonNegative = setting(1000, "transitions in the buffer before the first update")
    eval_every: NonNegative = setting(10, "training steps between greedy evaluations (0: never)")
    eval_episodes: Positive = setting(10, "episodes per greedy evaluation (the final one runs twice as many)")
    checkpoint_every: Positive = setting(50, "training steps between sealed checkpoints")
    anchors: str | None = setting(None, "PS: file of task states or an anchor set (None: random rollouts)")
    anchor_episodes: Positive = setting(
        200, "random-policy episodes collected for anchors when anchors is None"
    )
    init_policy: str | None = setting(None, "start from these weights (a stitched policy: few-shot)")
    env: str | None = setting(
        None,
        "a gymnasium id, trained in place of robot and task: any goal-conditioned env with ps_ray's "
        "observation layout (robot_state, task_state, achieved_goal, desired_goal), e.g. "
        "tests.point_env:PointGoal-v0; trained and evaluated, never stitched",
    )

    def __post_init__(self) -> None:
        if self.hindsight not in HINDSIGHT:
            raise SpecError(f"unknown hindsight {self.hindsight!r}; valid hindsight: {', '.join(HINDSIGHT)}")
        if self.env is not None:
            _check_gym_id(self.env)
            if self.hindsight != "goal":
                raise SpecError(
                    f"hindsight {self.hindsight!r} needs a built-in marker task, not env {self.env!r}"
                )
            return
        try:
            resolve_robot(self.robot)
            task = resolve_task(self.task)
        except (ValueError, TypeError) as e:
            raise SpecError(str(e)) from None
        if self.hindsight == "marker" and marker_columns(task) is None:
            raise SpecError(
                f"hindsight 'marker' needs a task said in a marker's frame, got task {self.task.spelling!r}; "
                "valid: reach_red, reach_blue, push_red, push_blue (goal_frame marker)"
            )

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], where: str = "train spec") -> TrainSpec:
        return parse(cls, data, where)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data; a setting added after runs were recorded is left out at its
        default (:data:`LATER_SETTINGS`), so those runs keep their identity and resume."""
        data = json.loads(json.dumps(dataclasses.asdict(self), default=plain_json))
        for name, default in LATER_SETTINGS.items():
            if data[name] == default:
                del data[name]
        return data

    @staticmethod
    def upgrade(data: Any) -> Any:
        """A training spec as any ps_ray wrote it (a run's or checkpoint's ``spec.json``), in
        today's words: one written before the method menu may name an old row of it. Anything
        else is returned as it is, for its reader to refuse."""
        if isinstance(data, Mapping) and isinstance(data.get("method"), str):
            return {**data, "method": upgrade_name(data["method"])}
        return data

    @property
    def env_config(self) -> dict[str, Any]:
        if self.env is not None:
            return {"id": self.env}
        return {"robot": self.robot.spelling, "task": self.task.spelling}

    @functools.cached_property
    def resolved(self) -> MethodSpec:
        """The method's resolved settings (its key is parsed once per spec)."""
        return method_spec(self.method)

    @property
    def env_name(self) -> str:
        """The Tune env the run trains on (``ps_ray.envs.registry``)."""
        return RLLIB_GYM_ENV if self.env is not None else RLLIB_ENV

    def identity(self) -> dict[str, Any]:
        """What defines the policy being trained; budget and reporting settings may change on resume."""
        return {k: v for k, v in self.to_dict().items() if k not in RESUMABLE_CHANGES}

    def label(self) -> str:
        return trial_key(self.to_dict())

    def slug(self) -> str:
        """The label as a directory name."""
        return re.sub(r"[^\w.-]+", "-", self.label()).strip("-")
