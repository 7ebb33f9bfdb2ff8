"""One record per stitched pair: the zero-shot trials' configs, the rows of zero_shot.csv, and
the pairs few-shot and the report's clips read back from that table (no Ray, no training)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pandas as pd
import pytest

from ps_ray.analysis.clips import stitched_clips
from ps_ray.analysis.page import Report
from ps_ray.plan import zero_shot as zero_shot_plan
from ps_ray.plan.catalogue import trained
from ps_ray.plan.few_shot import selected_pairs, starts
from ps_ray.plan.zero_shot import evaluated_pairs
from ps_ray.specs.names import short_name
from ps_ray.specs.stage_settings import FewShotSpec, ZeroShotSpec
from ps_ray.specs.sweep import SweepSpec
from ps_ray.stitching.pair_table import CONTROL_KEYS, RESULT_KEYS, pairs_from_table, table_of, write_table
from ps_ray.stitching.pairs import Control, StitchedPair
from ps_ray.store.layout import SweepLayout, sweep_layout
from tests.stitch_sources import K, write_trial
from tests.stitch_sources import spec as train_spec

Q1, Q3 = {"name": "reach", "goal_region": "q1"}, {"name": "reach", "goal_region": "q3"}
GRIPPER = {"name": "panda_l3", "gripper": True}


def a_pair(translation: str = "") -> StitchedPair:
    method = f"ps+{translation}" if translation else "ps"
    return StitchedPair(
        key=f"zero_shot/{method}/t: q1 & r: q3/1",
        method=method,
        translation=translation,
        pairing="same_seed",
        seed=1,
        robot_seed=1,
        label="t: q1 & r: q3",
        task_from="ps/panda/reach/1/i8",
        robot_from="ps/panda_l3/reach/1/i8",
        task_from_path="/sweep/tune/a/policy.safetensors",
        robot_from_path="/sweep/tune/b/policy.safetensors",
        robot=GRIPPER,
        task=Q1,
        task_from_robot="panda",
        robot_from_robot=GRIPPER,
        robot_from_task=Q3,
        controls={
            "robot_source": Control("ps/panda_l3/reach/1/i8", "/sweep/tune/b/policy.safetensors"),
            "task_source": Control("ps/panda/reach/1/i8", "/sweep/tune/a/policy.safetensors"),
        },
    )


@pytest.mark.parametrize("translation", ["", "orthogonal", "affine@outcome"])
def test_a_pair_survives_the_tune_config_and_the_csv_row(tmp_path, translation):
    pair = a_pair(translation)
    for back in (
        StitchedPair.from_dict(json.loads(json.dumps(pair.to_dict()))),
        StitchedPair.from_row(pair.to_row()),
    ):
        assert back == pair
        if translation:  # read back as the parsed record, written as its name
            assert (back.translation.kind, back.translation.fit) == tuple(translation.partition("@")[::2])
        else:
            assert back.translation == ""
    row = pair.to_row()
    assert row["task"] == '{"goal_region": "q1", "name": "reach"}'  # exact, not the short name
    assert (row["robot_source"], row["robot_source_path"]) == (pair.robot_from, pair.robot_from_path)
    assert (row["oracle"], row["oracle_path"]) == ("", "")  # no oracle trained for this target
    assert pair.fit_tasks == (Q1, Q3)
    # MLflow params as before the record: no paths, envs by short name
    assert pair.shown()["task"] == 'reach{"goal_region":"q1"}'
    assert not any("path" in k for k in pair.shown())
    # as zero_shot.csv: written by the zero-shot stage, read back cell by cell as text
    path = tmp_path / "zero_shot.csv"
    write_table(table_of([(pair, {"success_mean": 0.5})]), path)
    assert pairs_from_table(path) == [pair]
    assert pd.read_csv(path)["task_from_path"].tolist() == ["/sweep/tune/a/policy.safetensors"]
    # written by a sweep in /sweep: its files relative to it, found again wherever it was copied
    moved = tmp_path / "downloaded" / "zero_shot.csv"
    moved.parent.mkdir()
    write_table(table_of([(pair, {"success_mean": 0.5})], Path("/sweep")), moved)
    assert pd.read_csv(moved)["task_from_path"].tolist() == ["tune/a/policy.safetensors"]
    (found,) = pairs_from_table(moved)
    assert found.task_from_path == str(moved.parent / "tune/a/policy.safetensors")
    assert found.controls["robot_source"].path == str(moved.parent / "tune/b/policy.safetensors")


def test_a_zero_shot_batch_is_plain_json_in_tune_and_each_pair_finds_its_own_block_and_floor():
    """A Tune trial's config holds its batch as JSON (the batch under the grid key, the stream,
    fit and chance shared by every batch); read back it is the typed batch again, and each pair
    takes its training seed's block of the stream and the chance figures measured on it."""
    from ps_ray.plan.zero_shot import (
        Episodes,
        FitSettings,
        ZeroShotBatch,
        pair_episodes,
        stream_of,
        target_key,
    )

    settings = ZeroShotSpec()
    stream = stream_of(settings)
    fit = FitSettings.of(settings, "/sweep/outcomes")
    pairs = (a_pair(), a_pair("affine@outcome"), dataclasses.replace(a_pair(), seed=2, key="other"))
    chance = {target_key(p, pair_episodes(p, stream)): {"chance_success": p.seed / 10} for p in pairs}
    config = {"batch": [p.to_dict() for p in pairs], **ZeroShotBatch.shared(stream, fit, chance)}
    batch = ZeroShotBatch.from_config(json.loads(json.dumps(config)))
    assert batch == ZeroShotBatch(pairs, stream, fit, chance)
    assert stream == Episodes(settings.episodes, settings.repeats, settings.seed)
    first, same_seed, other_seed = (batch.episodes(p) for p in pairs)
    assert first == same_seed != other_seed and first.episodes == stream.episodes  # a block per seed
    assert abs(other_seed.seed - first.seed) >= stream.episodes * stream.repeats  # disjoint blocks
    assert [batch.chance_of(p)["chance_success"] for p in pairs] == [0.1, 0.1, 0.2]
    assert fit.fit_seed != fit.seed and fit.scenes == settings.outcome_scenes


