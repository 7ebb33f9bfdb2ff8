"""Training trials as Tune trials, shared by every stage that trains (train, grid, few-shot): the
trial function around a :class:`ps_ray.rllib.loop.TrainingRun` (:func:`sweep_trial`, and
:func:`report_ticks` for a grid's run), and the runner that launches a stage's trials, tracked
in MLflow under the stage's run (:func:`run_tune`)."""

from __future__ import annotations

import tempfile
from functools import partial
from pathlib import Path
from typing import Any

from ps_ray.specs.population import shared_settings
from ps_ray.specs.stages import stage as stage_record
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.trial import GridTrial, PopulationTrial, TrainTrial, training_trial
from ps_ray.store.layout import sweep_layout
from ps_ray.store.mlflow_values import flatten_params
from ps_ray.store.run_layout import (
    METRIC_FIELDS,
    POLICY_FILE,
    SIGNATURE_FILE,
    SPEC_FILE,
    cell_policy_file,
    cell_result_file,
    cell_spec_file,
)

# What each training result sends to MLflow: the metrics.csv columns but the step and the clock.
METRIC_KEYS = tuple(k for k in METRIC_FIELDS if k not in ("iteration", "wall_s")) + ("alpha", "entropy")


SCHEDULED_METRICS = {"eval_success": None, "best_eval_success": None}


def sweep_trial(config: dict[str, Any]) -> None:
    """Tune function trainable: one TrainingRun, checkpointed to Tune. It continues from Tune's
    checkpoint after a retry, else from the furthest checkpoint an earlier attempt of the same
    trial left (a resumed stage, :mod:`ps_ray.pipeline.trials`); its last result carries ``FINISHED``."""
    import ray

    from ps_ray.data.anchor_file import load_anchor_set
    from ps_ray.nets.policy_file import policy_anchor_set
    from ps_ray.rllib.loop import TrainingRun
    from ps_ray.store.attempts import replay_store

    if "population" in config["trial"]:
        return population_trial(config)
    trial = TrainTrial.of(config["trial"])
    spec = trial.spec
    if trial.anchors:
        anchor_set = load_anchor_set(trial.anchors)
    elif spec.init_policy is not None and spec.resolved.uses_anchors:  # anchors inside the policy file
        anchor_set = policy_anchor_set(spec.init_policy)
    else:
        anchor_set = None
    granted = ray.get_runtime_context().get_assigned_resources()  # what spec.resources asked for
    run = TrainingRun(
        spec,
        anchor_set,
        threads=max(1, int(granted.get("CPU", 1))),
        gpu=granted.get("GPU", 0),
        compile=config.get("compile", False),
        replay_store=replay_store(config, "trial"),
    )
    report_ticks(run, config, "trial")


def population_trial(config: dict[str, Any]) -> None:
    """One :class:`ps_ray.rllib.population_train.PopulationRun`: the trial's sources in one learner."""
    import ray

    from ps_ray.data.anchor_file import load_anchor_set
    from ps_ray.rllib.population_train import PopulationRun

    trial = PopulationTrial.of(config["trial"])
    anchor_sets = [None if m.anchors is None else load_anchor_set(m.anchors) for m in trial.members]
    granted = ray.get_runtime_context().get_assigned_resources()
    threads = max(1, int(granted.get("CPU", 1)))
    run = PopulationRun(trial.population, anchor_sets, threads=threads, gpu=granted.get("GPU", 0))
    report_ticks(run, config, "trial")


def report_ticks(run, config: dict[str, Any], key: str) -> None:
    """A Tune trial's loop over a :class:`TrainingRun` (a grid's too): restore from Tune's
    checkpoint after a retry, else from the furthest checkpoint an earlier attempt of the same
    trial (``config[key]``) left; report each evaluation, and checkpoints with their step; the
    last result carries the final evaluation and ``FINISHED``."""
    import ray
    from ray import tune

    from ps_ray.store.attempts import FINISHED, START_STEPS, earlier_checkpoint

    checkpoint = tune.get_checkpoint()
    if checkpoint is not None:
        with checkpoint.as_directory() as directory:
            run.restore(Path(directory))
    elif (earlier := earlier_checkpoint(config, key)) is not None:
        run.restore(earlier)
    node_id = ray.get_runtime_context().get_node_id()
    for tick in run.ticks():  # the loop of `ps-ray train` too: it decides steps and checkpoints
        if tick.finished is None and run.done:
            continue  # the last step: reported once, by the last tick, with the checkpoint
        # every row names the metrics a search's scheduler reads (None between evaluations)
        row = {**SCHEDULED_METRICS, **tick.row, **(tick.finished or {}), "node_id": node_id}
        row[START_STEPS] = run.start_steps  # the live view's ETA counts only this attempt's steps
        if tick.checkpoint:
            with tempfile.TemporaryDirectory() as directory:
                run.save(Path(directory))
                if tick.finished is not None:
                    final = {f"final_{k}": v for k, v in run.final_eval().items()}
                    row.update(final, converged=run.converged, **{FINISHED: True})
                tune.report(row, checkpoint=tune.Checkpoint.from_directory(directory))
        elif row.get("eval_success") is not None:
            tune.report(row)
    run.stop()


