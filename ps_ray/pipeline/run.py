"""`ps-ray run`: every stage of a sweep in order, skipping finished ones, resuming a killed one.

Stages (``SweepSpec.stages``, run in the order of ``sweep_spec.STAGES``):
  train      plain sources -> anchors -> the grid's trials (ps_ray.pipeline.sweep)
  zero_shot  every stitched pair evaluated (ps_ray.pipeline.zero_shot)
  few_shot   stitched starts fine-tuned beside from-scratch runs (ps_ray.pipeline.few_shot)
  report     figures, tables, HTML and the MLflow report run (ps_ray.analysis.report)

A finished stage leaves ``<sweep>/stages/<stage>.json`` with a fingerprint of the settings its
outputs depend on (its own and those of the stages before it). A stage whose marker matches is
skipped; one that started under the same fingerprint but has no marker was interrupted and is
resumed (Tune restores its experiment); one whose settings changed starts afresh.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from ps_ray.atomic import write_text
from ps_ray.pipeline.layout import SweepLayout
from ps_ray.pipeline.sweep import layout, raise_on_errors, require_same_sweep, sweep_dir
from ps_ray.sweep_spec import STAGES, SweepSpec

# The settings each stage's outputs depend on, besides those of the earlier stages.
STAGE_SETTINGS = {"train": None, "zero_shot": "zero_shot", "few_shot": "few_shot", "report": "report"}


def fingerprint(spec: SweepSpec, stage: str) -> str:
    """Hash of what ``stage``'s outputs depend on: training settings and every stage up to it."""
    data = spec.to_dict()
    parts = {"train": spec.training_identity()}
    for name in STAGES[1 : STAGES.index(stage) + 1]:
        if name in spec.stages:
            parts[name] = data[STAGE_SETTINGS[name]]
    text = json.dumps(parts, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _marker(root: Path, stage: str, suffix: str = "") -> Path:
    return SweepLayout(root).stages / f"{stage}{suffix}.json"


def _write_json(path: Path, data: dict) -> None:
    write_text(path, json.dumps(data, indent=1, sort_keys=True))


def _read_fingerprint(path: Path) -> str | None:
    try:
        return json.loads(path.read_text()).get("fingerprint")
    except (OSError, json.JSONDecodeError, AttributeError):
        return None


def stage_wall_s(spec: SweepSpec, stage: str) -> float | None:
    """Wall seconds of a stage's last finished run, if the pipeline ran it."""
    try:
        return float(json.loads(_marker(sweep_dir(spec), stage).read_text())["wall_s"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def stage_state(spec: SweepSpec, stage: str) -> str:
    """'done' (skip), 'interrupted' (resume) or 'new' (start afresh)."""
    root, wanted = sweep_dir(spec), fingerprint(spec, stage)
    if _read_fingerprint(_marker(root, stage)) == wanted:
        return "done"
    return "interrupted" if _read_fingerprint(_marker(root, stage, ".started")) == wanted else "new"


# -- the stages -------------------------------------------------------------------------------------
def _train(spec: SweepSpec, resume: bool, progress: bool) -> str:
    from ps_ray.pipeline.sweep import run_sweep

    # the training stage always resumes: run_sweep refuses a folder trained with other settings
    grid = run_sweep(spec, resume=True, progress=progress)
    raise_on_errors(grid, "training trials")
    return f"{len(grid)} training trials"


def _zero_shot(spec: SweepSpec, resume: bool, progress: bool) -> str:
    from ps_ray.pipeline.zero_shot import run_zero_shot, summary

    if not resume:
        shutil.rmtree(layout(spec).tune_zero_shot, ignore_errors=True)
    table = run_zero_shot(spec, resume=resume, progress=progress)
    means = summary(table)["success"].to_dict()
    return f"{len(table)} stitched pairs; mean success " + ", ".join(f"{m} {v:.2f}" for m, v in means.items())


def _few_shot(spec: SweepSpec, resume: bool, progress: bool) -> str:
    from ps_ray.pipeline.few_shot import run_few_shot

    if not resume:
        shutil.rmtree(layout(spec).few_shot, ignore_errors=True)
    grid = run_few_shot(spec, resume=resume, progress=progress)
    raise_on_errors(grid, "few-shot trials")
    return f"{len(grid)} fine-tuning trials"


def _report(spec: SweepSpec, resume: bool, progress: bool) -> str:
    from ps_ray.analysis.report import build_report

    return f"report at {build_report(spec, progress=progress)}"


RUNNERS: dict[str, Callable[[SweepSpec, bool, bool], str]] = {
    "train": _train,
    "zero_shot": _zero_shot,
    "few_shot": _few_shot,
    "report": _report,
}


def run_pipeline(spec: SweepSpec, *, progress: bool = True) -> dict[str, str]:
    """Run the spec's stages in order; returns a one-line summary per stage."""
    root = sweep_dir(spec)
    require_same_sweep(spec)
    stages = [s for s in STAGES if s in spec.stages]
    summaries = {}
    for index, stage in enumerate(stages, 1):
        state = stage_state(spec, stage)
        head = f"[{index}/{len(stages)}] {stage}"
        if state == "done":
            summaries[stage] = json.loads(_marker(root, stage).read_text())["summary"]
            print(f"{head}: done earlier, skipped ({summaries[stage]})", flush=True)
            continue
        print(f"{head}: {'resuming' if state == 'interrupted' else 'starting'}", flush=True)
        started = time.time()
        _write_json(_marker(root, stage, ".started"), {"fingerprint": fingerprint(spec, stage)})
        summaries[stage] = RUNNERS[stage](spec, state == "interrupted", progress)
        wall = time.time() - started
        _write_json(
            _marker(root, stage),
            {"fingerprint": fingerprint(spec, stage), "summary": summaries[stage], "wall_s": round(wall, 1)},
        )
        print(f"{head}: done in {wall / 60:.1f} min ({summaries[stage]})", flush=True)
    return summaries
