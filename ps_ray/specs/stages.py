"""The pipeline's stages, each described once. Every list that names stages derives from
:data:`STAGE_RECORDS`: the order ``ps-ray run`` follows (``STAGES``), the sweep keys that hold a
stage's settings and whether they change training (``specs.sweep``), which stages ask Ray for
per-trial resources (``specs.resources``), the settings a stage marker fingerprints
(``store.stages``) and each stage's Tune folders (``store.layout``). The runners live in
``pipeline.run``; tests/test_stages.py checks that each stage has one and that each registry
above matches this table (docs/reference.md, "Adding a stage")."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Stage:
    name: str
    # the sweep key of its settings; None: the sweep's own training keys (methods, train, ...)
    settings: str | None = None
    # its Tune experiments: the name its trials are tagged and costed under -> folder under the
    # sweep folder; none: it runs no Tune trials (and has no per-trial resources)
    tune_folders: Mapping[str, str] = field(default_factory=dict)
    # whether its settings change what the training stage produces (a resumed sweep keeps them)
    changes_training: bool = False
    # whether its trials take gradient updates (a GPU helps them) or only evaluate (zero-shot)
    trains: bool = True

    @property
    def runs_trials(self) -> bool:
        return bool(self.tune_folders)


STAGE_RECORDS = (
    Stage("train", None, {"anchors_plain": "tune_plain", "train": "tune"}, changes_training=True),
    # co-trained grids (ps_ray.pipeline.grid): more sources, beside the train stage's, not instead
    Stage("grid", "grid", {"grid": "tune_grid"}),
    Stage("zero_shot", "zero_shot", {"zero_shot": "tune_zero_shot"}, trains=False),
    Stage("few_shot", "few_shot", {"few_shot": "few_shot/tune_few_shot"}),
    Stage("report", "report", trains=False),
)
STAGES = tuple(s.name for s in STAGE_RECORDS)  # in the order they run
STAGES_WITH_TRIALS = tuple(s.name for s in STAGE_RECORDS if s.runs_trials)
# sweep keys that do not change what training produces: the stage list, the later stages'
# settings and how trials run
NOT_TRAINING = (
    "stages",
    *(s.settings for s in STAGE_RECORDS if s.settings and not s.changes_training),
    "resources",
    "max_concurrent",
    "max_failures",
    "description",
    "log_models",
)


def stage(name: str) -> Stage:
    """The record of a stage, or of the stage a Tune experiment belongs to (``anchors_plain``:
    ``train``)."""
    for record in STAGE_RECORDS:
        if name == record.name or name in record.tune_folders:
            return record
    raise KeyError(f"no stage {name!r}; stages: {', '.join(STAGES)}")


def earlier_and(name: str) -> tuple[Stage, ...]:
    """The stages up to and including ``name``, in order."""
    return STAGE_RECORDS[: STAGES.index(name) + 1]
