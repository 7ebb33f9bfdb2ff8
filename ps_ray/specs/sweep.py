"""The sweep spec: a grid of training trials and the settings of the stages that follow. Loaded
strictly: unknown keys and bad values fail with one line naming them."""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ps_ray.envs.robots import resolve_robot
from ps_ray.envs.tasks import resolve_task
from ps_ray.errors import UserError
from ps_ray.specs.defaults import INTERFACE_DIM
from ps_ray.specs.grid import GridSettings
from ps_ray.specs.methods import method_key, reanchoring_problem
from ps_ray.specs.names import ANCHOR_GOALS, EnvPart, plain_json, translations_problem
from ps_ray.specs.resources import ResourcesSpec
from ps_ray.specs.stages import NOT_TRAINING, STAGES
from ps_ray.specs.train import SpecError, TrainSpec, check_keys, check_types

ANCHOR_POLICIES = ("plain", "random")


def _method_keys(where: str, methods: Any) -> Any:
    """Each method (a preset, preset+options or a {preset: ...} mapping) as its canonical key."""
    if not isinstance(methods, (list, tuple)):
        return methods  # check_types names the problem
    try:
        return tuple(method_key(m) for m in methods)
    except UserError as e:
        raise SpecError(f"{where}: {e}") from None


@dataclass(frozen=True)
class AnchorSpec:
    """Where PS anchors come from: a file of task states / an anchor set, or rollouts of the
    source tasks (greedy trained plain policies, as the paper, or random actions)."""

    file: str | None = None  # anchor set (.npz) or task-state array; overrides rollouts
    source_tasks: tuple[str, ...] = ()  # tasks whose states are pooled (default: the sweep's tasks)
    robot: EnvPart = EnvPart("panda")  # the robot of the rollouts (task states do not depend on it)
    episodes: int = 200
    steps: tuple[int, ...] = (5, 6, 7, 8, 9)
    seed: int = 0
    policy: str = "plain"  # roll out trained plain policies (paper) or "random"
    goals: str = "real"  # the states' desired goals: their own (paper) or "relabelled" (ps_ray.data.collect)

    def __post_init__(self) -> None:
        check_types(self, "anchors")
        _unique("anchors", source_tasks=self.source_tasks, steps=self.steps)
        if not isinstance(self.robot, (str, Mapping)):
            raise SpecError(f"anchors.robot must be a name or a mapping, got {self.robot!r}")
        object.__setattr__(self, "robot", EnvPart(self.robot))
        try:
            resolve_robot(self.robot)
        except (ValueError, TypeError) as e:
            raise SpecError(f"anchors.robot: {e}") from None
        for key, valid in (("policy", ANCHOR_POLICIES), ("goals", ANCHOR_GOALS)):
            if getattr(self, key) not in valid:
                raise SpecError(f"unknown anchors.{key} {getattr(self, key)!r}; valid: {', '.join(valid)}")
        for task in self.source_tasks:
            try:
                resolve_task(task)
            except ValueError as e:
                raise SpecError(f"anchors.source_tasks: {e}") from None
        if self.episodes <= 0 or not self.steps:
            raise SpecError("anchors: episodes must be positive and steps non-empty")


def _unique(where: str, **lists: tuple) -> None:
    for key, values in lists.items():
        texts = [json.dumps(v, sort_keys=True) for v in values]
        repeated = sorted({t for t in texts if texts.count(t) > 1})
        if repeated:
            raise SpecError(f"{where}.{key}: duplicate entries {', '.join(repeated)}; list each once")


def _positive(where: str, **values: int | None) -> None:
    for key, value in values.items():
        if value is not None and value <= 0:
            raise SpecError(f"{where}.{key} must be positive, got {value}")


PAIRINGS = ("same_seed", "cross_seed", "both")


