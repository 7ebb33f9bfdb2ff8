"""Run names as an analyst reads them in MLflow's runs list (ps_ray.specs.titles): one scheme for
every stage, the distinguishing part first, no stage prefix, variants readable."""

from __future__ import annotations

from pathlib import Path

import pytest

from ps_ray.plan import few_shot, grid, train, zero_shot
from ps_ray.plan.catalogue import planned
from ps_ray.specs.grid import GridSpec
from ps_ray.specs.names import readable
from ps_ray.specs.sweep import load_sweep
from ps_ray.specs.titles import ANCHOR_POLICY, MAX_TITLE, SEP, title
from ps_ray.specs.train import TrainSpec
from ps_ray.specs.trial import TrainTrial

# every stage, grids with every cell held out, cross-seed pairs, translations, task variants
SWEEPS = ("smoke", "confirm2", "confirm2_ps", "transfer", "cotrain", "push_paper", "alignment_reach")
STAGE_WORDS = ("train", "grid", "zero_shot", "few_shot", "anchors_plain", "report")


def test_a_source_a_start_and_a_grid_read_env_method_seed_then_what_else_tells_them_apart():
    spec = TrainSpec.from_mapping(
        {
            "method": "ablation",
            "robot": "panda_far",
            "task": {"name": "reach", "goal_region": "q1"},
            "seed": 431,
        }
    )
    assert TrainTrial(spec).title == "panda_far/reach q1 · ablation · 431"
    narrow = TrainSpec.from_mapping({**spec.to_dict(), "interface_dim": 16})
    assert TrainTrial(narrow).title == "panda_far/reach q1 · ablation · 431 · i16"
    start = TrainTrial(spec, key="few_shot/x", label="t: a & r: b", kind="stitched")
    assert start.title == "panda_far/reach q1 · ablation · 431 · from the stitch t: a & r: b"
    assert TrainTrial(spec, key="scratch/x", label="x", kind="scratch").title.endswith(" · from scratch")
    cells = GridSpec.of(spec, ["panda", "panda_far"], ["reach_red", "reach_blue"], ["panda_far/reach_blue"])
    assert cells.title == "held out panda_far/reach_blue · ablation · 431"


@pytest.mark.parametrize("name", SWEEPS)
def test_every_run_of_a_shipped_sweep_has_its_own_title_without_its_stage(name):
    spec = load_sweep(Path(__file__).parents[1] / "sweeps" / f"{name}.yaml")
    zoo = planned(spec)
    alone = zero_shot.alone_pairs(spec, zoo, list(spec.few_shot.methods) or None)
    pairs = zero_shot.plan(spec, zoo) if "zero_shot" in spec.stages else []
    stages = {
        "train": [t.title for t in train.plan(spec)],
        "anchors_plain": [t.title for t in train.plain_sources(spec)],
        "grid": [t.title for t in grid.plan(spec)] if "grid" in spec.stages else [],
        "zero_shot": [p.title for p in pairs],
        "few_shot": [t.title for t in few_shot.plan(spec, zoo, alone)] if "few_shot" in spec.stages else [],
    }
    for stage, titles in stages.items():
        assert len(set(titles)) == len(titles), (stage, [t for t in titles if titles.count(t) > 1][:2])
        for text in titles:
            assert len(text) <= MAX_TITLE and "{" not in text and '"' not in text, text
            assert not text.startswith(STAGE_WORDS), text
            head = text.split(SEP)[0]
            assert head.startswith("held out ") or head.count("/") == 1, text  # the env first
    for pair in pairs:  # a stitch: its target, its method (with translation), its seeds, its sources
        seeds = str(pair.seed) if pair.pairing == "same_seed" else f"{pair.seed}x{pair.robot_seed}"
        assert pair.title.split(SEP)[1:3] == [pair.method, seeds], pair.title
        assert " t: " in f" {pair.title}" and ", r: " in pair.title


@pytest.mark.parametrize("name", SWEEPS)
def test_every_source_is_found_by_the_name_mlflow_and_the_report_print_for_it(name):
    """One spelling of a trial: the name a source's MLflow run shows and its key as the report and
    ``--check`` write it (``reach q1``) both lead back to the same module, for every source of a
    shipped sweep (``ps-ray stitch --task-from`` looks keys up through the zoo)."""
    spec = load_sweep(Path(__file__).parents[1] / "sweeps" / f"{name}.yaml")
    zoo = planned(spec)
    for trial in train.plan(spec) if "train" in spec.stages else ():
        if trial.key:  # a search's setting: its own run, not a source
            continue
        entry = zoo.get(trial.spec.label())
        assert zoo.get(trial.title) is entry and zoo.get(readable(trial.spec.label())) is entry
    for trial in train.plain_sources(spec) if "train" in spec.stages else ():
        entry = zoo.get(trial.spec.label())
        assert zoo.get(title(trial.title, ANCHOR_POLICY)) is entry
    for entry in zoo:
        assert all(zoo.get(spelling) is entry for spelling in entry.names), entry.names
