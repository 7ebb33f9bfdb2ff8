"""The grid stage: each co-trained grid of a sweep (:class:`ps_ray.specs.grid.GridSettings`) as
one Tune trial, resumable and tracked in MLflow like a training trial. Each checkpoint holds every
trained cell's policy file and spec, so the zoo (:mod:`ps_ray.stitching.zoo`) offers the cells as
sources of their grid, and the zero-shot stage stitches each held-out cell from them beside its
controls (docs/transfer.md "Co-trained grids")."""

from __future__ import annotations

from typing import Any

from ps_ray.pipeline.anchor_sets import prepare_sweep_anchors
from ps_ray.pipeline.stage import connect, record_spec, require_same_sweep
from ps_ray.pipeline.training_trials import report_ticks, run_tune
from ps_ray.plan import grid as grid_plan
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.trial import GridTrial
from ps_ray.store.layout import sweep_layout


def grid_trial(config: dict[str, Any]) -> None:
    """Tune function trainable: one :class:`ps_ray.rllib.grid_train.GridRun`."""
    import ray

    from ps_ray.data.anchor_file import load_anchor_set
    from ps_ray.rllib.grid_train import GridRun

    trial = GridTrial.of(config["trial"])
    anchor_sets = [None if path is None else load_anchor_set(path) for path in trial.anchors]
    granted = ray.get_runtime_context().get_assigned_resources()
    report_ticks(
        GridRun(trial.grid, anchor_sets, threads=max(1, int(granted.get("CPU", 1)))), config, "trial"
    )


def run_grids(spec: SweepSpec, *, resume: bool = False, progress: bool = True):
    """Train (or resume) the sweep's grids; the train stage's anchor sets serve PS grids."""
    from ps_ray.envs.registry import register

    require_same_sweep(spec)
    record_spec(spec)  # a grid-only sweep is a trained sweep to zero-shot, few-shot and report
    register()
    # a sweep that co-trains without training alone makes its anchor sets here (policy random or
    # a file; policy plain needs the train stage, as the spec says); made ones are kept
    prepare_sweep_anchors(spec)
    return run_tune(
        grid_plan.plan(spec),
        folder=sweep_layout(spec).tune_grid,
        stage="grid",
        spec=spec,
        tracking=connect(spec),
        resume=resume,
        progress=progress,
        trainable=grid_trial,
        key_fn=lambda trial: GridTrial.of(trial.config["trial"]).run_name,
        name_fn=lambda trial: GridTrial.of(trial.config["trial"]).title,
        params_fn=lambda trial: _params(GridTrial.of(trial.config["trial"])),
        artifacts_fn=lambda trial: [],
    )


def _params(trial: GridTrial) -> dict[str, str]:
    from ps_ray.store.mlflow_values import flatten_params

    return {**flatten_params(trial.grid.base.to_dict()), "held_out": trial.grid.held_out_text}
