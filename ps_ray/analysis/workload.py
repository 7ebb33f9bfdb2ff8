"""A sweep's work, counted from its spec alone (no policy needs to exist): training trials, the
plain policies trained for PS anchors, the grids, the stitched pairs of the zero-shot stage, and
the fine-tuning and from-scratch runs of the few-shot stage (docs/cost.md, "The work, per
stage"), each stage's trials as its own plan lists them (:mod:`ps_ray.plan`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ps_ray.envs import EPISODE_STEPS
from ps_ray.plan.stages import PLANS
from ps_ray.specs.names import CROSSED_FITS
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.train import TrainSpec
from ps_ray.stitching.chance import CHANCE_POLICIES, candidate_count, scene_oracles, scripted_floor
from ps_ray.stitching.pairs import StitchedPair
from ps_ray.stitching.told import can_tell
from ps_ray.stitching.zoo import ModuleZoo


@dataclass(frozen=True)
class StageLoad:
    """One stage's work: its trials, their env steps (training and evaluation) and updates."""

    stage: str
    trials: list[TrainSpec | None]  # None: an evaluation-only trial (zero-shot)
    env_steps: int
    updates: int
    eval_steps: int
    members: tuple[int, ...] = ()  # the sources each trial trains (a population's K); (): one each

    def sources(self, index: int) -> int:
        """How many sources trial ``index`` trains (a population trains K, every other trial one)."""
        return self.members[index] if self.members else 1


def train_load(stage: str, specs: list[TrainSpec]) -> StageLoad:
    env = updates = evals = 0
    for s in specs:
        env += s.env_steps
        updates += int(max(0, s.env_steps - s.learning_starts) * s.updates_per_step)
        steps_per_iteration = s.episodes_per_step * EPISODE_STEPS
        evals += s.env_steps // (steps_per_iteration * s.eval_every) * s.eval_episodes * EPISODE_STEPS
    return StageLoad(stage, list(specs), env, updates, evals)


def _train(spec: SweepSpec, zoo: ModuleZoo) -> list[StageLoad]:
    from ps_ray.plan import train

    plain = train.plain_sources(spec)
    loads = [train_load("anchors_plain", [t.spec for t in plain])] if plain else []
    trials = PLANS["train"](spec, zoo)
    if spec.population == 1:
        return [*loads, train_load("train", [t.spec for t in trials])]
    # a population trial trains each of its members: priced as their sum (docs/cost.md "Populations")
    members = train_load("train", [m.spec for t in trials for m in t.sources])
    bases = [t.sources[0].spec for t in trials]
    return [*loads, dataclasses.replace(members, trials=bases, members=tuple(len(t.sources) for t in trials))]


def _grid(spec: SweepSpec, zoo: ModuleZoo) -> list[StageLoad]:
    """A grid trial trains each of its cells (its update costs about one per cell)."""
    grids = PLANS["grid"](spec, zoo)
    if not grids:
        return []
    cells = train_load("grid", [t.grid.cell_spec(c) for t in grids for c in t.grid.cells])
    return [dataclasses.replace(cells, trials=[t.grid.base for t in grids])]


def _zero_shot(spec: SweepSpec, zoo: ModuleZoo) -> list[StageLoad]:
    return [zero_shot_load(spec, zoo, PLANS["zero_shot"](spec, zoo))]


def _few_shot(spec: SweepSpec, zoo: ModuleZoo) -> list[StageLoad]:
    return [train_load("few_shot", [t.spec for t in PLANS["few_shot"](spec, zoo)])]


# Each stage that runs trials: its plan's work (ps_ray.plan.stages.PLANS), from the spec and the
# catalogue it implies (the report runs none). A new stage adds its row (tests/test_stages.py
# checks that each has one).
LOADS = {"train": _train, "grid": _grid, "zero_shot": _zero_shot, "few_shot": _few_shot}


def workload(spec: SweepSpec) -> list[StageLoad]:
    """The work of every stage the spec runs, in order: each stage's own plan
    (:mod:`ps_ray.plan`) on the catalogue the spec implies, so the trials counted are the
    trials the stages launch."""
    from ps_ray.plan.catalogue import planned

    zoo = planned(spec)
    return [load for stage in spec.stages if stage in LOADS for load in LOADS[stage](spec, zoo)]


def _evaluated_beside(pair: StitchedPair) -> int:
    """How many policies a pair is scored beside: its controls, and the ceiling where it has one."""
    told = "robot_source" in pair.controls and can_tell(pair.task, pair.robot_from_task)
    return len(pair.controls) + told


def zero_shot_load(spec: SweepSpec, zoo: ModuleZoo, pairs: list[StitchedPair]) -> StageLoad:
    """The evaluations of the planned pairs: each stitch, each untranslated pair's controls and,
    on a marker family, its robot source told the task (its translations share their
    evaluations), chance (its policies) and the task-blind floor (once
    per candidate target, or per oracle of each candidate's task where no script does it) once
    per target env and training seed (each seed's own episodes), and
    the rollouts of the fits on scenes matched by outcome (:mod:`ps_ray.stitching.outcomes`)."""
    settings = spec.zero_shot
    targets = {(p.robot, p.task, p.seed) for p in pairs}
    evaluations = len(pairs) + sum(_evaluated_beside(p) for p in pairs if not p.translation)
    for robot, task, seed in targets:
        evaluations += len(CHANCE_POLICIES)
        if scripted_floor(task):  # driven to each candidate
            evaluations += candidate_count(task)
        elif candidate_count(task) > 1:  # each method's oracle of each candidate task
            evaluations += sum(map(len, scene_oracles(zoo, robot, task, seed).values()))
    steps = evaluations * settings.episodes * settings.repeats * EPISODE_STEPS
    # a fit on scenes matched by outcome rolls each source out once: on `outcome_scenes` scenes,
    # except a re-anchored stitch's robot source, once per anchor (PS: as many as the interface is
    # wide), and with a crossed fit ("both", "decoded") each source also in the other's scenes (at
    # most `outcome_scenes` candidates); the swapped scenes need no rollout
    rollouts: dict[tuple[str, str], int] = {}
    for p in pairs:
        kind, fit = (p.translation.kind, p.translation.fit) if p.translation else ("", "")
        if not fit or fit == "swapped":
            continue
        t, r = p.task_from, p.robot_from
        rollouts[t, "scenes"] = settings.outcome_scenes
        if kind == "anchors":
            rollouts[r, "anchors"] = zoo.get(r).key.interface_dim
        else:
            rollouts[r, "scenes"] = settings.outcome_scenes
        if fit in CROSSED_FITS:  # each source also ends in the other's scenes
            rollouts[t, "anchors"] = zoo.get(t).key.interface_dim
            rollouts[r, t] = settings.outcome_scenes
    steps += sum(rollouts.values()) * EPISODE_STEPS
    batches = len(settings.batch_sizes(len(pairs), spec.max_concurrent))  # trials of several pairs
    return StageLoad("zero_shot", [None] * batches, 0, 0, steps)
