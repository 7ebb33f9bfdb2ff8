"""What a sweep will cost before it runs: trials, env steps, gradient updates, core-hours, wall time.

The workload is counted from the spec alone (no policy needs to exist): training trials, the
plain policies trained for PS anchors, the stitched pairs of the zero-shot stage, and the
fine-tuning and from-scratch runs of the few-shot stage. Budgets with a success target are caps,
so the projection is an upper bound for them.

Seconds come from per-core rates (:class:`Rates`): measured on this machine by
``ps-ray bench rates`` and cached, or :data:`DEFAULT_RATES`, conservative figures stated as such.
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
from dataclasses import dataclass
from pathlib import Path

from ps_ray.envs import EPISODE_STEPS
from ps_ray.names import CONTROL_ROLES
from ps_ray.specs.methods import uses_anchors
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.train import SpecError, TrainSpec
from ps_ray.store.layout import SweepLayout


@dataclass(frozen=True)
class StageLoad:
    """One stage's work: its trials, their env steps (training and evaluation) and updates."""

    stage: str
    trials: list[TrainSpec | None]  # None: an evaluation-only trial (zero-shot)
    env_steps: int
    updates: int
    eval_steps: int


@dataclass(frozen=True)
class Rates:
    """Per-core seconds. ``update_s`` is a gradient update of all five SAC nets at batch 256 as
    ``fixed + per_unit * batch * hidden**2 / 256**3``; relative methods multiply updates by
    ``relative_factor`` (they re-embed the anchors in every forward pass)."""

    trial_s: float  # starting a trial: Ray worker, envs, RLlib build
    stage_s: float  # starting a stage: Ray and Tune
    env_step_s: float  # one collected env step (physics + acting)
    eval_step_s: float  # one greedy evaluation step
    update_fixed_s: float
    update_per_unit_s: float
    relative_factor: float
    source: str

    def update_s(self, spec: TrainSpec) -> float:
        unit = spec.batch_size * spec.hidden**2 / 256**3
        factor = self.relative_factor if uses_anchors(spec.method) else 1.0
        return (self.update_fixed_s + self.update_per_unit_s * unit) * factor


# Measured for hidden 256 on a 2-core machine (docs/cost.md), rounded up by about 1.5x.
DEFAULT_RATES = Rates(
    trial_s=20.0,
    stage_s=15.0,
    env_step_s=0.006,
    eval_step_s=0.004,
    update_fixed_s=0.01,
    update_per_unit_s=0.05,
    relative_factor=1.5,
    source="conservative defaults (run `ps-ray bench rates` to measure this machine)",
)


def rates_path() -> Path:
    root = os.environ.get("PS_RAY_CACHE") or Path.home() / ".cache" / "ps_ray"
    return Path(root) / f"rates-{socket.gethostname()}.json"


def load_rates(path: Path | None = None) -> Rates:
    """This machine's cached rates, else the defaults. A cache file that does not parse as rates
    is ignored (the defaults are used and the source says why)."""
    path = path or rates_path()
    try:
        data = json.loads(path.read_text())
        return Rates(
            **{f.name: type(getattr(DEFAULT_RATES, f.name))(data[f.name]) for f in dataclasses.fields(Rates)}
        )
    except FileNotFoundError:
        return DEFAULT_RATES
    except (OSError, ValueError, TypeError, KeyError):
        return dataclasses.replace(
            DEFAULT_RATES, source=f"conservative defaults ({path} is not a rates file)"
        )


def _train_load(stage: str, specs: list[TrainSpec]) -> StageLoad:
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
    """(task source, robot source) pairs the stitching stages will build for one method, by the
    rule of :func:`ps_ray.stitching.stitch.combos`: another task, another arm, the same interface, for
    relative methods the same anchor set (the same task-input width), and the seeds that
    ``pairing`` joins (:func:`ps_ray.specs.sweep.seed_pairs`)."""
    from ps_ray.envs.robots import arm
    from ps_ray.specs.sweep import seed_pairs, task_input_dim

    cells = [t for t in spec.trials() if t.method == method]
    joined = {(task_seed, robot_seed) for _, task_seed, robot_seed in seed_pairs(spec.seeds, pairing)}
    return [
        (t, r)
        for t in cells
        for r in cells
        if (t.seed, r.seed) in joined
        and t.interface_dim == r.interface_dim
        and t.task != r.task
        and arm(t.robot) != arm(r.robot)
        and (not uses_anchors(t.method) or task_input_dim(t.task) == task_input_dim(r.task))
    ]