@pytest.fixture
def sweep_spec(tmp_path) -> SweepSpec:
    """Two methods x two arms x two goal regions x two seeds of random policies, as trained."""
    spec = SweepSpec.from_mapping(
        {
            "name": "pairs",
            "methods": ["ps", "ablation"],
            "robots": ["panda", "panda_l3"],
            "tasks": [Q1, Q3],
            "seeds": [1, 2],
            "interface_dims": [K],
            "train": {"hidden": 16, "env_steps": 300},
            "zero_shot": {"pairs": "both", "translate": {"ps": ["orthogonal"]}},
            "storage": str(tmp_path / "store"),
        }
    )
    for t in spec.trials():
        write_trial(sweep_layout(spec).root, "tune", train_spec(t.method, t.robot, t.task, seed=t.seed))
    return spec


def test_few_shot_reads_the_pairs_zero_shot_wrote_in_the_zoos_order(sweep_spec):
    spec, table_path = sweep_spec, SweepLayout(sweep_layout(sweep_spec).root).zero_shot_table
    matrix = zero_shot_plan.matrix(spec, trained(spec), translate=True, pairing="both")
    # per method: 4 seed pairings (2 same-seed, 2 cross-seed) x 4 stitchable pairs; ps translated too
    assert len(matrix) == 4 * 4 * 2 + 4 * 4
    write_table(table_of([(p, {"success_mean": 0.5}) for p in matrix]), table_path)
    assert pairs_from_table(table_path) == matrix  # the matrix's order, every field
    for pair in matrix:
        files = [pair.task_from_path, pair.robot_from_path, *(c.path for c in pair.controls.values())]
        assert all(Path(f).is_file() for f in files)
    same_seed = [p for p in matrix if p.pairing == "same_seed" and not p.translation]
    assert len(same_seed) == 2 * 2 * 4

    def no_zoo():
        raise AssertionError("with the table, nothing reads the zoo")

    table = pairs_from_table(table_path)
    assert evaluated_pairs(spec, table, no_zoo) == same_seed
    assert evaluated_pairs(spec, table, no_zoo, ["ablation", "ps"]) == [
        p for m in ("ablation", "ps") for p in same_seed if p.method == m
    ]
    settings = FewShotSpec(max_pairs=3, pairs_per_seed=2)
    from_table = selected_pairs(evaluated_pairs(spec, table, no_zoo), settings)

    # a sweep that skips zero-shot: the same pairs, from the zoo
    from_zoo = evaluated_pairs(spec, None, lambda: trained(spec))
    assert [p.key for p in selected_pairs(from_zoo, settings)] == [p.key for p in from_table]
    assert [(p.method, p.seed) for p in from_table] == [("ps", 1), ("ps", 1), ("ps", 2)] + [
        ("ablation", 1),
        ("ablation", 1),
        ("ablation", 2),
    ]
    # a table written before its rows carried the sources' files: built from the zoo
    old = table_of([(p, {}) for p in matrix]).drop(columns=["format", "task_from_path", "robot_from_path"])
    write_table(old, table_path)
    assert pairs_from_table(table_path) is None
    assert evaluated_pairs(spec, None, lambda: trained(spec)) == same_seed


