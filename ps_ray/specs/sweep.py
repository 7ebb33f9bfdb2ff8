"""The sweep spec: a grid of training trials and the settings of the stages that follow. Loaded
strictly: unknown keys and bad values fail with one line naming them."""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

from pydantic import BeforeValidator

from ps_ray.envs.robots import resolve_robot
from ps_ray.envs.tasks import resolve_task
from ps_ray.envs.tasks.markers import Markers, MarkerScene
from ps_ray.specs.defaults import INTERFACE_DIM
from ps_ray.specs.engine import NonNegative, Positive, SpecError, parse, spec, sub_spec
from ps_ray.specs.grid import GridSettings
from ps_ray.specs.modes import Pairing
from ps_ray.specs.names import EnvPart, plain_json
from ps_ray.specs.resources import ResourcesSpec
from ps_ray.specs.search import SearchSpec
from ps_ray.specs.search import name as search_name
from ps_ray.specs.stage_settings import (
    AnchorSpec,
    FewShotSpec,
    ReportSpec,
    ZeroShotSpec,
    method_keys,
)
from ps_ray.specs.stages import NOT_TRAINING, STAGES
from ps_ray.specs.train import TrainSpec

SUB_SPECS = {
    "anchors": AnchorSpec,
    "grid": GridSettings,
    "zero_shot": ZeroShotSpec,
    "few_shot": FewShotSpec,
    "report": ReportSpec,
    "resources": ResourcesSpec,
    "search": SearchSpec,
}
SEARCH_STAGES = ("train", "report")  # a searched trial is a candidate setting, not a source to stitch


def _listed(value: Any) -> tuple:
    return tuple(value) if isinstance(value, (list, tuple)) else (value,)


# A grid's list (a single value is a list of one); its entries are checked by the trials' TrainSpecs,
# whose messages name the field ("seed must be an integer 0..99999, got 'abc'")
Listed = Annotated[tuple[Any, ...], BeforeValidator(_listed)]


def _sub(cls: type, key: str) -> Any:
    return Annotated[cls, sub_spec(cls, key)]