@dataclass(frozen=True)
class ZeroShotSpec:
    """The zero-shot stage: every stitched pair evaluated on fixed seeds (episodes x repeats)."""

    episodes: int = 200  # the paper: 200 episodes x 5 repeats
    repeats: int = 5
    seed: int = 0  # first evaluation seed
    methods: tuple[str, ...] = ()  # default: the sweep's methods
    # method -> translations also evaluated for its pairs, e.g. {ablation: [affine]}: rows
    # "ablation+affine" (ps_ray.nets.translation); "@outcome" etc.: ps_ray.stitching.outcomes
    translate: Mapping[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)
    fit_states_per_quadrant: int = 128  # reset task states per goal quadrant and source task
    outcome_scenes: int = 400  # per source: scenes its policy is rolled out on, for "@" fits
    outcome_points: int = 256  # reference points (k-means over the outcomes): matched pairs
    # which modules meet: of one training seed, of two seeds (seed i's task modules with seed
    # i+1's robot modules, cyclically: separate training runs), or both
    pairs: str = "same_seed"
    # at most this many pairs evaluated one after another in one Tune trial: a trial's start
    # (process, imports, reading the sources) is paid once per batch (see batch_sizes)
    pairs_per_trial: int = 8

    def __post_init__(self) -> None:
        object.__setattr__(self, "methods", _method_keys("zero_shot.methods", self.methods))
        if isinstance(self.translate, Mapping):
            keys = _method_keys("zero_shot.translate", tuple(self.translate))
            object.__setattr__(self, "translate", dict(zip(keys, self.translate.values(), strict=True)))
        check_types(self, "zero_shot")
        if self.pairs not in PAIRINGS:
            raise SpecError(f"unknown zero_shot.pairs {self.pairs!r}; valid: {', '.join(PAIRINGS)}")
        _unique("zero_shot", methods=self.methods)
        _positive(
            "zero_shot",
            episodes=self.episodes,
            repeats=self.repeats,
            fit_states_per_quadrant=self.fit_states_per_quadrant,
            pairs_per_trial=self.pairs_per_trial,
            outcome_scenes=self.outcome_scenes,
            outcome_points=self.outcome_points,
        )
        if not isinstance(self.translate, Mapping):
            raise SpecError(f"zero_shot.translate must map methods to translations, got {self.translate!r}")
        for method, kinds in self.translate.items():
            problem = translations_problem([kinds] if isinstance(kinds, str) else kinds)
            problem = problem or reanchoring_problem(method, self.translations(method))
            if problem:
                raise SpecError(f"zero_shot.translate.{method}: {problem}")

    def batch_sizes(self, pairs: int, slots: int | None) -> list[int]:
        """How many pairs each Tune trial of the stage evaluates: at most ``pairs_per_trial``, as
        even as can be, and as many trials as fill whole rounds of ``slots`` trials at once (the
        sweep's max_concurrent), so that no round runs a lone batch on an idle machine."""
        count = -(-pairs // self.pairs_per_trial)
        if slots:
            count = min(pairs, -(-count // slots) * slots)
        return [pairs // count + (i < pairs % count) for i in range(count)] if pairs else []

    def translations(self, method: str) -> tuple[str, ...]:
        kinds = self.translate.get(method, ())
        return (kinds,) if isinstance(kinds, str) else tuple(kinds)


@dataclass(frozen=True)
class FewShotSpec:
    """The few-shot stage: stitched starts fine-tuned with SAC + HER beside from-scratch runs."""

    env_steps: int = 20000
    collect_steps: int = 1000  # env steps before the first update (the paper: 10 epochs)
    max_pairs: int | None = None  # per method; default: every stitched pair
    pairs_per_seed: int | None = None  # per method and seed (a paired comparison over seeds)
    methods: tuple[str, ...] = ()  # default: the sweep's methods
    scratch: bool = True  # also train each target env from scratch
    unstitched: bool = True  # also fine-tune each pair's robot source as it is (where widths fit)
    # also start from each half of the stitch beside a fresh other half (ps_ray.stitching.halves):
    # the pair's robot module under a fresh task module, its task module over a fresh robot module
    halves: bool = False
    # the first updates of a start from trained weights fit the critics alone (actor frozen): a
    # stitched start's critics join halves of two networks and say nothing sound of its actor yet
    critic_warmup_updates: int = 500

    def __post_init__(self) -> None:
        object.__setattr__(self, "methods", _method_keys("few_shot.methods", self.methods))
        check_types(self, "few_shot")
        if self.critic_warmup_updates < 0:
            raise SpecError(f"few_shot.critic_warmup_updates must be >= 0, got {self.critic_warmup_updates}")
        _unique("few_shot", methods=self.methods)
        _positive(
            "few_shot", env_steps=self.env_steps, max_pairs=self.max_pairs, pairs_per_seed=self.pairs_per_seed
        )
        if not 0 <= self.collect_steps < self.env_steps:
            raise SpecError(f"few_shot.collect_steps must be in [0, env_steps), got {self.collect_steps}")


@dataclass(frozen=True)
class ReportSpec:
    """The analysis stage: interface dumps on fixed probe states, plots, tables, HTML report."""

    probes_per_group: int = 250  # task states per goal quadrant
    seed: int = 0  # probe-state seed

    def __post_init__(self) -> None:
        check_types(self, "report")
        _positive("report", probes_per_group=self.probes_per_group)


SUB_SPECS = {
    "anchors": AnchorSpec,
    "grid": GridSettings,
    "zero_shot": ZeroShotSpec,
    "few_shot": FewShotSpec,
    "report": ReportSpec,
    "resources": ResourcesSpec,
}


@dataclass(frozen=True)
class SweepSpec:
    """A grid of training trials (methods x robots x tasks x seeds) run as Ray Tune trials."""

    name: str
    methods: tuple[str, ...]
    robots: tuple[EnvPart, ...]
    tasks: tuple[EnvPart, ...]
    seeds: tuple[int, ...]
    stages: tuple[str, ...] = ("train",)
    interface_dims: tuple[int, ...] = (INTERFACE_DIM,)
    # TrainSpec fields shared by every trial (`ps-ray train --help`), checked when it loads (trials())
    train: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    anchors: AnchorSpec = AnchorSpec()
    grid: GridSettings = GridSettings()
    zero_shot: ZeroShotSpec = ZeroShotSpec()
    few_shot: FewShotSpec = FewShotSpec()
    report: ReportSpec = ReportSpec()
    resources: ResourcesSpec = ResourcesSpec()  # per trial of each stage (ps_ray.specs.resources)
    max_concurrent: int | None = None  # default: one trial per available CPU
    max_failures: int = 2  # retries of a crashed trial, from its last checkpoint
    storage: str = "runs/sweeps"
    tracking_uri: str | None = None  # default: sqlite under <storage>/<name>/

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.replace("_", "").replace("-", "").isalnum():
            raise SpecError(f"sweep name must be letters, digits, '-' or '_', got {self.name!r}")
        # the grid's lists are checked per trial, by TrainSpec, with messages naming the field
        check_types(self, "sweep", skip=("methods", "robots", "tasks", "seeds", "interface_dims", "stages"))
        _positive("sweep", max_concurrent=self.max_concurrent)
        if self.max_failures < 0:
            raise SpecError(f"sweep.max_failures must be a non-negative integer, got {self.max_failures}")
        for stage in self.stages:
            if stage not in STAGES:
                raise SpecError(f"unknown stage {stage!r}; valid stages: {', '.join(STAGES)}")
        for key in ("robots", "tasks"):  # one type; a value of another type is named by the trials' specs
            parts = (EnvPart(v) if isinstance(v, (str, Mapping)) else v for v in getattr(self, key))
            object.__setattr__(self, key, tuple(parts))
        object.__setattr__(self, "methods", _method_keys("methods", self.methods))
        for key in ("methods", "robots", "tasks", "seeds", "interface_dims", "stages"):
            if not getattr(self, key) and key != "stages":
                raise SpecError(f"{key} must be a non-empty list")
            values = getattr(self, key)
            same = [_identity(key, v) for v in values]
            repeated = sorted(
                {
                    json.dumps(v, sort_keys=True, default=plain_json)
                    for v, i in zip(values, same)
                    if same.count(i) > 1
                }
            )
            if repeated:  # the same trial twice: one run folder, MLflow run and zoo key, or wasted work
                raise SpecError(f"{key}: duplicate entries {', '.join(repeated)}; list each once")
        for stage in (self.grid, self.zero_shot, self.few_shot):
            for method in (*stage.methods, *getattr(stage, "translate", ())):
                if method not in self.methods:
                    raise SpecError(
                        f"{type(stage).__name__}: method {method!r} is not trained by "
                        f"this sweep; valid: {', '.join(self.methods)}"
                    )
        self.trials()  # every trial's TrainSpec is validated before anything starts
        if "grid" in self.stages:
            self.grid.grids(self)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data (tuples as lists)."""
        return json.loads(json.dumps(dataclasses.asdict(self), default=plain_json))

    def training_identity(self) -> dict[str, Any]:
        """What the training stage's outputs depend on (a resumed sweep must keep it)."""
        return {k: v for k, v in self.to_dict().items() if k not in NOT_TRAINING}

    def trials(self) -> list[TrainSpec]:
        """Every training trial of the grid, validated (expanded once per spec)."""
        return list(self._trials)

    @functools.cached_property
    def _trials(self) -> tuple[TrainSpec, ...]:
        overrides = dict(self.train)
        for key in ("method", "robot", "task", "seed", "interface_dim"):
            if key in overrides:
                raise SpecError(f"train.{key} is set by the sweep grid; remove it from 'train'")
        return tuple(
            TrainSpec.from_mapping(
                {**overrides, "method": m, "robot": r, "task": t, "seed": s, "interface_dim": d},
                where="sweep 'train'",
            )
            for m in self.methods
            for r in self.robots
            for t in self.tasks
            for s in self.seeds
            for d in self.interface_dims
        )

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


def _identity(key: str, value: Any) -> Any:
    """What makes two list entries the same: the robot or task they resolve to, else the value."""
    try:
        if key == "robots":
            return resolve_robot(value)
        if key == "tasks":
            return resolve_task(value)
    except (ValueError, TypeError):
        pass  # an unknown robot or task fails later, naming the choices
    return json.dumps(value, sort_keys=True, default=plain_json)


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


# -- what the grid implies ---------------------------------------------------------------------------
def seed_pairs(seeds: tuple[int, ...], pairing: str) -> list[tuple[str, int, int]]:
    """(pairing, task module's seed, robot module's seed): same seed, and/or each seed's task
    modules with the next seed's robot modules (cyclically: every seed once on each side)."""
    out = []
    if pairing in ("same_seed", "both"):
        out += [("same_seed", s, s) for s in seeds]
    if pairing in ("cross_seed", "both") and len(seeds) > 1:
        out += [("cross_seed", s, seeds[(i + 1) % len(seeds)]) for i, s in enumerate(seeds)]
    return out


def anchor_sources(spec: SweepSpec) -> list[TrainSpec]:
    """The plain trials whose greedy rollouts give the anchor states (policy: plain)."""
    ps = [t for t in spec.trials() if t.resolved.uses_anchors]
    tasks = [EnvPart(t) for t in spec.anchors.source_tasks] or list(dict.fromkeys(t.task for t in ps))
    return [
        TrainSpec.from_mapping(
            {
                **t.to_dict(),
                "method": "plain",
                "robot": spec.anchors.robot,
                "task": task,
                "seed": spec.seeds[0],
            }
        )
        for task in tasks
        for t in ps[:1]
    ]


def task_input_dim(task) -> int:
    """Width of ``task``'s task-module input: anchor sets are shared by tasks of one width."""
    return resolve_task(task).input_dim
