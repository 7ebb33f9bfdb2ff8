"""What a sweep will cost before it runs: trials, env steps, gradient updates, core-hours, wall time.

The workload is counted from the spec alone (:mod:`ps_ray.analysis.workload`). Budgets with a
success target are caps, so the projection is an upper bound for them.

Seconds come from per-core rates (:class:`Rates`): measured on this machine by
``ps-ray bench rates`` and cached, or :data:`DEFAULT_RATES`, conservative figures stated as such.
On this machine and on cluster.yaml's node kinds the hardware model of
:mod:`ps_ray.analysis.hardware` applies: physical cores, not vCPUs, torch threads per trial, and a
GPU's update time (docs/cost.md, "On a cluster").
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
from dataclasses import dataclass
from pathlib import Path

from ps_ray.analysis.hardware import (
    CLUSTERS,
    DEFAULT_GPU_RATES,
    DEFAULT_RATES,
    GpuRates,
    NodeKind,
    Rates,
    this_machine,
)
from ps_ray.analysis.placement import OnKind, on_kind
from ps_ray.analysis.workload import StageLoad, train_load, workload
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.train import SpecError, TrainSpec
from ps_ray.store.layout import SweepLayout


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


@dataclass(frozen=True)
class Projection:
    """``core_s``: per-core seconds (one trial per core, nothing shared); ``wall_s_on``: on
    ``cores_on`` cores counted the same way; ``here`` and ``clusters``: the hardware model."""

    loads: list[StageLoad]
    core_s: float
    wall_s_here: float
    wall_s_on: float
    cores_here: int
    cores_on: int
    rates: Rates
    here: OnKind
    clusters: tuple[OnKind, ...]
    gpu_rates: GpuRates


def _trial_s(spec: TrainSpec | None, load: StageLoad, rates: Rates, n: int, sources: int = 1) -> float:
    if spec is None:  # an evaluation-only trial: its share of the stage's evaluation steps
        return rates.trial_s + load.eval_steps / max(n, 1) * rates.eval_step_s
    own = train_load(load.stage, [spec] * sources)  # a population: each member's work
    return (
        rates.trial_s
        + own.env_steps * rates.env_step_s
        + own.updates * rates.update_s(spec)
        + own.eval_steps * rates.eval_step_s
    )


def trial_seconds(load: StageLoad, rates: Rates) -> list[float]:
    """Projected core-seconds of each trial of a stage."""
    return [_trial_s(s, load, rates, len(load.trials), load.sources(i)) for i, s in enumerate(load.trials)]


def _wall_s(loads: list[StageLoad], rates: Rates, cores: int, max_concurrent: int | None) -> float:
    total = 0.0
    for load in loads:
        times = sorted(trial_seconds(load, rates), reverse=True)
        slots = max(1, min(cores, max_concurrent or cores, len(times)))
        total += rates.stage_s + max(sum(times) / slots, times[0] if times else 0.0)
    return total


def project(
    spec: SweepSpec,
    cores_on: int = 64,
    rates: Rates | None = None,
    *,
    kinds: tuple[NodeKind, ...] = CLUSTERS,
    here: NodeKind | None = None,
    gpu_rates: GpuRates = DEFAULT_GPU_RATES,
) -> Projection:
    """Core-seconds of the whole sweep; its wall time on ``cores_on`` ideal cores, on this
    machine (``here``) and on each of ``kinds`` (cluster.yaml's CPU and GPU workers)."""
    if not isinstance(cores_on, int) or cores_on < 1:
        raise SpecError(f"--cores must be a positive number of cores, got {cores_on!r}")
    rates = rates or load_rates()
    loads = workload(spec)
    core_s = sum(sum(trial_seconds(load, rates)) for load in loads)
    local = on_kind(spec, loads, rates, gpu_rates, here or this_machine(), spec.max_concurrent)
    return Projection(
        loads,
        core_s,
        local.wall_s,
        _wall_s(loads, rates, cores_on, None),
        local.kind.vcpus,
        cores_on,
        rates,
        local,
        tuple(on_kind(spec, loads, rates, gpu_rates, kind) for kind in kinds),
        gpu_rates,
    )


def _duration(seconds: float) -> str:
    if seconds == float("inf"):
        return "never"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    if seconds < 3 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def _hardware_lines(p: Projection) -> list[str]:
    """This machine and each cluster kind side by side, then how each runs the stages."""
    lines = [f"  {'on':56} {'wall time':>10} {'vCPU-hours':>11} {'GPU-hours':>10} {'node-hours':>11}"]
    for o in (p.here, *p.clusters):
        lines.append(
            f"  {o.kind.name + ': ' + o.kind.describe():56} {_duration(o.wall_s):>10} "
            f"{o.vcpu_s / 3600:>11,.1f} {o.gpu_s / 3600:>10,.1f} {o.node_s / 3600:>11,.1f}"
        )
    for o in (p.here, *p.clusters):
        at_once = ", ".join(f"{stage} {n:,}" for stage, n in o.at_once.items())
        lines.append(f"    {o.kind.name}: trials at once: {at_once or 'none'}")
        lines += [f"    {o.kind.name}: {note}" for note in o.notes]
    return lines


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
        f"on this machine ({p.cores_here} cores), {_duration(p.wall_s_on)} on {p.cores_on} cores "
        f"(one trial per physical core)",
        *_hardware_lines(p),
        f"  rates: {p.rates.source}",
        f"  {p.gpu_rates.source}; hyperthreads, threads and GPU sharing as in docs/cost.md",
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
# the study where a stitched policy does what neither source can, confirmed on fresh seeds
# (docs/results/confirm2.md), and the command that shows a stitch of the first confirmation
TELLING_STUDY = (
    "sweeps/confirm2.yaml (co-trained grids' held-out cells stitched zero-shot at 0.87 and modules "
    "trained apart joined by affine@outcome at 0.97, over eight fresh seeds, against sources at "
    "0.00, chance at 0.08 and a task-blind floor of 0.50); `ps-ray demo` scores a stitch of the "
    "first confirmation (sweeps/confirm.yaml) beside those controls in under a minute"
)


def budget_note(spec: SweepSpec) -> str | None:
    """A plain warning when a sweep's sources train too briefly for its numbers to mean anything."""
    steps = max(t.env_steps for t in spec.trials())
    if steps >= SMALLEST_TELLING_BUDGET:
        return None
    return (
        f"With at most {steps:,} env steps per source, success figures are near zero by design: "
        f"this run shows that the machinery works, not whether stitching does. The study that "
        f"shows stitching transfer is {TELLING_STUDY}."
    )
