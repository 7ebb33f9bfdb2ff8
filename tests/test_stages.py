"""The stage record (ps_ray/specs/stages.py) is the one place a stage is registered: each registry
that names stages agrees with it, and a stage's settings reach exactly the markers they should."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from ps_ray.analysis.workload import LOADS
from ps_ray.pipeline.run import RUNNERS
from ps_ray.plan.stages import PLANS
from ps_ray.specs.resources import ResourcesSpec
from ps_ray.specs.stages import NOT_TRAINING, STAGE_RECORDS, STAGES, STAGES_WITH_TRIALS, stage
from ps_ray.specs.sweep import SUB_SPECS, SweepSpec, load_sweep
from ps_ray.store.layout import SweepLayout
from ps_ray.store.stages import fingerprint

SMOKE = Path(__file__).resolve().parents[1] / "sweeps" / "smoke.yaml"


def test_every_registry_names_the_stages_of_the_record():
    assert STAGES == ("train", "grid", "zero_shot", "few_shot", "report")
    assert set(RUNNERS) == set(STAGES)  # ps-ray run can run each stage
    assert set(LOADS) == set(STAGES_WITH_TRIALS)  # --check prices each stage that runs trials
    assert set(PLANS) == set(STAGES_WITH_TRIALS)  # each plans its trials in one shape
    assert [f.name for f in dataclasses.fields(ResourcesSpec)] == list(STAGES_WITH_TRIALS)
    sweep_fields = {f.name for f in dataclasses.fields(SweepSpec)}
    for record in STAGE_RECORDS:
        if record.settings:  # its settings are a typed block of the sweep YAML
            assert record.settings in sweep_fields and record.settings in SUB_SPECS
    assert stage("anchors_plain").name == "train"  # the plain sources are part of training
    with pytest.raises(KeyError, match="stages: train, grid, zero_shot, few_shot, report"):
        stage("toy")


def test_every_stage_plans_its_trials_from_the_spec_and_a_catalogue_alone():
    """plan(spec, catalogue) for each stage, on a shipped sweep with every stage: typed records,
    and the few-shot plan's pairs are the zero-shot plan's same-seed untranslated ones."""
    from ps_ray.plan.catalogue import planned
    from ps_ray.specs.trial import GridTrial, TrainTrial
    from ps_ray.stitching.pairs import StitchedPair

    kinds = {"train": TrainTrial, "grid": GridTrial, "zero_shot": StitchedPair, "few_shot": TrainTrial}
    for path in (SMOKE, SMOKE.with_name("confirm2.yaml")):  # with few-shot; with grids
        spec = load_sweep(path)
        zoo = planned(spec)
        for name in (s for s in spec.stages if s in PLANS):
            trials = PLANS[name](spec, zoo)
            assert trials and all(isinstance(t, kinds[name]) for t in trials), (path.name, name)
    spec = load_sweep(SMOKE)
    zoo = planned(spec)
    labels = {t.label for t in PLANS["few_shot"](spec, zoo) if t.kind == "stitched"}
    assert labels and labels <= {p.label for p in PLANS["zero_shot"](spec, zoo) if p.pairing == "same_seed"}


def test_each_tune_experiment_has_its_folder_under_the_sweep():
    layout = SweepLayout(Path("/sweeps/smoke"))
    folders = layout.stage_folders()
    assert set(folders) == {label for s in STAGE_RECORDS for label in s.tune_folders}
    assert (layout.tune_plain, layout.tune_train, layout.tune_zero_shot, layout.tune_few_shot) == (
        folders["anchors_plain"],
        folders["train"],
        folders["zero_shot"],
        folders["few_shot"],
    )
    assert len(set(folders.values())) == len(folders)
    assert all(layout.root in p.parents for p in folders.values())


def test_a_stage_s_settings_change_its_marker_and_the_later_ones_only():
    spec = dataclasses.replace(load_sweep(SMOKE), stages=STAGES)
    before = {s: fingerprint(spec, s) for s in STAGES}
    # one setting of each stage's block, changed
    changes = {
        "grid": {"held_out": (f"panda/{spec.tasks[0].text}",)},
        "zero_shot": {"repeats": 3},
        "few_shot": {"env_steps": 1200},
        "report": {"seed": 7},
    }
    assert set(changes) == {s.settings for s in STAGE_RECORDS if s.settings}
    for record in STAGE_RECORDS:
        if not record.settings:
            continue
        assert record.settings in NOT_TRAINING  # a resumed sweep may change a later stage's settings
        changed = dataclasses.replace(getattr(spec, record.settings), **changes[record.settings])
        other = dataclasses.replace(spec, **{record.settings: changed})
        assert other.training_identity() == spec.training_identity()
        after = {s: fingerprint(other, s) for s in STAGES}
        index = STAGES.index(record.name)
        assert [after[s] == before[s] for s in STAGES] == [i < index for i in range(len(STAGES))], record.name
    # the training grid's settings change every marker
    trained = dataclasses.replace(spec, seeds=(*spec.seeds, 999))
    assert all(fingerprint(trained, s) != before[s] for s in STAGES)


def test_a_training_trial_s_config_is_plain_json_and_reads_back():
    from ps_ray.specs.names import trial_key
    from ps_ray.specs.trial import TrainTrial

    spec = load_sweep(SMOKE).trials()[0]
    grid = TrainTrial(spec, "anchors.npz")
    # a grid trial's config is what the train stage always wrote: a resumed sweep finds its trials
    assert grid.config() == {"spec": spec.to_dict(), "anchors": "anchors.npz"}
    assert TrainTrial.of(grid.config()) == grid and grid.run_name == grid.row == trial_key(spec.to_dict())
    start = TrainTrial(spec, key="scratch/x", label="x", kind="scratch")
    assert TrainTrial.of(start.config()) == start and (start.run_name, start.row) == ("scratch/x", "x")
    with pytest.raises(ValueError, match="unknown trial kind 'toy'; kinds: train, stitched"):
        TrainTrial(spec, kind="toy")
