"""Every path of a sweep folder, in one place (docs/state.md). Stages, the zoo, the report and
the cost projection ask a :class:`SweepLayout` where things are; no module spells a file name of
another's."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ps_ray.specs.stages import STAGE_RECORDS

LOG_FOLDER = "logs"  # beside a stage's Tune folder: Tune's own output, one log per stage


@dataclass(frozen=True)
class SweepLayout:
    """``<storage>/<name>/``:

    sweep.yaml        the resolved spec (a resumed sweep must match it)
    .ps_ray.lock      held by the one driver writing the folder (ps_ray/store/lock.py)
    mlflow.db, mlartifacts/   the default MLflow store and its artifacts
    tune_plain/       plain source policies of the anchors (anchors.policy: plain)
    anchors/          one anchor set per (task-input width, k)
    tune/             every training trial (checkpoints hold policy.safetensors)
    tune_zero_shot/, zero_shot.csv      the zero-shot matrix
    few_shot/         tune_few_shot/ (fine-tuning and scratch runs), stitched/ (their starts)
    report/           the report (index.html, figures/, tables/, clips/)
    stages/           the pipeline's stage markers
    logs/             Tune's own output per stage (few_shot/logs/ for the few-shot stage)
    """

    root: Path

    @classmethod
    def of(cls, storage: str | Path, name: str) -> SweepLayout:
        return cls(Path(storage).resolve() / name)

    @property
    def spec_file(self) -> Path:
        return self.root / "sweep.yaml"

    @property
    def mlflow_db(self) -> Path:
        return self.root / "mlflow.db"

    @property
    def artifacts(self) -> Path:
        return self.root / "mlartifacts"

    @property
    def anchors(self) -> Path:
        return self.root / "anchors"

    def anchor_set(self, task_input_dim: int, k: int) -> Path:
        return self.anchors / f"anchors_{task_input_dim}d_k{k}.npz"

    @property
    def tune_plain(self) -> Path:
        return self.stage_folders()["anchors_plain"]

    @property
    def tune_train(self) -> Path:
        return self.stage_folders()["train"]

    @property
    def tune_grid(self) -> Path:
        return self.stage_folders()["grid"]

    @property
    def tune_zero_shot(self) -> Path:
        return self.stage_folders()["zero_shot"]

    @property
    def zero_shot_table(self) -> Path:
        return self.root / "zero_shot.csv"

    @property
    def outcomes(self) -> Path:
        """Outcome rollouts of the sources, for translations fitted on matched pairs
        (ps_ray.stitching.outcomes): one .npz per source, env and scene count."""
        return self.root / "outcomes"

    @property
    def chance(self) -> Path:
        """The zero-shot stage's chance levels and task-blind floors, one JSON file per target env
        and episodes (ps_ray.pipeline.chance_levels): measured once, read on resume."""
        return self.root / "chance"

    @property
    def few_shot(self) -> Path:
        return self.root / "few_shot"

    @property
    def tune_few_shot(self) -> Path:
        return self.stage_folders()["few_shot"]

    @property
    def stitched(self) -> Path:
        return self.few_shot / "stitched"

    @property
    def report(self) -> Path:
        return self.root / "report"

    @property
    def stages(self) -> Path:
        return self.root / "stages"

    def stage_folders(self) -> dict[str, Path]:
        """Each Tune experiment's folder, by the name its trials are tagged and costed under
        (:data:`ps_ray.specs.stages.STAGE_RECORDS`)."""
        return {label: self.root / folder for s in STAGE_RECORDS for label, folder in s.tune_folders.items()}


def sweep_layout(spec) -> SweepLayout:
    """The folder of a sweep spec (anything with ``storage`` and ``name``) and every path in it:
    the one way to name a sweep's folder."""
    return SweepLayout.of(spec.storage, spec.name)
