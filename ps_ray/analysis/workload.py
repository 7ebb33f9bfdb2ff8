"""A sweep's work, counted from its spec alone (no policy needs to exist): training trials, the
plain policies trained for PS anchors, the stitched pairs of the zero-shot stage, and the
fine-tuning and from-scratch runs of the few-shot stage (docs/cost.md, "The work, per stage")."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

from ps_ray.envs import EPISODE_STEPS
from ps_ray.specs.names import CONTROL_ROLES, CROSSED_FITS, split_translation
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.train import TrainSpec
from ps_ray.stitching.chance import CHANCE_POLICIES
from ps_ray.stitching.pairs import CO_TRAINED


@dataclass(frozen=True)
class StageLoad:
    """One stage's work: its trials, their env steps (training and evaluation) and updates."""

    stage: str
    trials: list[TrainSpec | None]  # None: an evaluation-only trial (zero-shot)
    env_steps: int
    updates: int
    eval_steps: int


def train_load(stage: str, specs: list[TrainSpec]) -> StageLoad:
    env = updates = evals = 0
    for s in specs:
        env += s.env_steps
        updates += int(max(0, s.env_steps - s.learning_starts) * s.updates_per_step)
        steps_per_iteration = s.episodes_per_step * EPISODE_STEPS
        evals += s.env_steps // (steps_per_iteration * s.eval_every) * s.eval_episodes * EPISODE_STEPS
    return StageLoad(stage, list(specs), env, updates, evals)


def stitch_pairs(
    spec: SweepSpec, method: str, pairing: str = "same_seed"
) -> list[tuple[TrainSpec, TrainSpec]]:
    """(task source, robot source) pairs the stitching stages will build for one method: the
    seeds that ``pairing`` joins (:func:`ps_ray.specs.sweep.seed_pairs`), then the one pairing
    rule of the stitching stages (:func:`ps_ray.stitching.rule.stitchable`) on the signatures
    the trials' policy files will carry."""
    from ps_ray.specs.sweep import seed_pairs
    from ps_ray.stitching.rule import expected_signature, stitchable

    cells = [(t, t.to_dict()) for t in spec.trials() if t.method == method]
    signatures = [expected_signature(d) for _, d in cells]
    joined = {(task_seed, robot_seed) for _, task_seed, robot_seed in seed_pairs(spec.seeds, pairing)}
    return [
        (t, r)
        for (t, td), st in zip(cells, signatures)
        for (r, rd), sr in zip(cells, signatures)
        if (t.seed, r.seed) in joined and stitchable(td, rd, st, sr) is not None
    ]


def _preset(shown: str) -> str:
    """The method of a row name (``"ablation co-trained"`` -> ``"ablation"``)."""
    return shown.removesuffix(f" {CO_TRAINED}")


