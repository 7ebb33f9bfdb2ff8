"""`ps-ray sweep`: the train stage, a SweepSpec's training trials as Ray Tune trials, resumable,
tracked in MLflow.

First the plain source policies of the anchors (anchors.policy: plain), then the anchor sets
(made by the driver: :mod:`ps_ray.pipeline.anchor_sets`), then every training trial of the sweep
(:mod:`ps_ray.pipeline.training_trials`). Where each goes: :class:`ps_ray.store.layout.SweepLayout`.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

from ps_ray.pipeline.anchor_sets import missing_anchor_sets, prepare_sweep_anchors
from ps_ray.pipeline.stage import connect, raise_on_errors, record_spec, require_same_sweep
from ps_ray.pipeline.training_trials import record_of, run_tune
from ps_ray.plan import train as train_plan
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.titles import ANCHOR_POLICY, title
from ps_ray.specs.trial import TrainTrial
from ps_ray.store.layout import sweep_layout


def check_inputs(spec: SweepSpec) -> None:
    """The files a sweep starts from, read before Ray starts and anything is written: the anchor
    file must exist, and every trial's ``init_policy`` must fit its method, sizes and env."""
    from ps_ray.errors import UserError

    if spec.anchors.file and not Path(spec.anchors.file).is_file():
        raise UserError(f"anchors.file: {spec.anchors.file}: no such file")
    starts = {  # one check per distinct (policy file, what it must fit)
        (t.init_policy, t.method, t.interface_dim, t.hidden, t.robot, t.task): t
        for t in spec.trials()
        if t.init_policy is not None
    }
    if starts:  # each start's signature, read without building its nets (the trial loads them)
        from ps_ray.stitching.rule import start_problems
        from ps_ray.store.signature import read_signature

        for trial in starts.values():
            problems = start_problems(trial, read_signature(trial.init_policy)[0])
            if problems:
                raise UserError(f"{trial.init_policy}: cannot start this run: " + "; ".join(problems))


def run_sweep(spec: SweepSpec, *, resume: bool = False, progress: bool = True):
    """Run (or resume) the train stage; returns its Tune ResultGrid.

    The anchors' plain source policies (anchors.policy: plain) as Tune trials, then the anchor
    sets, made by the driver, then every training trial as Tune trials. A step whose outputs exist
    is skipped, so a killed sweep resumes where it stopped.
    """
    from ps_ray.envs.registry import register
    from ps_ray.store.attempts import require_fresh

    layout = sweep_layout(spec)
    require_same_sweep(spec)
    if not resume:  # refused before Ray starts and anything is written
        require_fresh(layout.tune_plain, "trial", "anchors_plain")
        require_fresh(layout.tune_train, "trial", "train")
    check_inputs(spec)
    record_spec(spec)
    register()
    tune_args = dict(spec=spec, tracking=connect(spec), resume=resume, progress=progress)

    plain_policies = None
    if missing_anchor_sets(spec) and (sources := train_plan.plain_sources(spec)):
        results = run_tune(
            sources,
            folder=layout.tune_plain,
            stage="anchors_plain",
            # its own runs: the same plain spec may also be a trial of the sweep
            key_fn=lambda trial: "anchors_plain/" + record_of(trial).run_name,
            name_fn=lambda trial: title(record_of(trial).title, ANCHOR_POLICY),
            **tune_args,
        )
        raise_on_errors(results, "plain source policies")
        plain_policies = {
            TrainTrial.of(r.config["trial"]).spec.label(): r.checkpoint / "policy.safetensors"
            for r in results
        }
    prepare_sweep_anchors(spec, plain_policies)
    trials = train_plan.plan(spec)
    folder = layout.tune_train
    scheduler_fn = None
    if spec.search.active:
        from ps_ray.pipeline.search import search_scheduler

        configs = [t.config() for t in trials]
        max_steps = max(t.env_steps for t in spec.trials())
        scheduler_fn = partial(search_scheduler, spec.search, max_steps, folder, configs)
    return run_tune(
        trials,
        folder=folder,
        stage="train",
        scheduler_fn=scheduler_fn,
        **tune_args,
    )
