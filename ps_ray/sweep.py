"""`ps-ray sweep`: a SweepSpec's training trials as Ray Tune trials, resumable, tracked in MLflow.

Layout under <storage>/<name>/:
  sweep.yaml       the resolved spec (a resumed sweep must match it)
  anchors/         one anchor set per task-input width (PS), made by the driver before any trial
  tune/            Tune's experiment directory (trial checkpoints hold policy.safetensors)
  mlflow.db        the default MLflow store (sqlite), created once by the driver
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from ps_ray.config import SpecError, SweepSpec, TrainSpec

TUNE_DIR = "tune"
# Test hook for FailureConfig: a marker path; the first trial to find it absent after saving a
# checkpoint creates it and crashes.
CRASH_ENV = "PS_RAY_CRASH_ONCE"
METRIC_KEYS = ("env_steps", "updates", "train_success", "train_touching", "eval_success",
               "eval_touching")


def sweep_dir(spec: SweepSpec) -> Path:
    return Path(spec.storage).resolve() / spec.name


# -- anchors -------------------------------------------------------------------------------------
def task_input_dim(task) -> int:
    from ps_ray.envs.tasks import resolve_task

    return 3 if resolve_task(task).family.__name__ == "Reach" else 15


def prepare_sweep_anchors(spec: SweepSpec, root: Path) -> dict[int, str]:
    """One anchor set per task-input width, pooled over the source tasks of that width."""
    from ps_ray.anchors import anchors_from_file, collect_task_states, make_anchor_set, save_anchor_set
    from ps_ray.envs import make

    trials = [t for t in spec.trials() if t.method == "ps"]
    if not trials:
        return {}
    k = {t.interface_dim for t in trials}
    if len(k) != 1:
        raise SpecError("PS trials of one sweep must share one interface_dim (one anchor set each)")
    k = k.pop()
    sources = list(spec.anchors.source_tasks) or list(dict.fromkeys(
        t.task if isinstance(t.task, str) else json.dumps(t.task, sort_keys=True) for t in trials))
    paths: dict[int, str] = {}
    for dim in sorted({task_input_dim(t.task) for t in trials}):
        path = root / "anchors" / f"anchors_{dim}d_k{k}.npz"
        paths[dim] = str(path)
        if path.exists():
            continue
        if spec.anchors.file:
            anchor_set = anchors_from_file(spec.anchors.file, k, seed=spec.anchors.seed)
        else:
            group = [s for s in sources if task_input_dim(_task(s)) == dim]
            states = {s: collect_task_states(lambda s=s: make(spec.anchors.robot, _task(s)),
                                             episodes=spec.anchors.episodes,
                                             steps=spec.anchors.steps, seed=spec.anchors.seed)
                      for s in group}
            anchor_set = make_anchor_set(states, k, seed=spec.anchors.seed, extra_provenance={
                "policy": "random", "robot": spec.anchors.robot, "steps": list(spec.anchors.steps),
                "episodes": spec.anchors.episodes})
        path.parent.mkdir(parents=True, exist_ok=True)
        save_anchor_set(path, anchor_set)
    return paths


def _task(name: str):
    return json.loads(name) if name.startswith("{") else name


# -- the Tune trial ------------------------------------------------------------------------------
def sweep_trial(config: dict[str, Any]) -> None:
    """Tune function trainable: one TrainingRun, checkpointed to Tune, resumed from Tune."""
    import ray
    from ray import tune

    from ps_ray.anchors import load_anchor_set
    from ps_ray.train import TrainingRun

    trial = config["trial"]
    spec = TrainSpec.from_mapping(trial["spec"])
    anchor_set = load_anchor_set(trial["anchors"]) if trial["anchors"] else None
    run = TrainingRun(spec, anchor_set)
    checkpoint = tune.get_checkpoint()
    if checkpoint is not None:
        with checkpoint.as_directory() as directory:
            run.restore(Path(directory))
    node_id = ray.get_runtime_context().get_node_id()
    while not run.done:
        row = {**run.step(), "node_id": node_id}
        if row["iteration"] % spec.checkpoint_every == 0 or run.done:
            with tempfile.TemporaryDirectory() as directory:
                run.save(Path(directory))
                if run.done:
                    row.update({f"final_{k}": v for k, v in run.final_eval().items()})
                tune.report(row, checkpoint=tune.Checkpoint.from_directory(directory))
            _maybe_crash()
        elif row.get("eval_success") is not None:
            tune.report(row)
    run.stop()


def _maybe_crash() -> None:
    marker = os.environ.get(CRASH_ENV)
    if marker and not Path(marker).exists():
        Path(marker).write_text("crashed once")
        raise RuntimeError(f"injected crash ({CRASH_ENV}={marker})")


# -- the driver ----------------------------------------------------------------------------------
def run_sweep(spec: SweepSpec, *, resume: bool = False, progress: bool = True):
    """Run (or resume) every training trial of the sweep; returns Tune's ResultGrid."""
    import ray
    import yaml
    from ray import tune

    from ps_ray.envs.registry import register
    from ps_ray.tracking import MLflowTuneCallback, default_tracking_uri, ensure_experiment, git_commit

    root = sweep_dir(spec)
    spec_file = root / "sweep.yaml"
    resolved = yaml.safe_dump(json.loads(json.dumps(_spec_dict(spec))), sort_keys=True)
    if spec_file.exists() and spec_file.read_text() != resolved and resume:
        raise SpecError(f"{root} holds a different sweep spec; resume needs the same file")
    root.mkdir(parents=True, exist_ok=True)
    spec_file.write_text(resolved)
    anchors = prepare_sweep_anchors(spec, root)

    if not ray.is_initialized():
        ray.init(address=os.environ.get("RAY_ADDRESS", "local"), include_dashboard=False,
                 log_to_driver=False, configure_logging=False)
    register()
    tracking_uri = spec.tracking_uri or default_tracking_uri(root)
    experiment_id = ensure_experiment(tracking_uri, spec.name, root / "mlartifacts")
    callback = MLflowTuneCallback(
        tracking_uri, experiment_id, metric_keys=METRIC_KEYS + tuple(f"final_{k}" for k in (
            "success", "touching")),
        tags={"ps_ray.sweep": spec.name, "ps_ray.stage": "train", "git_commit": git_commit() or ""},
        artifacts_fn=_trial_artifacts)
    trainable = tune.with_resources(sweep_trial, {"cpu": 1})
    tune_path = root / TUNE_DIR
    if resume and tune.Tuner.can_restore(str(tune_path)):
        tuner = tune.Tuner.restore(str(tune_path), trainable=trainable, resume_unfinished=True,
                                   resume_errored=True, restart_errored=False)
    else:
        param_space = {"trial": tune.grid_search([
            {"spec": t.to_dict(), "anchors": anchors.get(task_input_dim(t.task)) if t.method == "ps"
             else None} for t in spec.trials()])}
        tuner = tune.Tuner(
            trainable, param_space=param_space,
            tune_config=tune.TuneConfig(max_concurrent_trials=spec.max_concurrent),
            run_config=tune.RunConfig(
                name=TUNE_DIR, storage_path=str(root),
                failure_config=tune.FailureConfig(max_failures=spec.max_failures),
                checkpoint_config=tune.CheckpointConfig(num_to_keep=1),
                callbacks=[callback], verbose=1 if progress else 0))
    return tuner.fit()


def _trial_artifacts(trial) -> list[Path]:
    """Module weights, interface signature, resolved spec and anchors of a finished trial."""
    paths = []
    if trial.checkpoint is not None:
        paths += [Path(trial.checkpoint.path) / name
                  for name in ("policy.safetensors", "signature.json", "spec.json")]
    anchors = trial.config["trial"].get("anchors")
    if anchors:
        paths.append(Path(anchors))
    return [p for p in paths if p.exists()]


def _spec_dict(spec: SweepSpec) -> dict[str, Any]:
    import dataclasses

    return dataclasses.asdict(spec)