def run_tune(
    trials: list[TrainTrial] | list[GridTrial] | list[PopulationTrial],
    *,
    folder: Path,
    stage: str,
    spec: SweepSpec,
    tracking: tuple[str, str],
    resume: bool,
    progress: bool,
    key_fn=None,
    name_fn=None,
    tags_fn=None,
    trainable=None,
    params_fn=None,
    artifacts_fn=None,
    scheduler_fn=None,
):
    """Training trials (sweep_trial; a grid's: ``trainable`` grid_trial) as one Tune experiment in
    ``folder``, tracked in MLflow, each trial's record as its ``config["trial"]``;
    ``scheduler_fn``: :func:`ps_ray.pipeline.trials.run_trials`'."""

    from ps_ray.pipeline.trials import run_trials, stage_summary
    from ps_ray.pipeline.tune_tracking import MLflowTuneCallback
    from ps_ray.specs.resources import device_tags
    from ps_ray.store.mlflow_values import relative_paths
    from ps_ray.store.stage_run import open_stage

    resources, root = getattr(spec.resources, stage_record(stage).name), sweep_layout(spec).root
    with open_stage(*tracking, spec.name, stage) as stage_run:  # open while the stage runs
        callback = MLflowTuneCallback(
            *tracking,
            metric_keys=METRIC_KEYS + ("final_success", "final_touching"),
            tags={**stage_run.tags, **device_tags(resources)},
            artifacts_fn=artifacts_fn or _trial_artifacts,
            model_fn=_trial_model if spec.log_models and stage == "train" else None,
            key_fn=key_fn or (lambda trial: record_of(trial).run_name),  # a search's: one per setting
            name_fn=name_fn or (lambda trial: record_of(trial).title),
            params_fn=lambda trial: relative_paths((params_fn or _spec_params)(trial), root),
            tags_fn=tags_fn,
            # env steps, the x axis RL curves are read on (restored with a checkpoint, like ps_ray's
            # own iteration; Tune's restarts at 1 when a resumed stage relaunches a trial): a retried
            # or relaunched trial re-reports the steps between its checkpoint and the kill, and the
            # run keeps their first record
            step_key="env_steps",
            once_per_step=True,
            # a population's members: a run each, under the trial's, each policy a model as a source's
            members_fn=partial(_member_runs, models=spec.log_models and stage == "train"),
        )
        results = run_trials(
            trainable or sweep_trial,
            {"trial": [t.config() for t in trials]},
            folder=folder,
            stage=stage,
            callback=callback,
            resume=resume,
            progress=progress,
            max_concurrent=spec.max_concurrent,
            max_failures=spec.max_failures,
            resources=resources,
            constants={"compile": resources.compile},  # how to run, not what: not the trial's identity
            scheduler_fn=scheduler_fn,
            budgets=[env_step_budget(t) for t in trials],
        )
        stage_run.record(*stage_summary(results))
    return results


def _member_runs(trial, *, models: bool = False) -> list:
    """A population trial's members as MLflow runs of their own (each an ordinary source's: its
    trial key, title and spec, and with ``models`` its policy as a logged model); none for any
    other trial."""
    from ps_ray.pipeline.tune_tracking import MemberRun

    if "population" not in trial.config["trial"]:
        return []
    record = PopulationTrial.of(trial.config["trial"])
    return [
        MemberRun(
            key=m.run_name,
            name=m.title,
            params=flatten_params(m.spec.to_dict()),
            prefix=f"c{i:02d}_",
            files=(cell_policy_file(i), cell_spec_file(i), cell_result_file(i)),
            model=(m.spec.robot, m.spec.task) if models and m.spec.env is None else None,
        )
        for i, m in enumerate(record.members)
    ]


def env_step_budget(trial: TrainTrial | GridTrial | PopulationTrial) -> int:
    """The env steps the live view counts a trial's results against: a source's budget (a
    population's: each member's, run together; a grid's: each cell's, its cells stepped in
    lockstep and its results' ``env_steps`` one cell's)."""
    if isinstance(trial, GridTrial):
        return trial.grid.base.env_steps
    return trial.sources[0].spec.env_steps


def record_of(trial) -> TrainTrial | PopulationTrial:
    """A training stage's Tune trial as its record (its config is ``{"trial": record.config()}``)."""
    return training_trial(trial.config["trial"])


def _spec_params(trial) -> dict[str, str]:
    """A training trial's MLflow params: its spec's fields as the config holds them (nested
    robot/task as ``robot.x``); a population's: the settings its members share, and their keys."""
    record = record_of(trial)
    if isinstance(record, PopulationTrial):
        shared = flatten_params(shared_settings(record.members[0].spec))
        return {**shared, "members": ", ".join(m.run_name for m in record.members)}
    return flatten_params(trial.config["trial"]["spec"])


def _trial_model(trial) -> tuple[Path, Any, Any, str] | None:
    """A finished source's policy file, env and title, to log as its run's MLflow model."""
    record = record_of(trial)
    if isinstance(record, PopulationTrial):
        return None  # its members' policy files are in its checkpoint (not yet logged as models)
    policy = Path(trial.checkpoint.path) / POLICY_FILE if trial.checkpoint is not None else None
    # a run of a gymnasium env given by id has no robot and task to log its model with
    found = policy is not None and policy.exists() and record.spec.env is None
    return (policy, record.spec.robot, record.spec.task, record.title) if found else None


def _trial_artifacts(trial) -> list[Path]:
    """Module weights, interface signature, resolved spec and anchors of a finished trial."""
    record = record_of(trial)
    if isinstance(record, PopulationTrial):
        return []  # its members' files are in its checkpoint
    paths = []
    if trial.checkpoint is not None:
        paths += [Path(trial.checkpoint.path) / name for name in (POLICY_FILE, SIGNATURE_FILE, SPEC_FILE)]
    anchors = record.anchors
    if anchors:
        paths.append(Path(anchors))
    return [p for p in paths if p.exists()]
