"""The one Tune runner of every stage: a grid of trials as one Tune experiment, resumed from what
the stage folder's plain JSON says (:mod:`ps_ray.store.attempts`), never from Tune's pickles."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

from ps_ray.pipeline.heap import releasing
from ps_ray.pipeline.preemption import PREEMPTION_RETRIES, failures, preempted
from ps_ray.specs.resources import StageResources
from ps_ray.store.attempts import (
    STAGE_DIR_KEY,
    UNFINISHED,
    TrialOutcome,
    identity,
    outcomes,
    require_fresh,
)
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
    preemption_retries: int = PREEMPTION_RETRIES,
    scheduler_fn=None,
    budgets: list[int] | None = None,
    work: str = "env_steps",
) -> list[TrialOutcome]:
    """Run a grid over ``grid``'s one key (plus ``constants``) as the Tune experiment in
    ``folder``: ``resources`` per trial (one CPU by default), the sweep's retry policy, the MLflow
    ``callback``, a compact live view on the terminal and Tune's own output in
    ``<folder's parent>/logs/<folder name>.log``
    (:mod:`ps_ray.pipeline.progress`). ``resume`` keeps the trials that finished earlier and runs the rest.

    Trials that failed only because their node went away (:mod:`ps_ray.pipeline.preemption`)
    are launched again by the resume path, up to ``preemption_retries`` rounds: a training
    trial continues from its checkpoint, and preemptions do not use up ``max_failures``.
    ``scheduler_fn()``: a fresh Tune trial scheduler for each launch (a search's ASHA).
    ``budgets``: each trial's work, in ``grid``'s order, counted by its results' ``work`` metric
    (env steps by default), for the live view's ETA."""
    from ray import tune

    from ps_ray.pipeline.progress import StageProgress, quiet_tune
    from ps_ray.store.terminal import verbose

    ((key, trials),) = grid.items()
    path, name, root = Path(folder), Path(folder).name, Path(folder).parent
    if not resume:
        require_fresh(path, key, stage)
    todo = [o.config[key] for o in outcomes(path, key, trials) if o.error] if resume else trials
    errors: dict[str, str] = {}
    quiet = progress and not verbose()
    budget_of = {identity(trial): steps for trial, steps in zip(trials, budgets or [])}
    for attempt in range(preemption_retries + 1):
        if not todo:
            break
        for trial in todo:  # relaunched: a lost node is no longer its error
            errors.pop(identity(trial), None)
        if attempt:
            print(
                f"{stage}: {len(todo)} trial(s) lost their node; launching them again "
                f"({attempt}/{preemption_retries})",
                flush=True,
            )
        view = StageProgress(stage, len(todo), key, budget_of, work)
        tuner = tune.Tuner(
            tune.with_resources(releasing(trainable), resources.tune_request()),
            param_space={key: tune.grid_search(todo), **(constants or {}), STAGE_DIR_KEY: str(path)},
            # a finished trial's worker process runs the next one: no new process, imports and
            # lazy inits per trial (docs/cost.md "Per-trial overhead")
            tune_config=tune.TuneConfig(
                max_concurrent_trials=max_concurrent,
                reuse_actors=True,
                **({"scheduler": scheduler_fn()} if scheduler_fn else {}),
            ),
            run_config=tune.RunConfig(
                name=name,
                storage_path=str(root),
                failure_config=tune.FailureConfig(max_failures=max_failures),
                checkpoint_config=tune.CheckpointConfig(num_to_keep=1),
                callbacks=[callback, *([view] if quiet else [])],
                verbose=1 if progress else 0,
            ),
        )
        with (
            quiet_tune(root / LOG_FOLDER / f"{name}.log") if quiet else contextlib.nullcontext(),
            _signal_handlers_kept(),
        ):
            grid_results = tuner.fit()  # quiet: Tune's tables go to the log
        failed = [r for r in grid_results if r.error]
        errors.update({identity(r.config[key]): str(r.error) for r in failed})
        relaunch = [r.config[key] for r in failed if preempted(_failures(r))]
        if any(o.error == UNFINISHED for o in outcomes(path, key, todo, errors)):
            for config in relaunch:  # stopped by its user (Ctrl-C): nothing is relaunched, and a
                errors.pop(identity(config))  # trial a lost node stopped is unfinished, not failed
            break
        todo = relaunch
    return outcomes(path, key, trials, errors)


def stage_summary(results: list[TrialOutcome]) -> tuple[dict[str, float], str]:
    """A training stage's summary metrics for its MLflow run (how many trials finished, failed
    or were cut short; the mean final success of those that report one) and how it ended."""
    failed = sum(1 for r in results if r.error and r.error != UNFINISHED)
    unfinished = sum(1 for r in results if r.error == UNFINISHED)
    finals = [r.metrics["final_success"] for r in results if r.metrics.get("final_success") is not None]
    metrics = {
        "trials": len(results),
        "trials_finished": len(results) - failed - unfinished,
        "trials_failed": failed,
        "trials_unfinished": unfinished,
        "mean_final_success": sum(finals) / len(finals) if finals else float("nan"),
    }
    return metrics, "FAILED" if failed else "KILLED" if unfinished else "FINISHED"


@contextlib.contextmanager
def _signal_handlers_kept() -> Iterator[None]:
    """Tune's run sets its own SIGINT (and SIGUSR1) handler and leaves it set when it ends: the
    first Ctrl-C of a later stage (the report) would only print Tune's "Stop signal received" and
    be lost. The driver's handlers are put back once Tune returns."""
    names = [name for name in ("SIGINT", "SIGUSR1") if hasattr(signal, name)]
    kept = {name: signal.getsignal(getattr(signal, name)) for name in names}
    try:
        yield
    finally:
        if threading.current_thread() is threading.main_thread():  # only it may set handlers
            for name, handler in kept.items():
                if handler is not None:  # set outside Python: not restorable from here
                    signal.signal(getattr(signal, name), handler)


def _failures(result) -> list[str]:
    """Every failure of a Tune trial: its ``error.txt`` (ray.air.constants.EXPR_ERROR_FILE),
    else its last error."""
    listed = Path(result.path) / "error.txt"
    text = listed.read_text(errors="replace") if listed.is_file() else ""
    return failures(text) or [str(result.error)]
