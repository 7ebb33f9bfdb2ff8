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

from ps_ray.analysis.cost import DEFAULT_RATES, Rates, describe, load_rates, project, workload
from ps_ray.specs.sweep import SweepSpec, load_sweep

SWEEPS = Path(__file__).resolve().parents[1] / "sweeps"
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


def test_the_workload_of_the_smoke_sweep_is_counted_from_its_spec():
    loads = {load.stage: load for load in workload(load_sweep(SWEEPS / "smoke.yaml"))}
    assert list(loads) == ["anchors_plain", "train", "zero_shot", "few_shot"]
    # 2 methods x 2 robots x 2 reach halves x 2 seeds, 1,500 env steps each
    assert len(loads["train"].trials) == 16 and loads["train"].env_steps == 16 * 1500
    assert loads["train"].updates == 16 * int((1500 - 500) * 0.4)
    assert len(loads["anchors_plain"].trials) == 2  # a plain policy per reach half
    # per method and seed, each of the 4 task modules (half X, Ra) meets the one robot module of
    # (the other half, the other arm): 4 pairs; 16 pairs run as 2 trials of 8
    assert len(loads["zero_shot"].trials) == 2
    # each pair evaluated with its three controls (robot source, task source, oracle)
    assert loads["zero_shot"].eval_steps == 16 * 4 * 10 * 2 * 50 and loads["zero_shot"].updates == 0
    # max_pairs 1 per method, plus one from-scratch run per target
    # and one unstitched start (the pair's robot source as it is) per pair
    assert len(loads["few_shot"].trials) == 2 * 3 and loads["few_shot"].env_steps == 6 * 1000


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


def test_check_prints_the_projection_and_refuses_a_bad_core_count(tmp_path):
    (tmp_path / "rates").mkdir()
    env = {"PS_RAY_CACHE": str(tmp_path / "rates")}
    run = subprocess.run(
        [sys.executable, "-m", "ps_ray.cli", "sweep", str(SWEEPS / "smoke.yaml"), "--check", "--cores", "16"],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        timeout=120,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "total: 26 trials, 33,000 training env steps" in run.stdout
    assert "on 16 cores" in run.stdout and "rates: conservative defaults" in run.stdout
    assert not list((tmp_path / "rates").iterdir())  # --check writes nothing
    bad = subprocess.run(
        [sys.executable, "-m", "ps_ray.cli", "sweep", str(SWEEPS / "smoke.yaml"), "--check", "--cores", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines()[-1].endswith("--cores must be a positive number of cores, got 0")


def test_a_success_target_makes_the_budget_a_cap(tmp_path):
    data = yaml.safe_load((SWEEPS / "smoke.yaml").read_text())
    data["train"]["target_success"] = 0.9
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    assert any("caps" in line for line in describe(project(load_sweep(tmp_path / "s.yaml"), rates=RATES)))
    assert not any(
        "caps" in line for line in describe(project(load_sweep(SWEEPS / "smoke.yaml"), rates=RATES))
    )
