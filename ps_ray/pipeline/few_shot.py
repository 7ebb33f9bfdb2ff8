"""`ps-ray few-shot`: fine-tune stitched policies with SAC + HER in their target env.

For each stitched pair of one seed without a translation, of the methods named (read from
``zero_shot.csv`` where the zero-shot stage wrote it, else from the zoo:
:func:`ps_ray.plan.zero_shot.evaluated_pairs`), the stitched actor, critics and target critics
are saved and a training trial starts from them: first `collect_steps` of data collection
without updates (the paper: 10 epochs), then training. The same target env trained
from scratch runs beside it, so MLflow holds both learning curves (success vs env steps), and,
with ``few_shot.halves``, each half of the stitch beside a fresh other half
(:mod:`ps_ray.stitching.halves`), which takes the stitched start's head start apart; with
``few_shot.translation``, the stitch aligned by that fitted latent map, as the zero-shot stage
scored it, the map folded into the robot module (:mod:`ps_ray.stitching.fold`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from ps_ray.errors import UserError
from ps_ray.plan import few_shot as few_shot_plan
from ps_ray.plan.catalogue import trained
from ps_ray.plan.zero_shot import evaluated_pairs
from ps_ray.specs.modes import TrialKind
from ps_ray.specs.names import trial_key
from ps_ray.specs.stage_settings import FewShotSpec
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.trial import STITCHED_STARTS, TrainTrial
from ps_ray.stitching.pair_table import pairs_from_table
from ps_ray.stitching.pairs import StitchedPair
from ps_ray.store.layout import sweep_layout


def few_shot_trials(spec: SweepSpec, settings: FewShotSpec) -> list[TrainTrial]:
    """The stage's plan (:func:`ps_ray.plan.few_shot.plan`) on the trained zoo and the pairs the
    zero-shot stage evaluated, with the policy file of every stitched start written."""
    zoo = trained(spec)
    table = pairs_from_table(sweep_layout(spec).zero_shot_table)
    pairs = evaluated_pairs(spec, table, lambda: zoo, list(settings.methods) or None)
    selected = few_shot_plan.selected_pairs(pairs, settings)
    aligned = {p.key: aligned_stitch(spec, p, settings.translation, table) for p in selected}
    for pair in selected:  # every aligned stitch found before any start is written
        for kind in few_shot_plan.starts(settings):
            _write_start(spec, pair, kind, settings.translation, aligned[pair.key])
    return few_shot_plan.plan(spec, zoo, pairs, settings)


def aligned_stitch(
    spec: SweepSpec, pair: StitchedPair, translation: str | None, table: list[StitchedPair] | None
) -> Path | None:
    """The policy file of ``pair``'s stitch aligned by ``translation``, as the zero-shot stage
    fitted, scored and kept it (:mod:`ps_ray.stitching.pair_files`); None without a translation."""
    from ps_ray.stitching.pair_files import STITCHED_FILE, pair_folder

    if translation is None:
        return None
    sources = (pair.task_from, pair.robot_from, pair.pairing, translation)
    found = [p for p in table or [] if (p.task_from, p.robot_from, p.pairing, p.translation) == sources]
    path = pair_folder(sweep_layout(spec).tune_zero_shot, found[0].key) / STITCHED_FILE if found else None
    if path is None or not path.is_file():
        raise UserError(
            f"few_shot.translation {translation!r}: the zero-shot stage kept no such stitch of "
            f"{pair.title}; run zero-shot with zero_shot.translate: {{{pair.method}: [{translation}]}} first"
        )
    return path


def _write_start(
    spec: SweepSpec, pair: StitchedPair, kind: str, translation: str | None, aligned: Path | None
) -> None:
    """The policy file a start of the pair begins from (:func:`ps_ray.plan.few_shot.start_file`):
    its stitch, the ``aligned`` stitch with its map folded in, or (``kind`` one of the halves) the
    stitch with one half fresh, drawn from the pair's seed; written once, so a resumed stage keeps
    the files its trials started from."""
    from ps_ray.nets.policy_file import load_policy, save_policy
    from ps_ray.stitching.fold import fold_translation
    from ps_ray.stitching.halves import half_stitch
    from ps_ray.stitching.stitch import stitch_policies

    path = few_shot_plan.start_file(spec, pair, kind, translation)
    if path.exists():
        return
    extra = {"task_from": pair.task_from, "robot_from": pair.robot_from, "start": kind}
    if kind == TrialKind.STITCHED:
        nets, signature = stitch_policies(pair.task_from_path, pair.robot_from_path)
    elif kind == TrialKind.ALIGNED:
        nets, signature = fold_translation(*load_policy(aligned))
        extra["translation"] = str(translation)
    else:
        nets, signature = half_stitch(pair.task_from_path, pair.robot_from_path, kind, pair.seed)
    save_policy(path, nets, signature, extra=extra)


def run_few_shot(spec: SweepSpec, *, resume: bool = False, progress: bool = True, **overrides: Any):
    """Settings from ``spec.few_shot`` (``overrides`` replace fields); returns the trials'
    outcomes. A resumed stage whose every trial finished starts neither Ray nor MLflow."""
    from ps_ray.pipeline.stage import connect, open_tracking
    from ps_ray.pipeline.training_trials import run_tune
    from ps_ray.pipeline.trials import stage_summary
    from ps_ray.store.attempts import outcomes, require_fresh
    from ps_ray.store.stage_run import close_left_open

    settings = dataclasses.replace(spec.few_shot, **overrides)
    root = sweep_layout(spec).root
    if not resume:  # refused before the stitched starts are written
        require_fresh(sweep_layout(spec).tune_few_shot, "trial", "few_shot")
    trials = few_shot_trials(spec, settings)
    if not trials:
        raise UserError(f"{root}: no stitchable pairs (train the sweep first: ps-ray sweep)")
    if resume:
        finished = outcomes(sweep_layout(spec).tune_few_shot, "trial", [trial.config() for trial in trials])
        if not any(outcome.error for outcome in finished):  # a kill's open stage run: closed
            close_left_open(*open_tracking(spec), "few_shot", stage_summary(finished)[0])
            return finished
    tracking = connect(spec)
    return run_tune(
        trials,
        folder=sweep_layout(spec).tune_few_shot,
        stage="few_shot",
        spec=spec,
        tracking=tracking,
        resume=resume,
        progress=progress,
        key_fn=lambda trial: TrainTrial.of(trial.config["trial"]).run_name,
        tags_fn=lambda trial, client: _source_tags(TrainTrial.of(trial.config["trial"]), client, tracking[1]),
    )


# Every few-shot run names its start and its target (method, robot, task, seed), so the runs of
# one target (stitched, halves, unstitched, scratch) group together; a start made from a stitched
# pair (stitched, halves) names the pair too.
START_TAG, TARGET_TAG, PAIR_TAG = "ps_ray.start", "ps_ray.target", "ps_ray.pair"


def _source_tags(trial: TrainTrial, client, experiment_id: str) -> dict[str, str]:
    """A fine-tuning run's start, target and pair; a stitched start's also its two sources (their
    runs) and anchor set."""
    from ps_ray.store.signature import read_signature
    from ps_ray.store.tracking import source_tags

    target = {k: v for k, v in trial.spec.to_dict().items() if k != "init_policy"}
    tags = {START_TAG: trial.kind, TARGET_TAG: trial_key(target)}
    if trial.kind in STITCHED_STARTS:
        tags[PAIR_TAG] = trial.label
    start = trial.spec.init_policy
    if trial.kind not in (TrialKind.STITCHED, TrialKind.ALIGNED) or not start:
        return tags
    meta = read_signature(start)[1]
    return {**tags, **source_tags(client, experiment_id, meta["task_from"], meta["robot_from"], start)}


def curves(results) -> dict[str, list[tuple[int, float]]]:
    """Greedy success vs env steps per trial key, from the stage's trial outcomes."""
    return {
        TrainTrial.of(result.config["trial"]).run_name: [
            (int(row["env_steps"]), row["eval_success"])
            for row in result.rows
            if row.get("eval_success") is not None
        ]
        for result in results
    }
