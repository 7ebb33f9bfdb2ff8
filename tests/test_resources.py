"""Resources per stage: what a sweep asks Ray for per trial, and what a trial does with it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ps_ray.errors import UserError
from ps_ray.rllib.algo import algo_config
from ps_ray.specs.resources import StageResources, device_tags, learner_device
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.train import TrainSpec
from tests.point_env import POINT_ENV
from tests.processes import own_ray_env

GRID = {"name": "r", "methods": ["ablation"], "robots": ["panda"], "tasks": ["reach"], "seeds": [1]}

# Four Tune trials through the stages' one runner on a Ray with one logical GPU, each asking for a
# quarter of it: each reports what Ray granted it and when it ran.
SHARE = """
import json, sys, time
from pathlib import Path
import ray
from ray import tune
from ps_ray.pipeline.trials import run_trials
from ps_ray.specs.resources import StageResources
from ps_ray.store.attempts import FINISHED

def trial(config):
    granted = ray.get_runtime_context().get_assigned_resources()
    start = time.time()
    time.sleep(3)
    tune.report({"cpu": granted.get("CPU"), "gpu": granted.get("GPU"), "gpu_ids": ray.get_gpu_ids(),
                 "start": start, "end": time.time(), FINISHED: True})

ray.init(num_cpus=4, num_gpus=1, include_dashboard=False, log_to_driver=False)
out = run_trials(trial, {"n": [0, 1, 2, 3]}, folder=Path(sys.argv[1]), stage="share",
                 callback=tune.Callback(), resume=False, progress=False, max_concurrent=None,
                 max_failures=0, resources=StageResources(cpu=1, gpu=0.25))
print(json.dumps([o.metrics for o in out]))
"""


@pytest.mark.e2e
def test_four_trials_asking_a_quarter_gpu_each_run_at_once_on_one_gpu(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-c", SHARE, str(tmp_path / "share")],
        capture_output=True,
        text=True,
        timeout=300,
        env=own_ray_env(),  # its own Ray, with a GPU it pretends to have
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(rows) == 4
    assert all(r["gpu"] == 0.25 and r["cpu"] == 1 and r["gpu_ids"] == [0] for r in rows), rows
    assert max(r["start"] for r in rows) < min(r["end"] for r in rows)  # all four overlapped


def test_a_sweep_gives_each_stage_its_resources_outside_its_training_identity():
    spec = SweepSpec.from_mapping({**GRID, "resources": {"train": {"cpu": 2, "gpu": 0.25}}})
    assert (
        spec.resources.train == StageResources(cpu=2, gpu=0.25)
        and spec.resources.zero_shot == StageResources()
    )
    assert spec.resources.train.tune_request() == {"cpu": 2, "gpu": 0.25}
    assert spec.resources.zero_shot.tune_request() == {"cpu": 1} and spec.resources.train.threads == 2
    assert spec.training_identity() == SweepSpec.from_mapping(GRID).training_identity()  # resumable elsewhere
    compiled = SweepSpec.from_mapping({**GRID, "resources": {"train": {"compile": True}}})
    assert compiled.resources.train.compile and compiled.resources.train.tune_request() == {"cpu": 1}
    assert compiled.training_identity() == spec.training_identity()  # how to run, not what


@pytest.mark.parametrize(
    "resources, message",
    [
        ({"train": {"cpu": 0}}, "resources.train.cpu must be a positive number, got 0"),
        ({"train": {"gpu": -1}}, "resources.train.gpu must be a non-negative number, got -1"),
        ({"train": {"gpu": 1.5}}, "whole number of GPUs, got 1.5"),
        ({"train": {"gpus": 1}}, "resources.train: unknown key 'gpus'; valid keys: cpu, gpu, compile"),
        (
            {"train": {"compile": "yes"}},
            "resources.train.compile must be true or false, got 'yes'",
        ),
        ({"trian": {}}, "unknown key 'trian'; valid keys: train, grid, zero_shot, few_shot"),
        ({"train": {"cpu": "two"}}, "resources.train.cpu must be a number, got 'two'"),
    ],
)
def test_bad_resources_are_one_line(resources, message):
    with pytest.raises(UserError) as info:
        SweepSpec.from_mapping({**GRID, "resources": resources})
    assert message in str(info.value)


def test_mlflow_device_tags_name_the_device_cpus_and_gpu_share():
    assert device_tags(StageResources(cpu=2, gpu=0.25)) == {
        "ps_ray.device": "cuda",
        "ps_ray.cpus": "2",
        "ps_ray.gpu_share": "0.25",
    }
    assert device_tags(StageResources(cpu=0.5)) == {
        "ps_ray.device": "cpu",
        "ps_ray.cpus": "0.5",
        "ps_ray.gpu_share": "0",
    }


def test_a_gpu_share_without_cuda_is_one_clear_error_and_none_is_the_cpu():
    assert learner_device(0) == "cpu"
    with pytest.raises(UserError, match="granted gpu 0.25 but torch sees no CUDA device on this node"):
        learner_device(0.25)
    with pytest.raises(UserError, match="no CUDA device"):  # before any RLlib object is built
        algo_config(TrainSpec(method="ablation"), gpu=0.25)
    config = algo_config(TrainSpec(method="ablation"))
    assert config.num_gpus_per_learner == 0 and config.num_learners == 0


def test_the_shipped_cluster_sweeps_parse_their_resources():
    for path in sorted(Path(__file__).parents[1].glob("sweeps/*.yaml")):
        from ps_ray.specs.sweep import load_sweep

        assert isinstance(load_sweep(path).resources.train, StageResources), path


@pytest.mark.slow
def test_a_compiled_learner_compiles_its_module_and_trains(ray_local):
    """``compile`` reaches the learner's module (Ray 2.60 alone would skip it inside a
    MultiRLModule): dynamo compiles its forward pass, and the updates change the weights."""
    import numpy as np
    import torch
    from torch._dynamo.utils import counters

    from ps_ray.rllib.loop import TrainingRun

    spec = TrainSpec(
        method="ablation",
        env=POINT_ENV,
        hidden=32,
        interface_dim=8,
        learning_starts=100,
        random_episodes=2,
        episodes_per_step=4,
        num_envs=2,
        eval_every=1000,
        batch_size=32,
    )
    torch._dynamo.reset()
    counters.clear()
    run = TrainingRun(spec, compile=True)
    try:
        before = {k: v.clone() for k, v in run.algo.learner_state().items()}
        while run.algo.counters["updates"] < 20:
            run.step()
        after = run.algo.learner_state()
    finally:
        run.stop()
    assert counters["stats"]["unique_graphs"] >= 1
    weights = [k for k in before if k.startswith("actor.")]
    assert any(not torch.equal(before[k], after[k]) for k in weights)
    assert all(np.isfinite(after[k].numpy()).all() for k in weights)
