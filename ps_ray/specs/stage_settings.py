"""The settings of a sweep's stages (its `anchors`, `zero_shot`, `few_shot` and `report` blocks),
each a typed record checked when it loads: unknown keys and bad values fail with one line."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import Field

from ps_ray.envs.robots import resolve_robot
from ps_ray.envs.tasks import resolve_task
from ps_ray.errors import UserError, Words
from ps_ray.specs.engine import NonNegative, Number, OneOf, Positive, Seq, SpecError, between, spec
from ps_ray.specs.methods import method_key, reanchoring_problem
from ps_ray.specs.modes import AnchorGoals, AnchorPolicy, Pairing
from ps_ray.specs.names import (
    LATENT_TRANSLATIONS,
    TRANSLATION_CHOICES,
    EnvPart,
    Part,
    Translation,
    translations_problem,
)
from ps_ray.specs.reset_seeds import MAX_STAGE_SEED

ANCHOR_POLICIES = tuple(AnchorPolicy)
# a stage's seed: where its fixed episodes start in the stage's block (ps_ray.specs.reset_seeds)
StageSeed = Annotated[int, Field(ge=0, lt=MAX_STAGE_SEED), Words(f"an integer 0..{MAX_STAGE_SEED - 1}")]


def method_keys(where: str, methods: Any) -> Any:
    """Each method (a preset, preset+options or a {preset: ...} mapping) as its canonical key."""
    if not isinstance(methods, (list, tuple)):
        return methods  # the field's type names the problem
    try:
        return tuple(method_key(m) for m in methods)
    except UserError as e:
        raise SpecError(f"{where}: {e}") from None


@spec("anchors")
class AnchorSpec:
    """Where PS anchors come from: a file of task states / an anchor set, or rollouts of the
    source tasks (greedy trained plain policies, as the paper, or random actions)."""

    file: str | None = None  # anchor set (.npz) or task-state array; overrides rollouts
    source_tasks: Seq[str] = ()  # tasks whose states are pooled (default: the sweep's tasks)
    robot: Part = EnvPart("panda")  # the robot of the rollouts (task states do not depend on it)
    episodes: Positive = 200
    steps: Seq[int] = (5, 6, 7, 8, 9)
    seed: StageSeed = 0
    # roll out trained plain policies (paper) or random actions
    policy: OneOf[AnchorPolicy] = AnchorPolicy.PLAIN
    goals: OneOf[AnchorGoals] = AnchorGoals.REAL  # the states' desired goals (ps_ray.data.collect)

    def __post_init__(self) -> None:
        unique_entries("anchors", source_tasks=self.source_tasks, steps=self.steps)
        try:
            resolve_robot(self.robot)
        except (ValueError, TypeError) as e:
            raise SpecError(f"anchors.robot: {e}") from None
        for task in self.source_tasks:
            try:
                resolve_task(task)
            except ValueError as e:
                raise SpecError(f"anchors.source_tasks: {e}") from None
        if not self.steps:
            raise SpecError("anchors: steps must be non-empty")


def unique_entries(where: str, **lists: tuple) -> None:
    for key, values in lists.items():
        texts = [json.dumps(v, sort_keys=True) for v in values]
        repeated = sorted({t for t in texts if texts.count(t) > 1})
        if repeated:
            raise SpecError(f"{where}.{key}: duplicate entries {', '.join(repeated)}; list each once")


PAIRINGS = tuple(Pairing)


@spec("zero_shot")
class ZeroShotSpec:
    """The zero-shot stage: every stitched pair evaluated on fixed seeds (episodes x repeats)."""

    episodes: Positive = 200  # the paper: 200 episodes x 5 repeats
    repeats: Positive = 5
    seed: StageSeed = 0  # first evaluation seed
    methods: Seq[str] = ()  # default: the sweep's methods
    # method -> translations also evaluated for its pairs, e.g. {ablation: [affine]}: rows
    # "ablation+affine" (ps_ray.nets.translation); "@outcome" etc.: ps_ray.stitching.outcomes
    translate: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    fit_states_per_quadrant: Positive = 128  # reset task states per goal quadrant and source task
    outcome_scenes: Positive = 400  # per source: scenes its policy is rolled out on, for "@" fits
    outcome_points: Positive = 256  # reference points (k-means over the outcomes): matched pairs
    # which modules meet: of one training seed, of two seeds (seed i's task modules with seed
    # i+1's robot modules, cyclically: separate training runs), or both
    pairs: OneOf[Pairing] = Pairing.SAME_SEED
    # at most this many pairs evaluated one after another in one Tune trial: a trial's start
    # (process, imports, reading the sources) is paid once per batch (see batch_sizes)
    pairs_per_trial: Positive = 8

    def __post_init__(self) -> None:
        object.__setattr__(self, "methods", method_keys("zero_shot.methods", self.methods))
        keys = method_keys("zero_shot.translate", tuple(self.translate))
        object.__setattr__(self, "translate", dict(zip(keys, self.translate.values(), strict=True)))
        unique_entries("zero_shot", methods=self.methods)
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

    def translations(self, method: str) -> tuple[Translation, ...]:
        """The translations ``translate`` names for ``method`` (checked when the spec loaded)."""
        kinds = self.translate.get(method, ())
        return tuple(map(Translation, (kinds,) if isinstance(kinds, str) else kinds))


@spec("few_shot")
class FewShotSpec:
    """The few-shot stage: stitched starts fine-tuned with SAC + HER beside from-scratch runs."""

    env_steps: Positive = 20000
    collect_steps: NonNegative = 1000  # env steps before the first update (the paper: 10 epochs)
    max_pairs: Positive | None = None  # per method; default: every stitched pair
    pairs_per_seed: Positive | None = None  # per method and seed (a paired comparison over seeds)
    methods: Seq[str] = ()  # default: the sweep's methods
    stitched: bool = True  # start from each selected pair's stitch as it is
    scratch: bool = True  # also train each target env from scratch
    unstitched: bool = True  # also fine-tune each pair's robot source as it is (where widths fit)
    # also start from each half of the stitch beside a fresh other half (ps_ray.stitching.halves):
    # the pair's robot module under a fresh task module, its task module over a fresh robot module
    halves: bool = False
    # also start from each pair's stitch aligned by this fitted latent map (e.g. affine@outcome), as
    # the zero-shot stage fitted and scored it, the map folded into the robot module
    # (ps_ray.stitching.fold): None starts from no aligned stitch
    translation: str | None = None
    # the first updates of a start from trained weights fit the critics alone (actor frozen): a
    # stitched start's critics join halves of two networks and say nothing sound of its actor yet
    critic_warmup_updates: NonNegative = 500

    def __post_init__(self) -> None:
        object.__setattr__(self, "methods", method_keys("few_shot.methods", self.methods))
        unique_entries("few_shot", methods=self.methods)
        if not (self.stitched or self.translation or self.halves or self.unstitched or self.scratch):
            starts = "stitched, translation, halves, unstitched, scratch"
            raise SpecError(f"few_shot: every start is off; turn on one of {starts}")
        if self.collect_steps >= self.env_steps:
            raise SpecError(f"few_shot.collect_steps must be in [0, env_steps), got {self.collect_steps}")
        if self.translation is not None:
            foldable = [t for t in TRANSLATION_CHOICES if Translation(t).kind in LATENT_TRANSLATIONS]
            if self.translation not in foldable:
                raise SpecError(
                    f"few_shot.translation: {self.translation!r} is not a fitted latent map; valid: "
                    f"{', '.join(foldable)}"
                )


@spec("report")
class ReportSpec:
    """The analysis stage: interface dumps on fixed probe states, plots, tables, HTML report."""

    probes_per_group: Positive = 250  # task states per goal quadrant
    seed: StageSeed = 0  # probe-state seed
    # the few-shot table's "env steps to" this greedy success
    few_shot_threshold: Annotated[Number, between(0, 1, "(]")] = 0.8
