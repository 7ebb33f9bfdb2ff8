"""A sweep's stages on one node kind: how many trials run at once, how long each takes there, and
what the run holds (vCPU-, GPU- and node-hours). The model is docs/cost.md's "On a cluster"."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ps_ray.analysis.hardware import (
    GPU_LAYOUT,
    GpuRates,
    NodeKind,
    Rates,
    cpu_factor,
    update_factor,
)
from ps_ray.analysis.workload import StageLoad, train_load
from ps_ray.specs.resources import StageResources
from ps_ray.specs.stages import STAGES_WITH_TRIALS
from ps_ray.specs.stages import stage as stage_record
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.train import TrainSpec


@dataclass(frozen=True)
class OnKind:
    """The whole sweep on ``kind``: wall time and what its trials held, per stage resources."""

    kind: NodeKind
    resources: dict[str, StageResources]
    at_once: dict[str, int]  # stage -> trials running at once
    wall_s: float
    vcpu_s: float
    gpu_s: float
    node_s: float
    notes: tuple[str, ...]


def placed(spec: SweepSpec, kind: NodeKind) -> tuple[dict[str, StageResources], list[str]]:
    """Each stage's request as ``kind`` runs it: a GPU share is dropped where there is no GPU,
    and training on a GPU kind that the spec gives none gets :data:`GPU_LAYOUT`."""
    out, notes = {}, []
    for stage in STAGES_WITH_TRIALS:
        r = getattr(spec.resources, stage)
        if r.gpu and not kind.gpus:
            out[stage] = StageResources(cpu=r.cpu)
            notes.append(f"{stage}: its gpu {r.gpu:g} dropped, trained on the CPU (no GPU here)")
        elif not r.gpu and kind.gpus and stage_record(stage).trains:
            out[stage] = GPU_LAYOUT
            notes.append(
                f"{stage}: cpu {GPU_LAYOUT.cpu:g}, gpu {GPU_LAYOUT.gpu:g} per trial "
                f"(the spec asks no GPU; docs/cluster.md's layout)"
            )
        else:
            out[stage] = r
    return out, notes


def trial_time(
    spec: TrainSpec | None,
    load: StageLoad,
    rates: Rates,
    gpu: GpuRates,
    r: StageResources,
    effective: float,
    sources: int = 1,
) -> float:
    """Seconds of one trial (``spec`` None: an evaluation-only trial) at ``effective`` cores;
    ``sources``: the sources it trains (a population's K, each member's work counted)."""
    cpu = cpu_factor(effective)
    if spec is None:
        return (rates.trial_s + load.eval_steps / max(len(load.trials), 1) * rates.eval_step_s) * cpu
    own = train_load(load.stage, [spec] * sources)
    if r.gpu:  # a population's K members update as one (launch-bound until K x busy is more)
        unit = rates.size_unit(spec) * sources
        update = gpu.update_s(unit, r.gpu, min(1.0, effective), rates.method_factor(spec)) / sources
    else:
        update = rates.update_s(spec) * update_factor(effective)
    serial = rates.trial_s + own.env_steps * rates.env_step_s + own.eval_steps * rates.eval_step_s
    return serial * cpu + own.updates * update


def on_kind(
    spec: SweepSpec,
    loads: list[StageLoad],
    rates: Rates,
    gpu: GpuRates,
    kind: NodeKind,
    max_concurrent: int | None = None,
) -> OnKind:
    """The stages one after another on ``kind``'s nodes, trials spread evenly over the nodes
    they need; a stage takes the longer of (trial seconds / trials at once) and its longest trial."""
    resources, notes = placed(spec, kind)
    notes = [n for n in notes if n.split(":")[0] in {load.stage for load in loads}]
    at_once: dict[str, int] = {}
    wall = vcpu = gpu_s = node = 0.0
    for load in loads:
        r = resources[stage_record(load.stage).name]  # the anchors' plain sources: as training
        n, per = len(load.trials), kind.per_node(r)
        if not n:
            continue
        if per < 1:
            notes.append(f"{load.stage}: a trial asks cpu {r.cpu:g} > the {kind.vcpus} vCPUs of a node")
            return OnKind(kind, resources, at_once, math.inf, math.inf, math.inf, math.inf, tuple(notes))
        slots = max(1, min(per * kind.nodes, max_concurrent or n, n))
        nodes = math.ceil(slots / per)
        effective = kind.effective_cores(math.ceil(slots / nodes), r.threads)
        times = [
            trial_time(s, load, rates, gpu, r, effective, load.sources(i)) for i, s in enumerate(load.trials)
        ]
        stage_wall = rates.stage_s + max(sum(times) / slots, max(times))
        at_once[load.stage] = slots
        wall += stage_wall
        vcpu += sum(times) * r.cpu
        gpu_s += sum(times) * r.gpu
        node += nodes * stage_wall
    return OnKind(kind, resources, at_once, wall, vcpu, gpu_s, node, tuple(notes))