def write_sweeps_table(spec: SweepSpec) -> list[StitchedPair]:
    """zero_shot.csv of the sweep's same-seed pairs, every figure 0.5; returns the pairs."""
    matrix = zero_shot_plan.matrix(spec, trained(spec))
    figures = {k: 0.5 for k in (*RESULT_KEYS, *CONTROL_KEYS)}
    write_table(table_of([(p, figures) for p in matrix]), sweep_layout(spec).zero_shot_table)
    return matrix


def test_the_reports_zero_shot_tables_show_no_files(sweep_spec, tmp_path):
    from ps_ray.analysis import report

    write_sweeps_table(sweep_spec)
    page = Report(tmp_path / "report")
    report.zero_shot_section(page, sweep_spec, 0.8, lambda *a: None)
    shown = [item[1] for section in page.sections for kind, item in section.items if kind == "table"]
    columns = {str(c) for frame in shown for c in [*frame.columns.to_flat_index(), *frame.index.names]}
    assert {"('ps', 'success')", "('ablation', 'success')", "oracle (trained on the target)"} <= columns
    assert not [c for c in columns if "path" in c or "touching" in c]  # reach: nothing to touch


@pytest.mark.e2e
def test_the_clips_run_each_source_in_its_own_env_as_the_table_says(sweep_spec, tmp_path):
    from ps_ray.stitching.zoo import ModuleZoo

    matrix = write_sweeps_table(sweep_spec)
    ((label, clips),) = stitched_clips(sweep_spec, tmp_path / "clips", pairs_per_method=1)
    zoo = ModuleZoo.from_sweep(sweep_layout(sweep_spec).root)
    assert len(clips) == 2 * 3  # per method: stitched, task source, robot source
    for method, i in (("ps", 0), ("ablation", 3)):
        stitched, task_source, robot_source = clips[i : i + 3]
        pair = next(p for p in matrix if (p.method, p.label, p.seed) == (method, label, 1))
        assert stitched.env == f"{short_name(pair.robot)}, {short_name(pair.task)}"
        for clip, key in ((task_source, pair.task_from), (robot_source, pair.robot_from)):
            entry = zoo.get(key)  # the env the source was trained in
            assert clip.env == f"{short_name(entry.robot)}, {short_name(entry.task)}" and clip.path.is_file()


def test_a_translation_is_parsed_once_into_its_kind_and_fit():
    from ps_ray.errors import UserError
    from ps_ray.specs.names import Translation

    anchored = Translation("anchors@both")
    assert (anchored.kind, anchored.fit, anchored.scene_fit) == ("anchors", "both", True)
    assert Translation("affine@swapped").scene_fit and not Translation("affine@outcome").scene_fit
    assert Translation(anchored) is anchored and json.dumps([anchored]) == '["anchors@both"]'
    for bad in ("anchors", "affine@nowhere", "rotate"):  # re-anchoring needs a fit; unknown names
        with pytest.raises(UserError, match=f"unknown translation '{bad}'; valid: orthogonal, affine, "):
            Translation(bad)


def test_the_few_shot_starts_are_those_its_settings_turn_on():
    assert starts(FewShotSpec()) == ("stitched",)
    both = FewShotSpec(translation="affine@outcome", halves=True)
    assert starts(both) == ("stitched", "aligned", "robot_module", "task_module")
    assert starts(FewShotSpec(stitched=False, translation="affine@outcome")) == ("aligned",)
