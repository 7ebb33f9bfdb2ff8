"""`ps-ray sweep FILE --check`: the workload counted from the spec and its projected cost."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from ps_ray.analysis.cost import describe, load_rates, project, workload
from ps_ray.analysis.hardware import (
    CLUSTERS,
    CPU_CLUSTER,
    DEFAULT_GPU_RATES,
    DEFAULT_RATES,
    GPU_CLUSTER,
    HT_WORTH,
    PARALLEL_FRACTION,
    NodeKind,
    Rates,
)
from ps_ray.specs.resources import ResourcesSpec, StageResources
from ps_ray.specs.sweep import SweepSpec, load_sweep

ROOT = Path(__file__).resolve().parents[1]
SWEEPS = ROOT / "sweeps"
RATES = Rates(
    trial_s=10.0,
    stage_s=5.0,
    env_step_s=0.01,
    eval_step_s=0.002,
    update_fixed_s=0.02,
    update_per_unit_s=0.1,
    relative_factor=2.0,
    source="test",
)


def one_trial(method: str = "ablation", **train) -> SweepSpec:
    return SweepSpec(
        name="one",
        methods=(method,),
        robots=("panda",),
        tasks=("reach",),
        seeds=(1,),
        train={"env_steps": 2000, "learning_starts": 1000, "eval_every": 5, "eval_episodes": 4, **train},
    )


def many_trials(n: int, **resources) -> SweepSpec:
    """``n`` one-stage training trials (ablation: no anchor stage) asking ``resources`` each."""
    train = StageResources(**resources) if resources else StageResources()
    seeds = tuple(range(1, n + 1))
    return dataclasses.replace(one_trial(), seeds=seeds, resources=ResourcesSpec(train=train))


def test_the_workload_of_the_smoke_sweep_is_counted_from_its_spec():
    loads = {load.stage: load for load in workload(load_sweep(SWEEPS / "smoke.yaml"))}
    assert list(loads) == ["anchors_plain", "train", "zero_shot", "few_shot"]
    # 2 methods x 2 robots x 2 reach halves x 2 seeds, 400 env steps each
    assert len(loads["train"].trials) == 16 and loads["train"].env_steps == 16 * 400
    assert loads["train"].updates == 16 * int((400 - 200) * 0.4)
    assert len(loads["anchors_plain"].trials) == 2  # a plain policy per reach half
    # per method and seed, each of the 4 task modules (half X, Ra) meets the one robot module of
    # (the other half, the other arm): 4 pairs; 16 pairs run as 2 trials of 8
    assert len(loads["zero_shot"].trials) == 2
    # each pair evaluated with its three controls (robot source, task source, oracle), and chance
    # (two policies) once on each of the 4 target envs (2 arms x 2 halves) per training seed (2:
    # each seed's own episodes); reach holds one target per scene, so no task-blind floor
    assert loads["zero_shot"].eval_steps == (16 * 4 + 4 * 2 * 2) * 2 * 2 * 50
    assert loads["zero_shot"].updates == 0
    # max_pairs 1 per method, plus one from-scratch run per target
    # and one unstitched start (the pair's robot source as it is) per pair
    assert len(loads["few_shot"].trials) == 2 * 3 and loads["few_shot"].env_steps == 6 * 300


def test_the_grid_stage_is_priced_per_cell_and_its_held_out_pairs_beside_the_alone_ones():
    loads = {load.stage: load for load in workload(load_sweep(SWEEPS / "cotrain.yaml"))}
    assert list(loads) == ["train", "grid", "zero_shot"]
    # 5 seeds x 2 held-out cells = 10 grids, each training its 3 other cells to the 16k cap
    assert len(loads["grid"].trials) == 10 and loads["grid"].env_steps == 10 * 3 * 16000
    # alone: 4 targets x 5 seeds, same and cross seed = 40 pairs; co-trained: 2 held-out targets x 5
    # seeds x 2 pairings = 20 pairs; each with 3 controls and the ceiling (its robot source told the
    # task); on each of 4 targets and for each of the 5 seeds' episodes, chance (2 policies) and the
    # task-blind floor (one run per marker, 2)
    assert loads["zero_shot"].eval_steps == ((40 + 20) * 5 + 4 * 5 * (2 + 2)) * 30 * 2 * 50


def test_projection_is_the_rates_times_the_work():
    p = project(one_trial(), cores_on=8, rates=RATES)
    # 10 s start + 2,000 env steps + 400 updates x (0.02 + 0.1 x 1) + 4 evaluations x 4 episodes x 50
    expected = 10 + 2000 * 0.01 + 400 * 0.12 + 800 * 0.002
    assert p.core_s == pytest.approx(expected)
    assert p.wall_s_here == pytest.approx(5 + expected) and p.wall_s_on == pytest.approx(5 + expected)
    # PS: updates cost 2x (anchors re-embedded), and a plain policy is trained for its anchors first
    relative = project(one_trial("ps"), rates=RATES)
    assert [load.stage for load in relative.loads] == ["anchors_plain", "train"]
    assert relative.core_s == pytest.approx(expected + (expected + 400 * 0.12))
    small = project(one_trial(hidden=64), rates=RATES)
    assert small.core_s == pytest.approx(expected - 400 * 0.1 * (1 - 1 / 16))


def test_more_cores_shorten_the_wall_time_not_the_core_hours():
    spec = dataclasses.replace(load_sweep(SWEEPS / "alignment_reach.yaml"), max_concurrent=None)
    few, many = project(spec, cores_on=4, rates=RATES), project(spec, cores_on=64, rates=RATES)
    assert few.core_s == many.core_s
    assert many.wall_s_on < few.wall_s_on / 4


def test_rates_come_from_the_cache_or_stated_defaults(tmp_path):
    path = tmp_path / "rates.json"
    assert load_rates(path) == DEFAULT_RATES and "conservative defaults" in DEFAULT_RATES.source
    path.write_text(json.dumps(dataclasses.asdict(RATES)))
    assert load_rates(path) == RATES
    path.write_text('{"trial_s": "fast"}')
    fallback = load_rates(path)
    assert fallback.env_step_s == DEFAULT_RATES.env_step_s and str(path) in fallback.source


@pytest.mark.e2e
@pytest.mark.parametrize("command", ["sweep", "run"])
def test_check_prints_the_projection_and_refuses_a_bad_core_count(tmp_path, command):
    """`ps-ray sweep FILE --check` and `ps-ray run FILE --check` price every stage the file names
    and write nothing, not even the sweep's folder."""
    (tmp_path / "rates").mkdir()
    env = {"PS_RAY_CACHE": str(tmp_path / "rates")}
    smoke, store = str(SWEEPS / "smoke.yaml"), str(tmp_path / "store")
    run = subprocess.run(
        [sys.executable, "-m", "ps_ray.cli", command, smoke, "--check", "--cores", "16", "--storage", store],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        timeout=120,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "total: 26 trials, 9,000 training env steps" in run.stdout
    assert "on 16 cores" in run.stdout and "rates: conservative defaults" in run.stdout
    # this machine, then cluster.yaml's two worker kinds side by side, with the GPU figures' source
    lines = run.stdout.splitlines()
    here = next(i for i, line in enumerate(lines) if line.startswith("  this machine: "))
    assert lines[here + 1].startswith("  CPU cluster: 4 x c6i.4xlarge (16 vCPUs, 8 cores) ")
    assert lines[here + 2].startswith("  GPU cluster: 2 x g5.2xlarge (8 vCPUs, 4 cores, 1 A10G) ")
    assert "measured on an H100 (11.2 ms" in run.stdout
    assert not list((tmp_path / "rates").iterdir()) and not (tmp_path / "store").exists()  # nothing written
    bad = subprocess.run(
        [sys.executable, "-m", "ps_ray.cli", command, smoke, "--check", "--cores", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 2 and not bad.stdout  # refused before a trial line is printed
    (line,) = bad.stderr.strip().splitlines()
    assert line.endswith("argument --cores: expected a positive integer, got 0")


def test_a_success_target_makes_the_budget_a_cap(tmp_path):
    data = yaml.safe_load((SWEEPS / "smoke.yaml").read_text())
    data["train"]["target_success"] = 0.9
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    assert any("caps" in line for line in describe(project(load_sweep(tmp_path / "s.yaml"), rates=RATES)))
    assert not any(
        "caps" in line for line in describe(project(load_sweep(SWEEPS / "smoke.yaml"), rates=RATES))
    )


# -- on a cluster: physical cores, threads, GPU shares (docs/cost.md, "On a cluster") -----------
def test_the_cluster_kinds_are_cluster_yamls_worker_types():
    types = yaml.safe_load((ROOT / "cluster.yaml").read_text())["available_node_types"]
    for kind in CLUSTERS:
        node = types[kind.node_type]
        assert node["node_config"]["InstanceType"] == kind.instance
        assert node["resources"] == {"CPU": kind.vcpus, **({"GPU": kind.gpus} if kind.gpus else {})}
        assert node["max_workers"] == kind.nodes
        assert kind.cores * 2 == kind.vcpus  # c6i and g5: two hyperthreads per core
    assert CPU_CLUSTER.nodes * CPU_CLUSTER.vcpus == 64 and GPU_CLUSTER.gpus == 1


def test_a_cluster_counts_physical_cores_not_vcpus():
    spec = many_trials(64)
    as_cores = dataclasses.replace(CPU_CLUSTER, cores=CPU_CLUSTER.vcpus)  # 16 vCPUs as 16 cores
    p = project(spec, cores_on=64, rates=RATES, kinds=(CPU_CLUSTER, as_cores))
    real, ideal = p.clusters
    assert real.at_once == ideal.at_once == {"train": 64}
    # every trial's work runs on a vCPU whose sibling is busy: worth HT_WORTH of a core
    assert (real.wall_s - RATES.stage_s) == pytest.approx((ideal.wall_s - RATES.stage_s) / HT_WORTH)
    assert real.vcpu_s == pytest.approx(ideal.vcpu_s / HT_WORTH)
    # 16 cores per node is what `--cores 64` assumes: the same wall time
    assert ideal.wall_s == pytest.approx(p.wall_s_on)
    assert real.node_s == pytest.approx(4 * real.wall_s)  # all four nodes held throughout
    # 8 trials need one node, and get a physical core each: no hyperthreading penalty
    few = project(many_trials(8), rates=RATES, kinds=(CPU_CLUSTER, as_cores)).clusters
    assert few[0].wall_s == pytest.approx(few[1].wall_s) and few[0].node_s == pytest.approx(few[0].wall_s)


def trial_wall_s(kind: NodeKind, n: int, cpu: float) -> float:
    """Wall time of one trial of ``n`` asking ``cpu`` vCPUs each (the stage start excluded)."""
    p = project(many_trials(n, cpu=cpu), rates=RATES, kinds=(kind,))
    (on,) = p.clusters
    slots = on.at_once["train"]
    return (on.wall_s - RATES.stage_s) * slots / n


@pytest.mark.parametrize("n", [1, 64])
def test_more_threads_per_trial_never_make_a_trial_slower(n):
    cpus = [0.5, 1, 1.5, 2, 3, 4, 6, 8, 16]
    times = [trial_wall_s(CPU_CLUSTER, n, cpu) for cpu in cpus]
    assert times == sorted(times, reverse=True), dict(zip(cpus, times))
    # on full nodes two threads make one trial's update faster by Amdahl: a 2-vCPU trial has
    # 2 x HT_WORTH = 1.2 cores, its env steps a full core
    own = 10 + 2000 * 0.01 + 800 * 0.002  # start, env steps, evaluation: one core's seconds
    updates = 400 * 0.12
    one, two = times[cpus.index(1)], times[cpus.index(2)]
    if n == 64:
        assert one == pytest.approx((own + updates) / HT_WORTH)
        p = PARALLEL_FRACTION
        assert two == pytest.approx(own + updates * ((1 - p) + p / (2 * HT_WORTH)))


@pytest.mark.parametrize("share", [1, 0.5, 0.25, 0.125])
def test_a_gpu_share_packs_one_over_share_trials_per_gpu(share):
    roomy = NodeKind("GPU", "g", nodes=2, vcpus=64, cores=32, gpus=1, gpu="X")  # CPUs never limit
    assert roomy.per_node(StageResources(cpu=1, gpu=share)) == round(1 / share)
    p = project(many_trials(32, cpu=1, gpu=share), rates=RATES, kinds=(roomy, CPU_CLUSTER))
    gpu, cpu = p.clusters
    assert gpu.at_once == {"train": min(32, round(2 / share))}
    assert gpu.gpu_s == pytest.approx(gpu.vcpu_s * share)  # each trial holds its share
    # a GPU update takes max(launch, busy / share): packing more trials per GPU only slows
    # each once the GPU, not the host, is the bound
    g = DEFAULT_GPU_RATES
    own = 10 + 2000 * 0.01 + 800 * 0.002
    expected = own + 400 * max(g.launch_s, g.busy_s / share)  # hidden 256, batch 256: one unit
    assert (gpu.wall_s - RATES.stage_s) * gpu.at_once["train"] / 32 == pytest.approx(expected)
    assert "train: its gpu" in " ".join(cpu.notes)  # the CPU cluster trains it on the CPU


def test_fits_on_matched_scenes_are_priced_by_the_rollouts_they_need():
    """Per stitched pair's sources, once each: a translation fitted on outcomes rolls both sources
    out on `outcome_scenes` scenes; re-anchoring rolls the task source out so and the robot source
    once per anchor; the swapped scenes roll nothing out."""
    from ps_ray.envs import EPISODE_STEPS
    from ps_ray.specs.sweep import SweepSpec

    def zero_shot_steps(translate: list[str]) -> int:
        spec = SweepSpec.from_mapping(
            {
                "name": "t",
                "stages": ["train", "zero_shot"],
                "methods": ["ps"],
                "robots": ["panda", "panda_far"],
                "tasks": ["reach_red", "reach_blue"],
                "seeds": [1],
                "interface_dims": [16],
                "zero_shot": {"outcome_scenes": 50, "translate": {"ps": translate} if translate else {}},
            }
        )
        return next(load for load in workload(spec) if load.stage == "zero_shot").eval_steps

    plain = zero_shot_steps([])
    per_stitch = zero_shot_steps(["affine"]) - plain  # one more evaluation per pair
    sources = 4  # every source of the 2 x 2 grid is both a task source and a robot source
    assert zero_shot_steps(["affine", "affine@swapped"]) - plain == 2 * per_stitch
    assert (
        zero_shot_steps(["affine", "affine@outcome"]) - plain == 2 * per_stitch + sources * 50 * EPISODE_STEPS
    )
    anchored = zero_shot_steps(["affine", "anchors@outcome"]) - plain
    assert anchored == 2 * per_stitch + sources * (50 + 16) * EPISODE_STEPS
    # each source also on the anchors as a task source (the same rollouts) and on its pair's task
    # source's scenes (one pair per robot source here)
    both = zero_shot_steps(["affine", "anchors@both"]) - plain
    assert both == 2 * per_stitch + sources * (50 + 16 + 50) * EPISODE_STEPS
    # decoding reads the same outcomes; with both, nothing is rolled out twice
    assert zero_shot_steps(["affine", "anchors@decoded"]) - plain == both
    assert zero_shot_steps(["affine", "anchors@both", "anchors@decoded"]) - plain == both + per_stitch
