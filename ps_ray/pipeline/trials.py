"""The one Tune runner of every stage: a grid of trials as one Tune experiment, resumed from what
the stage folder's plain JSON says (:mod:`ps_ray.store.attempts`), never from Tune's pickles."""

from __future__ import annotations

import contextlib
from pathlib import Path

from ps_ray.specs.resources import StageResources
from ps_ray.store.attempts import STAGE_DIR_KEY, TrialOutcome, identity, outcomes, require_fresh
from ps_ray.store.layout import LOG_FOLDER

ONE_CPU = StageResources()


def run_trials(
    trainable,
    grid: dict[str, list],
    *,
    folder: Path,
    stage: str,
    callback,
    resume: bool,
    progress: bool,
    max_concurrent: int | None,
    max_failures: int,
    resources: StageResources = ONE_CPU,
    constants: dict | None = None,
) -> list[TrialOutcome]:
    """Run a grid over ``grid``'s one key (plus ``constants``) as the Tune experiment in
    ``folder``: ``resources`` per trial (one CPU by default), the sweep's retry policy, the MLflow
    ``callback``, a compact live view on the terminal and Tune's own output in
    ``<folder's parent>/logs/<folder name>.log``
    (:mod:`ps_ray.pipeline.progress`). ``resume`` keeps the trials that finished earlier and runs the rest."""
    from ray import tune

    from ps_ray.pipeline.progress import StageProgress, quiet_tune, verbose

    ((key, trials),) = grid.items()
    path, name, root = Path(folder), Path(folder).name, Path(folder).parent
    if not resume:
        require_fresh(path, key, stage)
    todo = [o.config[key] for o in outcomes(path, key, trials) if o.error] if resume else trials
    errors: dict[str, str] = {}
    if todo:
        quiet = progress and not verbose()
        tuner = tune.Tuner(
            tune.with_resources(trainable, resources.tune_request()),
            param_space={key: tune.grid_search(todo), **(constants or {}), STAGE_DIR_KEY: str(path)},
            tune_config=tune.TuneConfig(max_concurrent_trials=max_concurrent),
            run_config=tune.RunConfig(
                name=name,
                storage_path=str(root),
                failure_config=tune.FailureConfig(max_failures=max_failures),
                checkpoint_config=tune.CheckpointConfig(num_to_keep=1),
                callbacks=[callback, *([StageProgress(stage, len(todo))] if quiet else [])],
                verbose=1 if progress else 0,
            ),
        )
        with quiet_tune(root / LOG_FOLDER / f"{name}.log") if quiet else contextlib.nullcontext():
            grid_results = tuner.fit()  # quiet: Tune's tables go to the log
        errors = {identity(r.config[key]): str(r.error) for r in grid_results if r.error}
    return outcomes(path, key, trials, errors)
