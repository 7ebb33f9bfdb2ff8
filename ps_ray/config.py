"""Typed, validated specs. Unknown keys and bad values fail with one line naming them."""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ps_ray.envs.robots import resolve_robot
from ps_ray.envs.tasks import resolve_task
from ps_ray.errors import UserError
from ps_ray.names import trial_key
from ps_ray.nets.modular import METHODS

POINT_TASK = "point"  # the physics-free PointGoalEnv (robot is ignored), for fast checks


RESUMABLE_CHANGES = (
    "env_steps",
    "eval_every",
    "eval_episodes",
    "checkpoint_every",
    "target_success",
    "target_evals",
)


class SpecError(UserError):
    """A spec that cannot run; the message is one line naming the bad key or value."""


def check_keys(data: Mapping[str, Any], cls: type, where: str) -> None:
    """The one unknown-key check: the first key that is not a field of ``cls`` fails, naming the
    valid keys."""
    valid = [f.name for f in dataclasses.fields(cls)]
    bad = [key for key in data if key not in valid]
    if bad:
        raise SpecError(f"{where}: unknown key {bad[0]!r}; valid keys: {', '.join(valid)}")


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

    robot: str | Mapping = setting("panda", "built-in robot name or a JSON mapping")
    task: str | Mapping = setting("reach", "built-in task name or a JSON mapping")
    method: str = setting("ps", "row of the method table: " + ", ".join(METHODS))
    seed: int = setting(101, "seed of networks, env runner and replay sampling")
    interface_dim: int = setting(128, "width of the task-robot interface (PS: number of anchors)")
    hidden: int = setting(256, "hidden units per layer of every MLP")
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
    random_episodes: int = setting(10, "warm-up episodes with uniform random actions")
    learning_starts: int = setting(1000, "transitions in the buffer before the first update")
    eval_every: int = setting(10, "training steps between greedy evaluations (0: never)")
    eval_episodes: int = setting(10, "episodes per greedy evaluation (the final one runs twice as many)")
    checkpoint_every: int = setting(50, "training steps between sealed checkpoints")
    anchors: str | None = setting(None, "PS: file of task states or an anchor set (None: random rollouts)")
    anchor_episodes: int = setting(200, "random-policy episodes collected for anchors when anchors is None")
    init_policy: str | None = setting(None, "start from these weights (a stitched policy: few-shot)")

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise SpecError(f"unknown method {self.method!r}; valid methods: {', '.join(METHODS)}")
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
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise SpecError(f"seed must be a non-negative integer, got {self.seed!r}")
        for name in ("random_episodes", "learning_starts", "eval_every"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise SpecError(f"{name} must be a non-negative integer, got {value!r}")
        if not isinstance(self.action_l2, (int, float)) or self.action_l2 < 0:
            raise SpecError(f"action_l2 must be a non-negative number, got {self.action_l2!r}")
        for name in ("updates_per_step", "lr", "tau", "initial_alpha"):
            if not isinstance(getattr(self, name), (int, float)) or getattr(self, name) <= 0:
                raise SpecError(f"{name} must be a positive number, got {getattr(self, name)!r}")
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
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @property
    def env_config(self) -> dict[str, Any]:
        if self.task == POINT_TASK:
            return {}
        return {"robot": _plain(self.robot), "task": _plain(self.task)}

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


def _plain(value: Any) -> Any:
    return dict(value) if isinstance(value, Mapping) else value


ANCHOR_POLICIES = ("plain", "random")
# Pipeline stages in order; "train" covers plain sources, anchors and the grid (ps_ray.pipeline.sweep).
STAGES = ("train", "zero_shot", "few_shot", "report")


@dataclass(frozen=True)
class AnchorSpec:
    """Where PS anchors come from: a file of task states / an anchor set, or rollouts of the
    source tasks (greedy trained plain policies, as the paper, or random actions)."""

    file: str | None = None  # anchor set (.npz) or task-state array; overrides rollouts
    source_tasks: tuple[str, ...] = ()  # tasks whose states are pooled (default: the sweep's tasks)
    robot: str = "panda"
    episodes: int = 200
    steps: tuple[int, ...] = (5, 6, 7, 8, 9)
    seed: int = 0
    policy: str = "plain"  # roll out trained plain policies (paper) or "random"

    def __post_init__(self) -> None:
        if self.policy not in ANCHOR_POLICIES:
            raise SpecError(f"unknown anchors.policy {self.policy!r}; valid: {', '.join(ANCHOR_POLICIES)}")
        for task in self.source_tasks:
            try:
                resolve_task(task)
            except ValueError as e:
                raise SpecError(f"anchors.source_tasks: {e}") from None
        if self.episodes <= 0 or not self.steps:
            raise SpecError("anchors: episodes must be positive and steps non-empty")


def _positive(where: str, **values: int | None) -> None:
    for key, value in values.items():
        if value is not None and value <= 0:
            raise SpecError(f"{where}.{key} must be positive, got {value}")


@dataclass(frozen=True)
class ZeroShotSpec:
    """The zero-shot stage: every stitched pair evaluated on fixed seeds (episodes x repeats)."""

    episodes: int = 200  # the paper: 200 episodes x 5 repeats
    repeats: int = 5
    seed: int = 0  # first evaluation seed
    methods: tuple[str, ...] = ()  # default: the sweep's methods
    # method -> latent translations also evaluated for its pairs, e.g. {ablation: [affine]};
    # shown as rows "ablation+affine" (ps_ray.nets.translation)
    translate: Mapping[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)
    fit_states_per_quadrant: int = 128  # reset task states per goal quadrant and source task

    def __post_init__(self) -> None:
        from ps_ray.nets.translation import TRANSLATIONS

        _positive(
            "zero_shot",
            episodes=self.episodes,
            repeats=self.repeats,
            fit_states_per_quadrant=self.fit_states_per_quadrant,
        )
        if not isinstance(self.translate, Mapping):
            raise SpecError(f"zero_shot.translate must map methods to translations, got {self.translate!r}")
        for method, kinds in self.translate.items():
            kinds = [kinds] if isinstance(kinds, str) else kinds
            if not isinstance(kinds, (list, tuple)) or not kinds:
                raise SpecError(
                    f"zero_shot.translate.{method}: expected a list of translations, "
                    f"got {kinds!r}; valid: {', '.join(TRANSLATIONS)}"
                )
            for kind in kinds:
                if kind not in TRANSLATIONS:
                    raise SpecError(
                        f"zero_shot.translate.{method}: unknown translation {kind!r}; "
                        f"valid: {', '.join(TRANSLATIONS)}"
                    )
            if len(set(kinds)) != len(kinds):
                raise SpecError(f"zero_shot.translate.{method}: duplicate translation in {list(kinds)}")

    def translations(self, method: str) -> tuple[str, ...]:
        kinds = self.translate.get(method, ())
        return (kinds,) if isinstance(kinds, str) else tuple(kinds)


@dataclass(frozen=True)
class FewShotSpec:
    """The few-shot stage: stitched starts fine-tuned with SAC + HER beside from-scratch runs."""

    env_steps: int = 20000
    collect_steps: int = 1000  # env steps before the first update (the paper: 10 epochs)
    max_pairs: int | None = None  # per method; default: every stitched pair
    methods: tuple[str, ...] = ()  # default: the sweep's methods
    scratch: bool = True  # also train each target env from scratch

    def __post_init__(self) -> None:
        _positive("few_shot", env_steps=self.env_steps, max_pairs=self.max_pairs)
        if not 0 <= self.collect_steps < self.env_steps:
            raise SpecError(f"few_shot.collect_steps must be in [0, env_steps), got {self.collect_steps}")


@dataclass(frozen=True)
class ReportSpec:
    """The analysis stage: interface dumps on fixed probe states, plots, tables, HTML report."""

    probes_per_group: int = 250  # task states per goal quadrant
    seed: int = 0  # probe-state seed

    def __post_init__(self) -> None:
        _positive("report", probes_per_group=self.probes_per_group)


SUB_SPECS = {"anchors": AnchorSpec, "zero_shot": ZeroShotSpec, "few_shot": FewShotSpec, "report": ReportSpec}
# Settings that do not change what the training stage produces (a resumed sweep may change them).
NOT_TRAINING = ("stages", "zero_shot", "few_shot", "report", "max_concurrent", "max_failures")


@dataclass(frozen=True)
class SweepSpec:
    """A grid of training trials (methods x robots x tasks x seeds) run as Ray Tune trials."""

    name: str
    methods: tuple[str, ...]
    robots: tuple[str | Mapping, ...]
    tasks: tuple[str | Mapping, ...]
    seeds: tuple[int, ...]
    stages: tuple[str, ...] = ("train",)
    interface_dims: tuple[int, ...] = (128,)
    # TrainSpec fields shared by every trial (documented by `ps-ray train --help`); each key and
    # value is checked against TrainSpec's typed fields when the sweep loads (see trials()).
    train: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    anchors: AnchorSpec = AnchorSpec()
    zero_shot: ZeroShotSpec = ZeroShotSpec()
    few_shot: FewShotSpec = FewShotSpec()
    report: ReportSpec = ReportSpec()
    max_concurrent: int | None = None  # default: one trial per available CPU
    max_failures: int = 2  # retries of a crashed trial, from its last checkpoint
    storage: str = "runs/sweeps"
    tracking_uri: str | None = None  # default: sqlite under <storage>/<name>/

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.replace("_", "").replace("-", "").isalnum():
            raise SpecError(f"sweep name must be letters, digits, '-' or '_', got {self.name!r}")
        for stage in self.stages:
            if stage not in STAGES:
                raise SpecError(f"unknown stage {stage!r}; valid stages: {', '.join(STAGES)}")
        for key in ("methods", "robots", "tasks", "seeds", "interface_dims", "stages"):
            if not getattr(self, key) and key != "stages":
                raise SpecError(f"{key} must be a non-empty list")
            values = [json.dumps(v, sort_keys=True) for v in getattr(self, key)]
            repeated = sorted({v for v in values if values.count(v) > 1})
            if repeated:  # two trials would share one run folder, MLflow run and zoo key
                raise SpecError(f"{key}: duplicate entries {', '.join(repeated)}; list each once")
        for stage in (self.zero_shot, self.few_shot):
            for method in (*stage.methods, *getattr(stage, "translate", ())):
                if method not in self.methods:
                    raise SpecError(
                        f"{type(stage).__name__}: method {method!r} is not trained by "
                        f"this sweep; valid: {', '.join(self.methods)}"
                    )
        self.trials()  # every trial's TrainSpec is validated before anything starts

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data (tuples as lists)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    def training_identity(self) -> dict[str, Any]:
        """What the training stage's outputs depend on (a resumed sweep must keep it)."""
        return {k: v for k, v in self.to_dict().items() if k not in NOT_TRAINING}

    def trials(self) -> list[TrainSpec]:
        overrides = dict(self.train)
        for key in ("method", "robot", "task", "seed", "interface_dim"):
            if key in overrides:
                raise SpecError(f"train.{key} is set by the sweep grid; remove it from 'train'")
        return [
            TrainSpec.from_mapping(
                {**overrides, "method": m, "robot": r, "task": t, "seed": s, "interface_dim": d},
                where="sweep 'train'",
            )
            for m in self.methods
            for r in self.robots
            for t in self.tasks
            for s in self.seeds
            for d in self.interface_dims
        ]

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], where: str = "sweep") -> SweepSpec:
        if not isinstance(data, Mapping):
            raise SpecError(f"{where}: expected a mapping at the top level, got {type(data).__name__}")
        check_keys(data, cls, where)
        fields = dict(data)
        for key in ("methods", "robots", "tasks", "seeds", "stages", "interface_dims"):
            if key in fields:
                value = fields[key]
                fields[key] = tuple(value) if isinstance(value, (list, tuple)) else (value,)
        for key, sub in SUB_SPECS.items():
            if key in fields:
                fields[key] = _sub_spec(sub, fields[key], f"{where}: {key}")
        try:
            return cls(**fields)
        except TypeError as e:
            raise SpecError(f"{where}: {e}") from None


def _sub_spec(cls, data: Any, where: str):
    """A nested mapping as a typed spec; unknown keys fail with the valid ones listed."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise SpecError(f"{where}: expected a mapping, got {data!r}")
    check_keys(data, cls, where)
    try:
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})
    except TypeError as e:
        raise SpecError(f"{where}: {e}") from None


def load_sweep(path: str | Path) -> SweepSpec:
    """Strict YAML loading: malformed YAML, unknown keys and bad values fail with one line."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise SpecError(f"{path}: no such sweep file") from None
    except IsADirectoryError:
        raise SpecError(f"{path}: is a folder, not a sweep file") from None
    except UnicodeDecodeError as e:
        raise SpecError(f"{path}: not a UTF-8 text file (byte {e.start}); a sweep is YAML text") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise SpecError(f"{path}: malformed YAML{where}: {getattr(e, 'problem', e)}") from None
    try:
        return SweepSpec.from_mapping(data, where=str(path))
    except SpecError as e:
        message = str(e)
        raise SpecError(message if message.startswith(str(path)) else f"{path}: {message}") from None
