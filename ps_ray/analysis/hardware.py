"""The hardware a sweep's trials run on, as data: node kinds (this machine, cluster.yaml's worker
types), the public GPU figures, and how a trial's work speeds up or slows down on a node. Every
figure here is an assumption or a public number, stated in docs/cost.md ("On a cluster")."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

from ps_ray.specs.resources import StageResources
from ps_ray.specs.train import TrainSpec

# A vCPU whose sibling hyperthread is busy is worth this much of a physical core: two busy
# siblings give 1.2 cores (an assumption for dense float maths, which shares the core's FPUs;
# counting vCPUs as cores is then 1.67x optimistic, inside the 1.3-1.8x of issue 30).
HT_WORTH = 0.6
# Amdahl: the share of a gradient update that spreads over torch threads (an assumption, kept
# low: at batch 256 and hidden 256 the matrix products are small, and the rest is Python).
PARALLEL_FRACTION = 0.5
# What a GPU training trial asks for when a sweep asks none (docs/cluster.md's layout).
GPU_LAYOUT = StageResources(cpu=2, gpu=0.25)


@dataclass(frozen=True)
class NodeKind:
    """``nodes`` nodes of one instance type, each with ``vcpus`` vCPUs on ``cores`` physical
    cores and ``gpus`` GPUs. ``node_type`` names its entry in cluster.yaml ("" for none)."""

    name: str
    instance: str
    nodes: int
    vcpus: int
    cores: int
    gpus: int = 0
    gpu: str = ""
    node_type: str = ""

    def per_node(self, r: StageResources) -> int:
        """Trials at request ``r`` that fit on one node (0: none, e.g. a GPU share on no GPU)."""
        fit = math.floor(self.vcpus / r.cpu + 1e-9)
        if r.gpu:
            fit = min(fit, math.floor(self.gpus / r.gpu + 1e-9))
        return fit

    def throughput(self, busy: float) -> float:
        """Physical cores' worth of ``busy`` busy threads on one node: a full core each up to
        ``cores``, then each thread that shares a core adds 2 x HT_WORTH - 1; capped at the vCPUs."""
        busy = min(busy, self.vcpus)
        shared = max(0.0, busy - self.cores)
        return min(busy, self.cores) + shared * (2 * HT_WORTH - 1)

    def effective_cores(self, on_node: int, threads: int) -> float:
        """A trial's share of its node in physical cores, with ``on_node`` trials of ``threads``
        torch threads each on it; time-sliced when the threads outnumber the vCPUs."""
        busy = on_node * threads
        return threads * self.throughput(busy) / max(busy, 1)

    def describe(self) -> str:
        gpus = f", {self.gpus} {self.gpu}" if self.gpus else ""
        each = f"{self.vcpus} vCPUs, {self.cores} cores{gpus}"
        return f"{self.nodes} x {self.instance} ({each})" if self.instance else each


# cluster.yaml's worker types (tests/test_cost.py checks they agree). c6i and g5 instances run two
# hyperthreads per physical core (AWS's instance type pages): 16 vCPUs = 8 cores, 8 vCPUs = 4.
CPU_CLUSTER = NodeKind("CPU cluster", "c6i.4xlarge", 4, 16, 8, node_type="cpu_worker")
GPU_CLUSTER = NodeKind("GPU cluster", "g5.2xlarge", 2, 8, 4, 1, "A10G", node_type="gpu_worker")
CLUSTERS = (CPU_CLUSTER, GPU_CLUSTER)


def physical_cores(vcpus: int) -> int:
    """This machine's physical cores: distinct hyperthread sibling sets (Linux), else ``vcpus``."""
    siblings = {
        p.read_text().strip()
        for p in Path("/sys/devices/system/cpu").glob("cpu[0-9]*/topology/thread_siblings_list")
    }
    return min(vcpus, len(siblings)) if siblings else vcpus


def this_machine() -> NodeKind:
    """This machine as one node; a GPU here is not looked for (that would load torch)."""
    vcpus = os.cpu_count() or 1
    return NodeKind("this machine", "", 1, vcpus, physical_cores(vcpus))


@dataclass(frozen=True)
class GpuRates:
    """Seconds per SAC update on a GPU, at batch 256 and hidden 256. An eager update is
    launch-bound: ``launch_s`` of host work (Python and kernel launches, on the trial's CPU),
    while the GPU itself is busy ``busy_s`` (grows with batch x hidden^2). A trial at GPU share
    ``s`` gets ``s`` of the GPU: its update takes max(launch_s, busy_s / s)."""

    launch_s: float
    busy_s: float
    source: str

    def update_s(self, unit: float, share: float, cpu_speed: float, factor: float = 1.0) -> float:
        """One update of a trial at ``share``, ``unit`` = batch x hidden^2 / 256^3, host CPU at
        ``cpu_speed`` of a core, ``factor`` for relative methods (more kernels per update)."""
        return factor * max(self.launch_s / cpu_speed, self.busy_s * unit / share)


# ps_ray's own SAC update on an H100 (`ps-ray bench update --devices cpu cuda --dims 15,8,7`,
# session 30, docs/cost.md "A GPU update, measured"): eager, batch 256, hidden 256, the ablation
# 11.2 ms on one host thread whose CPU update takes 30 ms, as on the 2-core machine the rates are
# measured on. Batch 65,536 took 17.9 ms: the GPU's own work at batch 256 is at most 1/256 of that.
DEFAULT_GPU_RATES = GpuRates(
    launch_s=0.0112,
    busy_s=0.0179 / 256,
    source="GPU: ps_ray's eager update measured on an H100 (11.2 ms, ablation, batch 256)",
)


def cpu_factor(effective: float) -> float:
    """Time multiplier of single-threaded work (env steps, evaluation) at ``effective`` cores."""
    return 1 / min(1.0, effective)


def update_factor(effective: float, p: float = PARALLEL_FRACTION) -> float:
    """Time multiplier of a CPU update at ``effective`` cores (Amdahl, parallel fraction ``p``);
    never above :func:`cpu_factor`, and falls as ``effective`` grows."""
    return (1 - p) / min(1.0, effective) + p / effective


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

    @staticmethod
    def size_unit(spec: TrainSpec) -> float:
        return spec.batch_size * spec.hidden**2 / 256**3

    def method_factor(self, spec: TrainSpec) -> float:
        return self.relative_factor if spec.resolved.uses_anchors else 1.0

    def update_s(self, spec: TrainSpec) -> float:
        per_update = self.update_fixed_s + self.update_per_unit_s * self.size_unit(spec)
        return per_update * self.method_factor(spec)


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