def workload(spec: SweepSpec) -> list[StageLoad]:
    """The work of every stage the spec runs, in order."""
    from ps_ray.specs.sweep import anchor_sources

    loads = []
    if "train" in spec.stages:
        plain = anchor_sources(spec) if spec.anchors.policy == "plain" and not spec.anchors.file else []
        if plain:
            loads.append(train_load("anchors_plain", plain))
        loads.append(train_load("train", spec.trials()))
    grids = spec.grid.grids(spec) if "grid" in spec.stages else []
    if grids:  # a grid trial trains each of its cells (its update costs about one per cell)
        cells = train_load("grid", [g.cell_spec(c) for g in grids for c in g.cells])
        loads.append(dataclasses.replace(cells, trials=[g.base for g in grids]))
    if "zero_shot" in spec.stages:
        methods = list(spec.zero_shot.methods) or list(spec.methods)
        pairing = spec.zero_shot.pairs
        found = {m: stitch_pairs(spec, m, pairing) for m in methods}
        # a grid's pairs: the same rule, on the grid's held-out targets (ps_ray.stitching.matrix)
        held = {(g.base.method, g.base.seed, g.held_out_text) for g in grids}
        for m in list(found):
            co_trained = [(t, r) for t, r in found[m] if (m, t.seed, f"{r.robot.text}/{t.task.text}") in held]
            if co_trained:
                found[f"{m} {CO_TRAINED}"] = co_trained
        n = sum(len(pairs) * (1 + len(spec.zero_shot.translations(_preset(m)))) for m, pairs in found.items())
        # each trial evaluates its pair and up to three controls (ps_ray.stitching.matrix.controls);
        # chance, once per target env (the task source's task on the robot source's robot)
        targets = {(r.robot, t.task) for pairs in found.values() for t, r in pairs}
        # (a pair's translated stitches share its controls' evaluations)
        base = sum(len(pairs) for pairs in found.values())
        evaluations = n + base * len(CONTROL_ROLES) + len(targets) * len(CHANCE_POLICIES)
        steps = evaluations * spec.zero_shot.episodes * spec.zero_shot.repeats * EPISODE_STEPS
        # a fit on scenes matched by outcome rolls each source out once (ps_ray.stitching.outcomes):
        # on `outcome_scenes` scenes, except a re-anchored stitch's robot source, once per anchor
        # (PS: as many as the interface is wide), and with a crossed fit ("both", "decoded") each
        # source also in the other's scenes (at most `outcome_scenes` candidates); the swapped
        # scenes need no rollout
        rollouts: dict[tuple[TrainSpec, TrainSpec | str], int] = {}
        for m in found:
            for kind, fit in map(split_translation, spec.zero_shot.translations(_preset(m))):
                for t, r in found[m] if fit and fit != "swapped" else ():
                    rollouts[t, "scenes"] = spec.zero_shot.outcome_scenes
                    if kind == "anchors":
                        rollouts[r, "anchors"] = r.interface_dim
                    else:
                        rollouts[r, "scenes"] = spec.zero_shot.outcome_scenes
                    if fit in CROSSED_FITS:  # each source also ends in the other's scenes
                        rollouts[t, "anchors"] = t.interface_dim
                        rollouts[r, t] = spec.zero_shot.outcome_scenes
        steps += sum(rollouts.values()) * EPISODE_STEPS
        batches = len(spec.zero_shot.batch_sizes(n, spec.max_concurrent))  # trials of several pairs
        loads.append(StageLoad("zero_shot", [None] * batches, 0, 0, steps))
    if "few_shot" in spec.stages:
        from ps_ray.specs.sweep import task_input_dim

        few = spec.few_shot
        runs: list[TrainSpec] = []
        targets: dict[str, TrainSpec] = {}
        unstitched: dict[str, TrainSpec] = {}
        for method in list(few.methods) or list(spec.methods):
            chosen, per_seed = [], {}
            for t, r in stitch_pairs(spec, method):
                if few.pairs_per_seed is not None and per_seed.get(t.seed, 0) >= few.pairs_per_seed:
                    continue
                per_seed[t.seed] = per_seed.get(t.seed, 0) + 1
                chosen.append((t, r))
            for t, r in chosen[: few.max_pairs]:
                run = TrainSpec.from_mapping(
                    {
                        **r.to_dict(),
                        "task": t.task,
                        "env_steps": few.env_steps,
                        "learning_starts": few.collect_steps,
                    }
                )
                runs.append(run)  # fine-tuning a stitched start
                if few.halves:  # and each half of it beside a fresh other half
                    runs += [run, run]
                key = json.dumps(run.to_dict(), sort_keys=True, default=str)
                targets.setdefault(key, run)
                if few.unstitched and task_input_dim(r.task) == task_input_dim(t.task):
                    unstitched.setdefault(key + json.dumps(r.task, sort_keys=True, default=str), run)
        runs += unstitched.values()  # each pair's robot source fine-tuned as it is
        if few.scratch:  # one from-scratch run per distinct target
            runs += targets.values()
        loads.append(train_load("few_shot", runs))
    return loads
