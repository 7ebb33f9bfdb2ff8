"""The trials the training stages hand to Tune and read back, as typed records: a
:class:`TrainTrial` (a source, an anchor policy or a few-shot start) and a :class:`GridTrial` (a
co-trained grid). Their Tune configs are plain JSON (``config``), the same a stage wrote before the
records existed, so a resumed stage finds its trials and stored ``params.json`` files still read
(``of``). A zero-shot trial's record is :class:`ps_ray.stitching.pairs.StitchedPair`."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ps_ray.specs.grid import GridSpec
from ps_ray.specs.modes import TrialKind
from ps_ray.specs.names import readable, short_name, trial_key
from ps_ray.specs.population import PopulationSpec
from ps_ray.specs.titles import env_title, spec_title, title, width_tag
from ps_ray.specs.train import TrainSpec

# What a training trial is: a source of the grid or of the anchors, or a few-shot start
# (ps_ray.pipeline.few_shot): the stitched pair, one half of it beside a fresh other half, the
# pair's robot source as it is, or the target env from scratch.
HALVES = (TrialKind.ROBOT_MODULE, TrialKind.TASK_MODULE)  # which half of the stitch a start keeps
KINDS = tuple(TrialKind)
STITCHED_STARTS = (TrialKind.STITCHED, TrialKind.ALIGNED, *HALVES)  # the starts made from a stitched pair


@dataclass(frozen=True)
class TrainTrial:
    spec: TrainSpec
    anchors: str | None = None  # the anchor-set file of a PS trial (None: none, or the init policy's)
    key: str = ""  # its MLflow run name ("": the spec's trial key)
    label: str = ""  # the row a table puts it in ("": its key)
    kind: TrialKind = TrialKind.TRAIN

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", TrialKind.of(self.kind, "trial kind", "kinds"))

    @property
    def run_name(self) -> str:
        return self.key or trial_key(self.spec.to_dict())

    @property
    def title(self) -> str:
        """Its MLflow run name (:mod:`ps_ray.specs.titles`): the trained env, method and seed, then
        a search's setting or what a few-shot run starts from."""
        label = readable(self.label)
        start = {
            TrialKind.TRAIN: label,  # a search's setting, or nothing
            TrialKind.STITCHED: f"from the stitch {label}",
            TrialKind.ALIGNED: f"from the aligned stitch {label}",
            TrialKind.ROBOT_MODULE: f"the stitch's robot module, a fresh task module {label}",
            TrialKind.TASK_MODULE: f"the stitch's task module, a fresh robot module {label}",
            TrialKind.UNSTITCHED: "the robot source as it is",
            TrialKind.SCRATCH: "from scratch",
        }[self.kind]
        return spec_title(self.spec.to_dict(), start)

    @property
    def row(self) -> str:
        return self.label or self.run_name

    @property
    def sources(self) -> tuple[TrainTrial, ...]:
        """The sources this trial trains: itself (a population: its members)."""
        return (self,)

    def config(self) -> dict[str, Any]:
        """The Tune config: spec and anchors, and key, label and kind where they are not the
        defaults (a source's config is ``{"spec", "anchors"}``, as it always was)."""
        config: dict[str, Any] = {"spec": self.spec.to_dict(), "anchors": self.anchors}
        if (self.key, self.label, self.kind) != ("", "", "train"):
            config.update(key=self.key, label=self.label, kind=self.kind)
        return config

    @classmethod
    def of(cls, config: Mapping[str, Any]) -> TrainTrial:
        """The record of a Tune config or a stored ``params.json`` trial (its spec upgraded:
        :meth:`TrainSpec.upgrade`)."""
        fields = {f.name for f in dataclasses.fields(cls)}
        given = {k: v for k, v in config.items() if k in fields and k != "spec"}
        return cls(spec=TrainSpec.from_mapping(TrainSpec.upgrade(config["spec"])), **given)


@dataclass(frozen=True)
class GridTrial:
    """One co-trained grid: its spec and the anchor-set file of each of its tasks (None where the
    method has no anchors), in ``grid.tasks`` order."""

    grid: GridSpec
    anchors: tuple[str | None, ...]

    @property
    def run_name(self) -> str:
        return self.grid.run_key

    @property
    def title(self) -> str:
        return self.grid.title

    def config(self) -> dict[str, Any]:
        return {"grid": self.grid.to_dict(), "anchors": list(self.anchors), "key": self.run_name}

    @classmethod
    def of(cls, config: Mapping[str, Any]) -> GridTrial:
        return cls(GridSpec.from_mapping(config["grid"]), tuple(config["anchors"]))


@dataclass(frozen=True)
class PopulationTrial:
    """Sources of the train stage trained in one learner (:class:`ps_ray.specs.population.PopulationSpec`):
    each member an ordinary source trial (its spec and anchor-set file), in member order."""

    members: tuple[TrainTrial, ...]

    @property
    def sources(self) -> tuple[TrainTrial, ...]:
        return self.members

    @property
    def population(self) -> PopulationSpec:
        return PopulationSpec(tuple(m.spec for m in self.members))

    @property
    def run_name(self) -> str:
        return self.population.run_key

    @property
    def title(self) -> str:
        """``population of 4 from panda/reach q1 · ablation · seeds 411, 412``: its MLflow run name."""
        first = self.members[0].spec
        seeds = ", ".join(map(str, sorted({m.spec.seed for m in self.members})))
        start = f"population of {len(self.members)} from {env_title(first.robot, first.task)}"
        return title(
            start,
            short_name(first.method),
            f"seed{'s' * (',' in seeds)} {seeds}",
            width_tag(first.interface_dim),
        )

    def config(self) -> dict[str, Any]:
        return {"population": [m.config() for m in self.members], "key": self.run_name}

    @classmethod
    def of(cls, config: Mapping[str, Any]) -> PopulationTrial:
        return cls(tuple(TrainTrial.of(m) for m in config["population"]))


def training_trial(config: Mapping[str, Any]) -> TrainTrial | PopulationTrial:
    """The record of a train-stage Tune config: a source's, or a population's."""
    return PopulationTrial.of(config) if "population" in config else TrainTrial.of(config)
