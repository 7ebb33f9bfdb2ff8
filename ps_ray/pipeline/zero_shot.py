"""`ps-ray zero-shot`: the stitching matrix of a sweep, evaluated as Tune trials, into MLflow.

Every valid (task module, robot module) pair of each method (see `stitch.combos`), of one seed or,
with ``zero_shot.pairs``, across seeds, is stitched, evaluated on fixed seeds (episodes x
repeats, a block of its own per training seed: :func:`pair_episodes`), then the pair's controls
are evaluated as they are on the same episodes (its robot source, its task source, the oracle:
`stitch.controls`, docs/controls.md), so that every method and control is scored on identical
episodes; beside them, the chance level and task-blind floor of the target env on those episodes
(:mod:`ps_ray.stitching.chance`: policies with no task knowledge, measured once per target env
and seed before the trials start). The table, one row per pair (its record, :meth:`StitchedPair.to_row`:
the sources' and controls' keys and files) with its controls' figures and transfer gain, goes to
<sweep>/zero_shot.csv, and to MLflow (stage zero_shot, one run per pair). Pairs run in
batches (``zero_shot.pairs_per_trial`` per Tune trial), so that a trial's start is paid once per
batch; each pair is still one result row and one MLflow run.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ps_ray.errors import UserError
from ps_ray.pipeline.chance_levels import chance_levels
from ps_ray.pipeline.stage import connect, open_tracking, raise_on_errors
from ps_ray.pipeline.zero_shot_table import stage_metrics
from ps_ray.plan import zero_shot as zero_shot_plan
from ps_ray.plan.catalogue import trained
from ps_ray.plan.zero_shot import (
    Episodes,
    FitSettings,
    ZeroShotBatch,
    check_kept,
    stream_of,
)
from ps_ray.specs.stage_settings import ZeroShotSpec
from ps_ray.specs.sweep import SweepSpec
from ps_ray.stitching.pair_table import CONTROL_KEYS, RESULT_KEYS, table_of, write_table
from ps_ray.stitching.pairs import StitchedPair
from ps_ray.stitching.zoo import ModuleZoo
from ps_ray.store.layout import sweep_layout
from ps_ray.store.stage_run import StageRun, close_left_open, open_stage


def fit_states(tasks: list, per_quadrant: int, seed: int) -> np.ndarray:
    """Task inputs for fitting a latent translation: the probe states of every given task (the
    target task and the robot source's task), ``per_quadrant`` per goal quadrant
    (:func:`ps_ray.analysis.latent.probe_states`: for reach, goals from the four quadrant discs
    rather than the task's own goal region; for other tasks, the task's own resets). Resets only:
    no env steps are taken."""
    from ps_ray.analysis.latent import probe_states

    return np.concatenate([probe_states(task, per_quadrant, seed).states for task in tasks])


def check_sources(trials: list[StitchedPair]) -> None:
    """Every policy file the pairs read loads, and every pair stitches, before a trial starts: a
    damaged or unfinished file is one line naming it, not a failing trial retried per pair."""
    from ps_ray.nets.policy_file import load_policy
    from ps_ray.stitching.rule import check_stitchable

    signatures = {}
    for pair in trials:
        paths = [pair.task_from_path, pair.robot_from_path]
        paths += [control.path for control in pair.controls.values()]
        for path in paths:
            if path not in signatures:
                signatures[path] = load_policy(path)[1]
        try:
            check_stitchable(signatures[pair.task_from_path], signatures[pair.robot_from_path])
        except UserError as e:
            raise UserError(f"{pair.task_from_path} with {pair.robot_from_path}: {e}") from None


PAIR_KEY = "pair_key"  # names the stitched pair of a batched trial's result row
PAIR_FILES = "pair_files"  # and the folder of its stitched policy and per-episode outcomes


class Sources:
    """A trial's policy files, each read once, and the controls' evaluations, each run once (the
    translated stitches of a pair share its controls; pairs of a seed share their sources)."""

    def __init__(self) -> None:
        self._loaded: dict[str, Any] = {}
        self._scored: dict[tuple, dict] = {}

    def __call__(self, path: str):
        if path not in self._loaded:
            from ps_ray.nets.policy_file import load_policy

            self._loaded[path] = load_policy(path)
        return self._loaded[path]

    def evaluated(self, path: str, pair: StitchedPair, episodes: Episodes) -> dict:
        """The policy file at ``path`` as it is, on ``pair``'s target env and ``episodes``."""
        from ps_ray.stitching.evaluate import evaluate

        key = (path, pair.robot.text, pair.task.text, episodes.seed)
        if key not in self._scored:
            self._scored[key] = evaluate(self(path), pair.robot, pair.task, **episodes.kwargs())
        return self._scored[key]

    def told(self, path: str, pair: StitchedPair, episodes: Episodes) -> dict:
        """The robot source at ``path`` told ``pair``'s task (:mod:`ps_ray.stitching.told`), on
        its target env and ``episodes``."""
        from ps_ray.stitching.evaluate import as_action_fn, evaluate
        from ps_ray.stitching.told import TellTask

        key = ("told", path, pair.robot.text, pair.task.text, pair.robot_from_task.text, episodes.seed)
        if key not in self._scored:
            act = TellTask(as_action_fn(self(path))[0], pair.task, pair.robot_from_task)
            self._scored[key] = evaluate(act, pair.robot, pair.task, **episodes.kwargs())
        return self._scored[key]


def zero_shot_trial(config: dict[str, Any]) -> None:
    """Tune function trainable: a :class:`ZeroShotBatch`'s pairs one after another, one result
    row per pair (named by ``PAIR_KEY``)."""
    from ray import tune

    from ps_ray.pipeline.tune_tracking import ROW_ENDED, ROW_STARTED
    from ps_ray.stitching.pair_files import pair_folder
    from ps_ray.store.attempts import FINISHED, STAGE_DIR_KEY

    batch, sources = ZeroShotBatch.from_config(config), Sources()
    for i, pair in enumerate(batch.pairs):
        keep, started = pair_folder(config[STAGE_DIR_KEY], pair.key), time.time()
        metrics = evaluate_pair(pair, batch.episodes(pair), batch.fit, batch.chance_of(pair), sources, keep)
        last = {FINISHED: True} if i == len(batch.pairs) - 1 else {}
        times = {ROW_STARTED: started, ROW_ENDED: time.time()}
        tune.report({**metrics, PAIR_KEY: pair.key, PAIR_FILES: str(keep), **times, **last})


def _fit_states(pair: StitchedPair, fit: FitSettings, sources: Sources) -> np.ndarray | None:
    """The task states a pair's translation is fitted on (None for a pair without one)."""
    from ps_ray.stitching.outcomes import fit_pairs, matched_anchors

    if not pair.translation:
        return None
    kind, where = pair.translation.kind, pair.translation.fit
    if kind == "anchors":  # the robot module's anchors, matched in the task module's task
        anchors = sources(pair.robot_from_path)[0].actor.anchors
        if anchors is None:
            raise UserError(f"{pair.key}: anchors@{where} needs a method with a relative projection")
        return matched_anchors(where, anchors.numpy(), *pair.sources, fit.scenes, fit.seed, fit.cache)
    if where:  # matched pairs of states (ps_ray.stitching.outcomes)
        return fit_pairs(where, *pair.sources, fit.scenes, fit.points, fit.seed, fit.cache)
    return fit_states(list(pair.fit_tasks), fit.states_per_quadrant, fit.fit_seed)


def evaluate_pair(
    pair: StitchedPair,
    episodes: Episodes,
    fit: FitSettings,
    chance: dict[str, Any],
    sources: Sources | None = None,
    keep: Path | None = None,
) -> dict:
    """Stitch one pair (translated as ``fit`` says, if the pair names a translation), evaluate it,
    then each of its controls as it is, all on the pair's fixed ``episodes``
    (:func:`pair_episodes`); ``chance``: the chance level and task-blind floor of the pair's target
    env on those episodes (:func:`chance_levels`); ``sources``: the trial's loaded files and
    control scores, to reuse; ``keep``: a folder for the stitched policy and its per-episode
    outcomes beside the controls' (:mod:`ps_ray.stitching.pair_files`)."""
    from ps_ray.stitching.evaluate import evaluate
    from ps_ray.stitching.outcomes import fit_cost
    from ps_ray.stitching.stitch import stitch_policies, translation_ridge
    from ps_ray.stitching.told import can_tell

    sources = sources or Sources()
    stitched = stitch_policies(
        sources(pair.task_from_path),
        sources(pair.robot_from_path),
        translation=pair.translation.kind if pair.translation else None,
        fit_states=_fit_states(pair, fit, sources),
    )
    result = evaluate(stitched, pair.robot, pair.task, **episodes.kwargs())
    metrics = {k: result[k] for k in RESULT_KEYS if k in result} | {"episodes_seed": episodes.seed}
    ridge = translation_ridge(stitched[0])
    metrics["translation_ridge"] = np.nan if ridge is None else ridge
    metrics["fit_env_steps"] = 0
    if (t := pair.translation) and t.fit:  # what the fit rolled out, cached or not
        n_anchors = len(sources(pair.robot_from_path)[0].actor.anchors) if t.kind == "anchors" else 0
        metrics["fit_env_steps"] = fit_cost(t.kind, t.fit, pair.sources[0], fit.scenes, n_anchors, fit.cache)
    controls = {}
    for role, control in pair.controls.items():
        controls[role] = unstitched = sources.evaluated(control.path, pair, episodes)
        if unstitched["episodes_digest"] != result["episodes_digest"]:  # a bug, never bad input
            raise RuntimeError(f"{pair.key}: its {role} control ran on other episodes")
        metrics[f"{role}_success"] = unstitched["success_mean"]
    robot_source = pair.controls.get("robot_source")
    if robot_source is not None and can_tell(pair.task, pair.robot_from_task):  # the ceiling
        controls["told_robot_source"] = told = sources.told(robot_source.path, pair, episodes)
        if told["episodes_digest"] != result["episodes_digest"]:  # a bug, never bad input
            raise RuntimeError(f"{pair.key}: its told robot source ran on other episodes")
        metrics["told_robot_source_success"] = told["success_mean"]
    if chance["episodes_digest"] != result["episodes_digest"]:  # a bug, never bad input
        raise RuntimeError(f"{pair.key}: its chance level was measured on other episodes")
    for key in ("chance_success", "task_blind_success", "task_blind_wrong_target"):
        metrics[key] = chance.get(key, np.nan)
    if keep is not None:
        from ps_ray.stitching.pair_files import episodes_table, write_pair_files
        from ps_ray.stitching.stitch import stitch_metadata

        extra = stitch_metadata(pair.task_from, pair.robot_from)
        if ridge is not None:
            extra["translation_ridge"] = f"{ridge:.6g}"
        write_pair_files(keep, *stitched, extra, episodes_table(result, controls))
    return {**metrics, **gain(metrics)}


def gain(metrics: dict[str, Any]) -> dict[str, float]:
    """``best_unstitched`` (the better of the two unstitched controls that apply), ``best_control``
    (the best of those, chance and the task-blind floor where the scene has one), ``transfer_gain``
    (stitched success minus ``best_control``) and ``gain_over_chance`` (the gain over the sources
    and chance alone, the measure before the floor existed); NaN when none applies."""

    def best(keys) -> float:
        values = [metrics.get(f"{key}_success") for key in keys]
        return max((v for v in values if v is not None and v == v), default=np.nan)

    unstitched = best(("robot_source", "task_source"))
    control = best(("robot_source", "task_source", "chance", "task_blind"))
    return {
        "best_unstitched": unstitched,
        "best_control": control,
        "transfer_gain": metrics["success_mean"] - control,
        "gain_over_chance": metrics["success_mean"] - best(("robot_source", "task_source", "chance")),
    }


def run_zero_shot(
    spec: SweepSpec, *, resume: bool = False, progress: bool = True, **overrides: Any
) -> pd.DataFrame:
    """The matrix as Tune trials of ``zero_shot.pairs_per_trial`` pairs each, settings from
    ``spec.zero_shot`` (``overrides`` replace fields).

    ``resume`` finishes an interrupted matrix: pairs with a result row in ``tune_zero_shot`` are
    kept, whatever batch they ran in; the others run in new batches (a matrix with none left
    starts neither Ray nor its chance levels)."""
    from ps_ray.store.attempts import require_fresh, rows_naming

    settings = dataclasses.replace(spec.zero_shot, **overrides)
    root, folder = sweep_layout(spec).root, sweep_layout(spec).tune_zero_shot
    if not resume:
        require_fresh(folder, "batch", "zero_shot")
    zoo = trained(spec)
    trials = zero_shot_plan.plan(spec, zoo, settings)
    if not trials:
        raise UserError(f"{root}: no stitchable pairs (train the sweep first: ps-ray sweep)")
    check_sources(trials)
    done = rows_naming(folder, PAIR_KEY) if resume else {}
    check_kept(done, trials, settings)
    todo = [pair.to_dict() for pair in trials if pair.key not in done]
    if not todo:  # a resumed matrix whose every pair reported needs neither Ray nor chance again
        table = _table(spec, trials)
        close_left_open(*open_tracking(spec), "zero_shot", stage_metrics(table))  # a kill's leftover
        return table
    tracking = connect(spec)
    with open_stage(*tracking, spec.name, "zero_shot") as stage_run:  # open while the stage runs
        _evaluate(spec, settings, trials, todo, tracking, stage_run, zoo, resume=resume, progress=progress)
        table = _table(spec, trials)
        stage_run.record(stage_metrics(table))
    return table


def _table(spec: SweepSpec, trials: list[StitchedPair]) -> pd.DataFrame:
    """The stage's table, a row per pair in the plan's order, written to ``zero_shot.csv``."""
    from ps_ray.store.attempts import rows_naming

    rows = rows_naming(sweep_layout(spec).tune_zero_shot, PAIR_KEY)
    missing = [pair.key for pair in trials if pair.key not in rows]
    if missing:  # every batch finished, so each of its pairs reported: a bug, never bad input
        raise RuntimeError(f"{len(missing)} pairs have no result row, e.g. {missing[0]}")
    table = table_of([(pair, rows[pair.key]) for pair in trials], sweep_layout(spec).root)
    write_table(table, sweep_layout(spec).zero_shot_table)
    return table


def _evaluate(
    spec: SweepSpec,
    settings: ZeroShotSpec,
    trials: list[StitchedPair],
    todo: list[dict],
    tracking: tuple[str, str],
    stage_run: StageRun,
    zoo: ModuleZoo,
    *,
    resume: bool,
    progress: bool,
) -> None:
    """Run the ``todo`` pairs as Tune batches, each pair's row and MLflow run (a child of
    ``stage_run``) as it reports."""
    from ps_ray.pipeline.trials import run_trials, stage_summary
    from ps_ray.pipeline.tune_tracking import RowRunsCallback
    from ps_ray.specs.resources import device_tags

    folder, by_key = sweep_layout(spec).tune_zero_shot, {pair.key: pair for pair in trials}
    evaluated = {"episodes": settings.episodes, "repeats": settings.repeats}
    stream = stream_of(settings)  # each seed's block of the zero-shot stream
    chance = chance_levels(trials, stream, progress, zoo, sweep_layout(spec).chance)
    fit = FitSettings.of(settings, str(sweep_layout(spec).outcomes))
    tracking_uri, experiment_id = tracking
    callback = RowRunsCallback(
        tracking_uri,
        experiment_id,
        row_key=PAIR_KEY,
        metric_keys=(*RESULT_KEYS, *CONTROL_KEYS),
        params_fn=lambda key: by_key[key].shown() | evaluated,
        tags={
            **stage_run.tags,
            **device_tags(spec.resources.zero_shot),
            "ps_ray.device": "cpu",  # stitching and evaluation run on the CPU, whatever the grant
        },
        tags_fn=lambda key, client: _tags(client, experiment_id, by_key[key]),
        name_fn=lambda key: by_key[key].title,
        artifacts_key=PAIR_FILES,
    )
    batches = _batches(todo, settings.batch_sizes(len(todo), spec.max_concurrent))
    results = run_trials(
        zero_shot_trial,
        {"batch": batches},
        folder=folder,
        stage="zero_shot",
        callback=callback,
        resume=resume,
        progress=progress,
        max_concurrent=spec.max_concurrent,
        max_failures=spec.max_failures,
        resources=spec.resources.zero_shot,
        budgets=[len(batch) for batch in batches],  # the ETA by pairs scored (one result each)
        work="training_iteration",
        constants=ZeroShotBatch.shared(stream, fit, chance),
    )
    ended = stage_summary(results)[1]
    if ended != "FINISHED":  # how the stage ends, as raise_on_errors ends it here
        stage_run.record({}, ended)
    raise_on_errors(results, "zero-shot batches")


def _batches(pairs: list, sizes: list[int]) -> list[list]:
    """Consecutive runs of ``pairs`` (pairs of one seed share their sources) of the given sizes."""
    ends = np.cumsum([0, *sizes])
    return [pairs[a:b] for a, b in zip(ends[:-1], ends[1:], strict=True)]


def _tags(client, experiment_id: str, pair: StitchedPair) -> dict:
    from ps_ray.store.tracking import source_tags

    return source_tags(client, experiment_id, pair.task_from, pair.robot_from, pair.task_from_path)
