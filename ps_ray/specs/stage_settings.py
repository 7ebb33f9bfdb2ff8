"""The settings of a sweep's stages (its `anchors`, `zero_shot`, `few_shot` and `report` blocks),
each a typed record checked when it loads: unknown keys and bad values fail with one line."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ps_ray.envs.robots import resolve_robot
from ps_ray.envs.tasks import resolve_task
from ps_ray.errors import UserError
from ps_ray.specs.methods import method_key, reanchoring_problem
from ps_ray.specs.modes import AnchorGoals, AnchorPolicy, Mode, Pairing
from ps_ray.specs.names import EnvPart, translations_problem
from ps_ray.specs.train import SpecError, check_types

ANCHOR_POLICIES = tuple(AnchorPolicy)


def _mode(mode: type[Mode], value: Any, where: str) -> Mode:
    try:
        return mode.of(value, where)
    except UserError as e:
        raise SpecError(str(e)) from None


def method_keys(where: str, methods: Any) -> Any:
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
    policy: AnchorPolicy = AnchorPolicy.PLAIN  # roll out trained plain policies (paper) or random actions
    goals: AnchorGoals = AnchorGoals.REAL  # the states' desired goals (ps_ray.data.collect)

    def __post_init__(self) -> None:
        for key, mode in (("policy", AnchorPolicy), ("goals", AnchorGoals)):
            object.__setattr__(self, key, _mode(mode, getattr(self, key), f"anchors.{key}"))
        check_types(self, "anchors")
        unique_entries("anchors", source_tasks=self.source_tasks, steps=self.steps)
        if not isinstance(self.robot, (str, Mapping)):
            raise SpecError(f"anchors.robot must be a name or a mapping, got {self.robot!r}")
        object.__setattr__(self, "robot", EnvPart(self.robot))
        try:
            resolve_robot(self.robot)
        except (ValueError, TypeError) as e:
            raise SpecError(f"anchors.robot: {e}") from None
        for task in self.source_tasks:
            try:
                resolve_task(task)
            except ValueError as e:
                raise SpecError(f"anchors.source_tasks: {e}") from None
        if self.episodes <= 0 or not self.steps:
            raise SpecError("anchors: episodes must be positive and steps non-empty")


def unique_entries(where: str, **lists: tuple) -> None:
    for key, values in lists.items():
        texts = [json.dumps(v, sort_keys=True) for v in values]
        repeated = sorted({t for t in texts if texts.count(t) > 1})
        if repeated:
            raise SpecError(f"{where}.{key}: duplicate entries {', '.join(repeated)}; list each once")


def positive(where: str, **values: int | None) -> None:
    for key, value in values.items():
        if value is not None and value <= 0:
            raise SpecError(f"{where}.{key} must be positive, got {value}")


PAIRINGS = tuple(Pairing)


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
    pairs: Pairing = Pairing.SAME_SEED
    # at most this many pairs evaluated one after another in one Tune trial: a trial's start
    # (process, imports, reading the sources) is paid once per batch (see batch_sizes)
    pairs_per_trial: int = 8

    def __post_init__(self) -> None:
        object.__setattr__(self, "methods", method_keys("zero_shot.methods", self.methods))
        if isinstance(self.translate, Mapping):
            keys = method_keys("zero_shot.translate", tuple(self.translate))
            object.__setattr__(self, "translate", dict(zip(keys, self.translate.values(), strict=True)))
        object.__setattr__(self, "pairs", _mode(Pairing, self.pairs, "zero_shot.pairs"))
        check_types(self, "zero_shot")
        unique_entries("zero_shot", methods=self.methods)
        positive(
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
        object.__setattr__(self, "methods", method_keys("few_shot.methods", self.methods))
        check_types(self, "few_shot")
        if self.critic_warmup_updates < 0:
            raise SpecError(f"few_shot.critic_warmup_updates must be >= 0, got {self.critic_warmup_updates}")
        unique_entries("few_shot", methods=self.methods)
        positive(
            "few_shot", env_steps=self.env_steps, max_pairs=self.max_pairs, pairs_per_seed=self.pairs_per_seed
        )
        if not 0 <= self.collect_steps < self.env_steps:
            raise SpecError(f"few_shot.collect_steps must be in [0, env_steps), got {self.collect_steps}")


@dataclass(frozen=True)
class ReportSpec:
    """The analysis stage: interface dumps on fixed probe states, plots, tables, HTML report."""

    probes_per_group: int = 250  # task states per goal quadrant
    seed: int = 0  # probe-state seed
    few_shot_threshold: float = 0.8  # the few-shot table's "env steps to" this greedy success

    def __post_init__(self) -> None:
        check_types(self, "report")
        positive("report", probes_per_group=self.probes_per_group)
        if not 0 < self.few_shot_threshold <= 1:
            raise SpecError(f"report.few_shot_threshold must be in (0, 1], got {self.few_shot_threshold!r}")
