"""`ps-ray run`: every stage of a sweep in order, skipping finished ones, resuming a killed one.

Stages (``SweepSpec.stages``, run in the order of ``specs.stages.STAGES``):
  train      plain sources -> anchors -> the sweep's sources (ps_ray.pipeline.sweep)
  grid       co-trained robot x task grids, a held-out cell each (ps_ray.pipeline.grid)
  zero_shot  every stitched pair evaluated (ps_ray.pipeline.zero_shot)
  few_shot   stitched starts fine-tuned beside from-scratch runs (ps_ray.pipeline.few_shot)
  report     figures, tables, HTML and the MLflow report run (ps_ray.analysis.report)

A finished stage leaves ``<sweep>/stages/<stage>.json`` with a fingerprint of the settings its
outputs depend on (its own and those of the stages before it). A stage whose marker matches is
skipped; one that started under the same fingerprint but has no marker was interrupted and is
resumed (Tune restores its experiment); one whose settings changed starts afresh.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable

from ps_ray.pipeline.stage import raise_on_errors, require_same_sweep
from ps_ray.specs.stages import STAGES
from ps_ray.specs.sweep import SweepSpec
from ps_ray.store.layout import sweep_layout
from ps_ray.store.stages import finished_summary, mark_finished, mark_started, stage_state


# -- the stages -------------------------------------------------------------------------------------
def _train(spec: SweepSpec, resume: bool, progress: bool) -> str:
    from ps_ray.pipeline.sweep import run_sweep

    # the training stage always resumes: run_sweep refuses a folder trained with other settings
    results = run_sweep(spec, resume=True, progress=progress)
    raise_on_errors(results, "training trials")
    return f"{len(results)} training trials"


def _grid(spec: SweepSpec, resume: bool, progress: bool) -> str:
    from ps_ray.pipeline.grid import run_grids

    grids = run_grids(spec, resume=True, progress=progress)  # as training: finished grids are kept
    raise_on_errors(grids, "grid trials")
    return f"{len(grids)} co-trained grids"


def _zero_shot(spec: SweepSpec, resume: bool, progress: bool) -> str:
    from ps_ray.pipeline.zero_shot import run_zero_shot
    from ps_ray.pipeline.zero_shot_table import summary

    if not resume:
        shutil.rmtree(sweep_layout(spec).tune_zero_shot, ignore_errors=True)
    table = run_zero_shot(spec, resume=resume, progress=progress)
    means = summary(table)["success"].to_dict()
    return f"{len(table)} stitched pairs; mean success " + ", ".join(f"{m} {v:.2f}" for m, v in means.items())


def _few_shot(spec: SweepSpec, resume: bool, progress: bool) -> str:
    from ps_ray.pipeline.few_shot import run_few_shot

    if not resume:
        shutil.rmtree(sweep_layout(spec).few_shot, ignore_errors=True)
    results = run_few_shot(spec, resume=resume, progress=progress)
    raise_on_errors(results, "few-shot trials")
    return f"{len(results)} fine-tuning trials"


def _report(spec: SweepSpec, resume: bool, progress: bool) -> str:
    from ps_ray.analysis.report import build_report

    return f"report at {build_report(spec, progress=progress)}"


RUNNERS: dict[str, Callable[[SweepSpec, bool, bool], str]] = {
    "train": _train,
    "grid": _grid,
    "zero_shot": _zero_shot,
    "few_shot": _few_shot,
    "report": _report,
}


def run_pipeline(spec: SweepSpec, *, progress: bool = True) -> dict[str, str]:
    """Run the spec's stages in order; returns a one-line summary per stage."""
    require_same_sweep(spec)
    stages = [s for s in STAGES if s in spec.stages]
    summaries = {}
    for index, stage in enumerate(stages, 1):
        state = stage_state(spec, stage)
        head = f"[{index}/{len(stages)}] {stage}"
        if state == "done":
            summaries[stage] = finished_summary(spec, stage)
            print(f"{head}: done earlier, skipped ({summaries[stage]})", flush=True)
            continue
        print(f"{head}: {'resuming' if state == 'interrupted' else 'starting'}", flush=True)
        started = time.time()
        mark_started(spec, stage)
        summaries[stage] = RUNNERS[stage](spec, state == "interrupted", progress)
        wall = time.time() - started
        mark_finished(spec, stage, summaries[stage], wall)
        print(f"{head}: done in {wall / 60:.1f} min ({summaries[stage]})", flush=True)
    return summaries