@spec("sweep", where="sweep")
class SweepSpec:
    """A grid of training trials (methods x robots x tasks x seeds) run as Ray Tune trials."""

    name: str
    methods: Listed
    robots: Listed
    tasks: Listed
    seeds: Listed
    stages: Listed = ("train",)
    interface_dims: Listed = (INTERFACE_DIM,)
    # TrainSpec fields shared by every trial (`ps-ray train --help`), checked when it loads (trials())
    train: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    anchors: _sub(AnchorSpec, "anchors") = AnchorSpec()
    grid: _sub(GridSettings, "grid") = GridSettings()
    zero_shot: _sub(ZeroShotSpec, "zero_shot") = ZeroShotSpec()
    few_shot: _sub(FewShotSpec, "few_shot") = FewShotSpec()
    report: _sub(ReportSpec, "report") = ReportSpec()
    # per trial of each stage (ps_ray.specs.resources)
    resources: _sub(ResourcesSpec, "resources") = ResourcesSpec()
    search: _sub(SearchSpec, "search") = SearchSpec()  # training settings searched over (ps_ray.specs.search)
    # sources per train-stage trial: up to K sources that share their method and widths trained in
    # one learner (ps_ray.specs.population, docs/cost.md "Populations"); 1: a trial per source
    population: Positive = 1
    max_concurrent: Positive | None = None  # default: one trial per available CPU
    max_failures: NonNegative = 2  # retries of a crashed trial, from its last checkpoint
    storage: str = "runs/sweeps"
    tracking_uri: str | None = None  # default: sqlite under <storage>/<name>/
    # what the sweep is for, the MLflow experiment's description (default: the file's header)
    description: str = ""
    log_models: bool = True  # each source's policy as a logged MLflow model (ps_ray.pipeline.policy_models)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.replace("_", "").replace("-", "").isalnum():
            raise SpecError(f"sweep name must be letters, digits, '-' or '_', got {self.name!r}")
        for stage in self.stages:
            if stage not in STAGES:
                raise SpecError(f"unknown stage {stage!r}; valid stages: {', '.join(STAGES)}")
        ordered = [s for s in STAGES if s in self.stages]
        if list(dict.fromkeys(self.stages)) != ordered:  # they run in the pipeline's order: say so
            order = ", ".join(ordered)
            raise SpecError(f"stages {list(self.stages)} are not in the pipeline's order; write [{order}]")
        for key in ("robots", "tasks"):  # one type; a value of another type is named by the trials' specs
            parts = (EnvPart(v) if isinstance(v, (str, Mapping)) else v for v in getattr(self, key))
            object.__setattr__(self, key, tuple(parts))
        object.__setattr__(self, "methods", method_keys("methods", self.methods))
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
        if self.search.active:
            self._check_search()
            if self.population > 1:
                raise SpecError(
                    f"population {self.population}: a search ranks each drawn setting by a trial of its "
                    "own; valid with a search: population 1"
                )
        train = self.resources.train
        if self.population > 1 and train.compile:
            raise SpecError(
                f"population {self.population}: a population's batched update runs uncompiled (its "
                "vmapped pass is not checked under torch.compile); valid with population > 1: "
                "resources.train compile false"
            )
        trials = self.trials()  # every trial's TrainSpec is validated before anything starts
        consolidating = [t.method for t in trials if t.resolved.consolidate is not None]
        if self.population > 1 and consolidating:
            raise SpecError(
                f"population {self.population}: method {consolidating[0]} consolidates its actor when a "
                "run ends, which a population does not do; valid: population 1 for it"
            )
        self._check_marker_scenes()
        if "grid" in self.stages:
            self.grid.grids(self)

    def _check_search(self) -> None:
        extra = [s for s in self.stages if s not in SEARCH_STAGES]
        if extra:
            raise SpecError(
                f"stage {extra[0]!r} cannot follow a search (its trials are candidate settings, not "
                f"sources); valid stages with a search: {', '.join(SEARCH_STAGES)}"
            )
        both = [k for k in self.search.space if k in self.train]
        if both:
            raise SpecError(f"search.space.{both[0]} is also set in 'train'; set it in one place")

    def _check_marker_scenes(self) -> None:
        """A stitch that sets a scene from a task input (``anchors@``: the reach markers only) or
        swaps its markers (``@swapped``: tasks of one family with marker scenes, the push family's
        too) is refused here for other tasks, not after training."""
        zero_shot = self.zero_shot
        kinds = [t for m in zero_shot.translate for t in zero_shot.translations(m) if t.scene_fit]
        families = {resolve_task(t).family for t in self.tasks}
        for translation in kinds:
            anchors = translation.kind == "anchors"
            family = Markers if anchors else MarkerScene
            other = [t for t in self.tasks if not issubclass(resolve_task(t).family, family)]
            what, valid = (
                ("sets reach marker scenes", "the reach markers (reach_red, reach_blue, ...)")
                if anchors
                else ("swaps marker scenes", "tasks with markers (reach_red, push_red, ...)")
            )
            if other:
                raise SpecError(
                    f"zero_shot.translate: {translation} {what}, and task {other[0].short} has none; "
                    f"valid: {valid}"
                )
            if len(families) > 1:  # a pair across families has no markers to trade
                raise SpecError(
                    f"zero_shot.translate: {translation} {what} between two tasks of one family, and "
                    f"the sweep mixes {', '.join(sorted(f.__name__ for f in families))}; valid: "
                    f"tasks of one family"
                )

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data (tuples as lists); no ``search`` key without a search, no
        ``population`` key at 1 and no ``few_shot.translation`` without one, so a sweep recorded
        before any of them existed keeps its identity."""
        data = json.loads(json.dumps(dataclasses.asdict(self), default=plain_json))
        if not self.search.active:
            del data["search"]
        if self.population == 1:  # a sweep recorded before populations existed keeps its identity
            del data["population"]
        if self.few_shot.translation is None:  # nor one recorded before aligned starts existed
            del data["few_shot"]["translation"]
        return data

    def training_identity(self) -> dict[str, Any]:
        """What the training stage's outputs depend on (a resumed sweep must keep it)."""
        return {k: v for k, v in self.to_dict().items() if k not in NOT_TRAINING}

    def trials(self) -> list[TrainSpec]:
        """Every training trial of the grid, validated (expanded once per spec); with a search,
        the grid once per drawn setting."""
        return [spec for _, spec in self._trials]

    def named_trials(self) -> list[tuple[str, TrainSpec]]:
        """:meth:`trials` with the name of each one's drawn setting ("" without a search)."""
        return list(self._trials)

    @functools.cached_property
    def _trials(self) -> tuple[tuple[str, TrainSpec], ...]:
        overrides = dict(self.train)
        for key in ("method", "robot", "task", "seed", "interface_dim"):
            if key in overrides:
                raise SpecError(f"train.{key} is set by the sweep grid; remove it from 'train'")
        if overrides.get("env") is not None:
            raise SpecError(
                "train.env: a sweep trains robots x tasks; train a gymnasium env with ps-ray train --env"
            )
        draws = dict(enumerate(self.search.draws())) if self.search.active else {None: {}}
        return tuple(
            (
                "" if i is None else search_name(i),
                TrainSpec.from_mapping(
                    {**overrides, **draw, "method": m, "robot": r, "task": t, "seed": s, "interface_dim": d},
                    where="sweep 'train'" if i is None else f"sweep 'train' with {search_name(i)} {draw}",
                ),
            )
            for i, draw in draws.items()
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
        return parse(cls, data, where)


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


def load_stored_sweep(path: str | Path) -> SweepSpec:
    """A sweep folder's own spec (its ``sweep.yaml``, resolved and written by ps_ray), strictly;
    one recorded before the method menu names old rows, read as their keys."""
    from ps_ray.specs.old_methods import upgrade_names
    from ps_ray.specs.sweep_file import read_file

    return SweepSpec.from_mapping(upgrade_names(read_file(Path(path)) or {}), where=str(path))


def load_sweep(path: str | Path, sets: Sequence[str] = ()) -> SweepSpec:
    """Strict loading of a sweep file (:mod:`ps_ray.specs.sweep_file`: its base merged under it,
    ``sets`` over it): malformed YAML, duplicate or unknown keys and bad values fail with one line
    naming the file."""
    from ps_ray.specs.sweep_file import BASE_KEY, header, read_file, read_sweep

    path = Path(path)
    data = read_sweep(path, sets)
    if isinstance(data, Mapping) and "description" not in data and (text := header(path)):
        data = {**data, "description": text}
    top = read_file(path)
    where = str(path)
    if isinstance(top, Mapping) and BASE_KEY in top:  # a bad key may come from either file
        where = f"{path} (with its base {top[BASE_KEY]})"
    try:
        return SweepSpec.from_mapping(data, where=where)
    except SpecError as e:
        message = str(e).removeprefix(f"{where}: ")
        if sets and _loads(path):  # the file alone is fine: the error is the --set's
            raise SpecError(f"--set {' '.join(sets)} (over {path}): {message}") from None
        raise SpecError(f"{where}: {message}") from None


def _loads(path: Path) -> bool:
    """Whether the sweep file, without any ``--set``, is a valid spec."""
    try:
        load_sweep(path)
    except SpecError:
        return False
    return True


# -- what the grid implies ---------------------------------------------------------------------------
def seed_pairs(seeds: tuple[int, ...], pairing: str) -> list[tuple[str, int, int]]:
    """(pairing, task module's seed, robot module's seed): same seed, and/or each seed's task
    modules with the next seed's robot modules (cyclically: every seed once on each side)."""
    out = []
    if pairing in (Pairing.SAME_SEED, Pairing.BOTH):
        out += [("same_seed", s, s) for s in seeds]
    if pairing in (Pairing.CROSS_SEED, Pairing.BOTH) and len(seeds) > 1:
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