def workload(spec: SweepSpec) -> list[StageLoad]:
    """The work of every stage the spec runs, in order."""
    from ps_ray.specs.sweep import anchor_sources

    loads = []
    if "train" in spec.stages:
        plain = anchor_sources(spec) if spec.anchors.policy == "plain" and not spec.anchors.file else []
        if plain:
            loads.append(_train_load("anchors_plain", plain))
        loads.append(_train_load("train", spec.trials()))
    if "zero_shot" in spec.stages:
        methods = list(spec.zero_shot.methods) or list(spec.methods)
        pairing = spec.zero_shot.pairs
        n = sum(
            len(stitch_pairs(spec, m, pairing)) * (1 + len(spec.zero_shot.translations(m))) for m in methods
        )
        # each trial evaluates its pair and up to three controls (ps_ray.stitching.stitch.controls)
        steps = (
            n * (1 + len(CONTROL_ROLES)) * spec.zero_shot.episodes * spec.zero_shot.repeats * EPISODE_STEPS
        )
        batches = -(-n // spec.zero_shot.pairs_per_trial)  # trials of pairs_per_trial pairs each
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
                key = json.dumps(run.to_dict(), sort_keys=True, default=str)
                targets.setdefault(key, run)
                if few.unstitched and task_input_dim(r.task) == task_input_dim(t.task):
                    unstitched.setdefault(key + json.dumps(r.task, sort_keys=True, default=str), run)
        runs += unstitched.values()  # each pair's robot source fine-tuned as it is
        if few.scratch:  # one from-scratch run per distinct target
            runs += targets.values()
        loads.append(_train_load("few_shot", runs))
    return loads


@dataclass(frozen=True)
class Projection:
    loads: list[StageLoad]
    core_s: float
    wall_s_here: float
    wall_s_on: float
    cores_here: int
    cores_on: int
    rates: Rates


def _trial_s(spec: TrainSpec | None, load: StageLoad, rates: Rates, n: int) -> float:
    if spec is None:  # an evaluation-only trial: its share of the stage's evaluation steps
        return rates.trial_s + load.eval_steps / max(n, 1) * rates.eval_step_s
    own = _train_load(load.stage, [spec])
    return (
        rates.trial_s
        + own.env_steps * rates.env_step_s
        + own.updates * rates.update_s(spec)
        + own.eval_steps * rates.eval_step_s
    )


def trial_seconds(load: StageLoad, rates: Rates) -> list[float]:
    """Projected core-seconds of each trial of a stage."""
    return [_trial_s(s, load, rates, len(load.trials)) for s in load.trials]


def _wall_s(loads: list[StageLoad], rates: Rates, cores: int, max_concurrent: int | None) -> float:
    total = 0.0
    for load in loads:
        times = sorted(trial_seconds(load, rates), reverse=True)
        slots = max(1, min(cores, max_concurrent or cores, len(times)))
        total += rates.stage_s + max(sum(times) / slots, times[0] if times else 0.0)
    return total


def project(spec: SweepSpec, cores_on: int = 64, rates: Rates | None = None) -> Projection:
    """Core-seconds of the whole sweep, and its wall time here and on ``cores_on`` cores."""
    if not isinstance(cores_on, int) or cores_on < 1:
        raise SpecError(f"--cores must be a positive number of cores, got {cores_on!r}")
    rates = rates or load_rates()
    loads = workload(spec)
    core_s = sum(sum(trial_seconds(load, rates)) for load in loads)
    here = os.cpu_count() or 1
    return Projection(
        loads,
        core_s,
        _wall_s(loads, rates, here, spec.max_concurrent),
        _wall_s(loads, rates, cores_on, None),
        here,
        cores_on,
        rates,
    )


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    if seconds < 3 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def describe(p: Projection) -> list[str]:
    """The projection as lines for the terminal."""
    lines = [f"  {'stage':14} {'trials':>7} {'env steps':>14} {'updates':>13} {'eval steps':>13}"]
    for load in p.loads:
        counts = (load.env_steps, load.updates, load.eval_steps)
        lines.append(
            f"  {load.stage:14} {len(load.trials):>7,} {counts[0]:>14,} {counts[1]:>13,} {counts[2]:>13,}"
        )
    trials = sum(len(load.trials) for load in p.loads)
    lines += [
        f"  total: {trials:,} trials, {sum(x.env_steps for x in p.loads):,} training env steps, "
        f"{sum(x.updates for x in p.loads):,} gradient updates",
        f"  projected cost: {p.core_s / 3600:,.1f} core-hours; wall time {_duration(p.wall_s_here)} "
        f"on this machine ({p.cores_here} cores), {_duration(p.wall_s_on)} on {p.cores_on} cores",
        f"  rates: {p.rates.source}",
    ]
    if any(s is not None and s.target_success is not None for load in p.loads for s in load.trials):
        lines.append("  budgets with a success target are caps: sources that converge early cost less")
    return lines


def spent(root: Path) -> dict[str, tuple[int, float]]:
    """What each stage of a sweep folder actually used: (attempts, core-seconds inside trials,
    from the last result of every attempt, retries and resumed attempts included)."""
    from ps_ray.store.attempts import PARAMS_FILE, read_rows

    out = {}
    for stage, folder in SweepLayout(root).stage_folders().items():
        attempts = [p.parent for p in sorted(folder.glob(f"*/{PARAMS_FILE}"))]
        if attempts:
            lasts = [rows[-1] for a in attempts if (rows := read_rows(a))]
            out[stage] = (len(attempts), sum(float(r.get("time_total_s", 0.0)) for r in lasts))
    return out


SMALLEST_TELLING_BUDGET = 5_000  # env steps: below this no method learns reach (docs/alignment.md)
TELLING_STUDY = "sweeps/alignment_reach.yaml (about 2 h on 2 CPUs)"


def budget_note(spec: SweepSpec) -> str | None:
    """A plain warning when a sweep's sources train too briefly for its numbers to mean anything."""
    steps = max(t.env_steps for t in spec.trials())
    if steps >= SMALLEST_TELLING_BUDGET:
        return None
    return (
        f"With at most {steps:,} env steps per source, success figures are near zero by design: "
        f"this run shows that the machinery works, not whether stitching does. The study that "
        f"shows the effect is {TELLING_STUDY}."
    )
