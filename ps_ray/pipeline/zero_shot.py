"""`ps-ray zero-shot`: the stitching matrix of a sweep, evaluated as Tune trials, into MLflow.

Every valid (task module, robot module) pair of each method and seed (see `stitch.combos`) is one
trial: stitch, then evaluate on fixed seeds (episodes x repeats), so that every method is scored
on identical episodes. The table goes to <sweep>/zero_shot.csv and to MLflow (stage zero_shot).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ps_ray.atomic import atomic_path
from ps_ray.errors import UserError
from ps_ray.names import short_name
from ps_ray.pipeline.sweep import layout, raise_on_errors, sweep_dir
from ps_ray.sweep_spec import SweepSpec

RESULT_KEYS = (
    "success_mean",
    "success_std",
    "touching_mean",
    "touching_std",
    "contact_mean",
    "episodes_per_s",
)


def pairs(spec: SweepSpec, methods: list[str] | None = None, translate: bool = False) -> list[dict[str, Any]]:
    """One trial config per stitched pair of the sweep's trained policies; with ``translate``,
    also one per latent translation that ``spec.zero_shot.translate`` names for the method
    (its method shown as ``<method>+<translation>``)."""
    from ps_ray.stitch import combos
    from ps_ray.zoo import ModuleZoo

    zoo = ModuleZoo.from_sweep(sweep_dir(spec))
    out = []
    for method in methods or spec.methods:
        kinds = ("", *spec.zero_shot.translations(method)) if translate else ("",)
        for seed in spec.seeds:
            for combo in combos(zoo, method, seed):
                for kind in kinds:
                    out.append(
                        {
                            "method": f"{method}+{kind}" if kind else method,
                            "translation": kind,
                            "seed": seed,
                            "label": combo.label,
                            "task_from": str(combo.task_from.key),
                            "robot_from": str(combo.robot_from.key),
                            "task_from_path": str(combo.task_from.path),
                            "robot_from_path": str(combo.robot_from.path),
                            "fit_tasks": [combo.task_from.spec["task"], combo.robot_from.spec["task"]],
                            "robot": combo.robot,
                            "task": combo.task,
                        }
                    )
    return out


def fit_states(tasks: list, per_quadrant: int, seed: int) -> np.ndarray:
    """Task inputs for fitting a latent translation: env resets of every given task (the target
    task and the robot source's task, so both task modules see familiar states), per goal
    quadrant. Resets only: no env steps are taken."""
    from ps_ray.analysis.latent import probe_states

    return np.concatenate([probe_states(task, per_quadrant, seed).states for task in tasks])


def zero_shot_trial(config: dict[str, Any]) -> None:
    """Tune function trainable: stitch one pair (translated, if the pair says so) and evaluate it."""
    from ray import tune

    from ps_ray.evaluate import evaluate
    from ps_ray.pipeline.trials import FINISHED
    from ps_ray.stitch import stitch_policies

    pair, settings = config["pair"], config["eval"]
    translation = pair.get("translation") or None
    states = (
        fit_states(pair["fit_tasks"], config["fit_states_per_quadrant"], settings["seed"])
        if translation
        else None
    )
    stitched = stitch_policies(
        pair["task_from_path"], pair["robot_from_path"], translation=translation, fit_states=states
    )
    result = evaluate(stitched, pair["robot"], pair["task"], **settings)
    tune.report({**{k: result[k] for k in RESULT_KEYS}, FINISHED: True})


def run_zero_shot(
    spec: SweepSpec, *, resume: bool = False, progress: bool = True, **overrides: Any
) -> pd.DataFrame:
    """The matrix as Tune trials, settings from ``spec.zero_shot`` (``overrides`` replace fields).

    ``resume`` finishes an interrupted matrix (restores ``tune_zero_shot``)."""
    from ps_ray.pipeline.sweep import connect
    from ps_ray.pipeline.tracking import git_commit, source_tags
    from ps_ray.pipeline.trials import require_fresh, run_trials
    from ps_ray.pipeline.tune_tracking import MLflowTuneCallback

    settings = dataclasses.replace(spec.zero_shot, **overrides)
    root = sweep_dir(spec)
    if not resume:
        require_fresh(layout(spec).tune_zero_shot, "pair", "zero_shot")
    trials = pairs(spec, list(settings.methods) or None, translate=True)
    if not trials:
        raise UserError(f"{root}: no stitchable pairs (train the sweep first: ps-ray sweep)")
    tracking_uri, experiment_id = connect(spec)
    callback = MLflowTuneCallback(
        tracking_uri,
        experiment_id,
        metric_keys=RESULT_KEYS,
        key_fn=lambda trial: (
            f"zero_shot/{trial.config['pair']['method']}/"
            f"{trial.config['pair']['label']}/{trial.config['pair']['seed']}"
        ),
        params_fn=lambda trial: (
            {
                k: short_name(v)
                for k, v in trial.config["pair"].items()
                if not k.endswith("_path") and k != "fit_tasks"
            }
            | {"episodes": settings.episodes, "repeats": settings.repeats}
        ),
        tags={"ps_ray.sweep": spec.name, "ps_ray.stage": "zero_shot", "git_commit": git_commit() or ""},
        tags_fn=lambda trial, client: source_tags(
            client,
            experiment_id,
            trial.config["pair"]["task_from"],
            trial.config["pair"]["robot_from"],
            trial.config["pair"]["task_from_path"],
        ),
    )
    results = run_trials(
        zero_shot_trial,
        {"pair": trials},
        folder=layout(spec).tune_zero_shot,
        stage="zero_shot",
        callback=callback,
        resume=resume,
        progress=progress,
        max_concurrent=spec.max_concurrent,
        max_failures=spec.max_failures,
        constants={
            "eval": {"episodes": settings.episodes, "repeats": settings.repeats, "seed": settings.seed},
            "fit_states_per_quadrant": settings.fit_states_per_quadrant,
        },
    )
    raise_on_errors(results, "zero-shot trials")
    rows = [
        {
            **{
                k: short_name(v)
                for k, v in r.config["pair"].items()
                if not k.endswith("_path") and k != "fit_tasks"
            },
            **{k: r.metrics.get(k) for k in RESULT_KEYS},
        }
        for r in results
    ]
    table = pd.DataFrame(rows).sort_values(["method", "seed", "label"]).reset_index(drop=True)
    write_atomic_csv(table, layout(spec).zero_shot_table)
    return table


def summary(table: pd.DataFrame) -> pd.DataFrame:
    """Mean over pairs per method (and the number of pairs), for the note and the report."""
    grouped = table.groupby("method")
    return pd.DataFrame(
        {
            "pairs": grouped.size(),
            "success": grouped["success_mean"].mean(),
            "touching": grouped["touching_mean"].mean(),
        }
    )


def write_atomic_csv(table: pd.DataFrame, path: Path) -> None:
    """Write beside, then rename: a reader never sees half a table."""
    with atomic_path(path) as partial:
        table.to_csv(partial, index=False)
