"""Golden files: a file of every on-disk format, as a released ps_ray wrote it
(tests/data/formats/<format>-<version>, and tests/data/policies_v1, policies_v2 for policy files),
read by today's readers. A format whose writer changes its id gets a new golden file beside the
old one, which must still read (or be refused in one line, if the reader says so)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ps_ray.data import anchor_file, her
from ps_ray.data.anchor_file import load_anchor_set
from ps_ray.data.her import HindsightReplay
from ps_ray.envs.goals import goal_reward
from ps_ray.errors import UserError
from ps_ray.stitching.example import EXAMPLE_DIR
from ps_ray.stitching.pair_table import COLUMNS, pairs_from_table, read_table
from ps_ray.store import checkpoint, replay, signature
from ps_ray.store.formats import CHECKPOINT, FORMATS, ZERO_SHOT_TABLE, id_in
from ps_ray.store.npz import read_npz

GOLDEN = Path(__file__).parent / "data" / "formats"


def _golden_ids() -> dict[str, object]:
    """The format id each golden file carries, as its reader finds it."""
    anchor = json.loads(str(read_npz(GOLDEN / "anchor_set-1.npz")["meta"]))
    return {
        "anchor_set": id_in(anchor),  # written as two fields then
        "hindsight_replay": json.loads(str(read_npz(GOLDEN / "hindsight_replay-1.npz")["meta"]))["format"],
        "replay_segments": json.loads((GOLDEN / "checkpoint-1" / "replay.json").read_text())["format"],
        "example_zoo": json.loads((EXAMPLE_DIR / "zoo.json").read_text())["format"],
        "chance": json.loads((GOLDEN / "chance-1.json").read_text())["format"],
    }


def test_every_format_has_one_id_style_and_a_golden_file_of_each_version_it_reads():
    """Every writer puts ``ps_ray.<name>/<version>`` in its files; each version a reader reads has
    a golden file (spelt as the ps_ray that wrote it did: old spellings resolve in
    ps_ray.store.formats alone). Bump a format and this fails until its new golden file is added."""
    names = (*_golden_ids(), "checkpoint", "policy", "zero_shot_table")  # the last three: their own tests
    assert {f.name for f in FORMATS} == {f"ps_ray.{name}" for name in names}
    for fmt in FORMATS:
        assert re.fullmatch(r"ps_ray\.[a-z_]+/[1-9][0-9]*", fmt.id), fmt.id
        assert fmt.version_of(fmt.id) == fmt.version and fmt.reads(fmt.id)
        assert not fmt.reads(f"{fmt.name}/{fmt.version + 1}") and fmt.version_of("other/1") is None
    for name, found in _golden_ids().items():
        fmt = next(f for f in FORMATS if f.name == f"ps_ray.{name}")
        assert fmt.version_of(found) == fmt.version == 1, (name, found)
    assert (checkpoint.FORMAT, replay.FORMAT, her._FORMAT, anchor_file.FORMAT, signature.FORMAT) == (
        "ps_ray.checkpoint/2",
        "ps_ray.replay_segments/1",
        "ps_ray.hindsight_replay/1",
        "ps_ray.anchor_set/1",
        "ps_ray.policy/2",
    )
    for name, fmt in (("checkpoint", CHECKPOINT), ("zero_shot_table", ZERO_SHOT_TABLE)):
        versions = [f"{name}-{v}" for v in range(1, fmt.version + 1)]
        assert sorted(p.stem for p in GOLDEN.glob(f"{name}-*")) == versions
    assert (CHECKPOINT.version, ZERO_SHOT_TABLE.version) == (2, 3)
    assert ZERO_SHOT_TABLE.readable == tuple(f"ps_ray.zero_shot_table/{v}" for v in (1, 2, 3))

    assert signature.FORMATS == ("ps_ray.policy/1", "ps_ray.policy/2")
    assert {p.parent.name for p in Path(__file__).parent.glob("data/policies_v*/*.safetensors")} == {
        "policies_v1",
        "policies_v2",
    }  # read by tests/test_methods.py


def test_files_written_today_read_back_as_the_golden_ones_do(tmp_path):
    """A file of today's id style reads as its golden file, spelt the old way, does."""
    from ps_ray.data.anchor_file import save_anchor_set

    golden = load_anchor_set(GOLDEN / "anchor_set-1.npz")
    save_anchor_set(tmp_path / "a.npz", golden)
    assert json.loads(str(read_npz(tmp_path / "a.npz")["meta"]))["format"] == "ps_ray.anchor_set/1"
    assert load_anchor_set(tmp_path / "a.npz") == golden
    buf = HindsightReplay.from_file(GOLDEN / "hindsight_replay-1.npz", goal_reward)
    buf.save(tmp_path / "h.npz")
    again = HindsightReplay.from_file(tmp_path / "h.npz", goal_reward)
    for key, value in buf.episodes(0, 3).items():
        np.testing.assert_array_equal(again.episodes(0, 3)[key], value, err_msg=key)


def test_an_anchor_set_of_version_1_reads_with_its_anchors_hash_and_provenance():
    found = load_anchor_set(GOLDEN / "anchor_set-1.npz")
    assert found.anchors.shape == (4, 3) and found.anchors.dtype == np.float32
    assert found.provenance == {"k": 4, "policy": "random"}
    # the hash of the anchors as written (the reader checks the anchors against it)
    assert found.hash == "0a61a51f32f1c462c7087bebaa041466882ec799bd9ba8034f3aa451df7923f8"
    np.testing.assert_allclose(found.anchors[0], [0.00123015, 0.29874554, -0.27413785], atol=1e-7)


def test_a_hindsight_replay_of_version_1_reads_back_its_episodes():
    buf = HindsightReplay.from_file(GOLDEN / "hindsight_replay-1.npz", goal_reward)
    assert (buf.num_episodes, buf.horizon, buf.action_dim) == (3, 4, 2)
    episodes = buf.episodes(0, 3)
    assert episodes["actions"].shape == (3, 4, 2) and episodes["obs/desired_goal"].shape == (3, 5, 3)
    batch = buf.sample(8)  # and it samples, relabelling included
    assert batch["actions"].shape == (8, 2)


@pytest.mark.parametrize("version", [1, 2])
def test_a_checkpoint_of_each_version_verifies_and_its_replay_segments_restore_the_buffer(version):
    folder, store = GOLDEN / f"checkpoint-{version}", GOLDEN / "replay_store-1"
    assert checkpoint.verify(folder, replay_store=store) == folder
    assert checkpoint.version(folder) == version
    saved = HindsightReplay.from_file(GOLDEN / "hindsight_replay-1.npz", goal_reward)
    spec = saved.obs_spec
    restored = HindsightReplay(spec, saved.action_dim, saved.horizon, saved.capacity_episodes, goal_reward)
    replay.load(restored, folder, store)
    for key, value in saved.episodes(0, 3).items():
        np.testing.assert_array_equal(restored.episodes(0, 3)[key], value, err_msg=key)


@pytest.mark.parametrize("name", ["anchor_set-1.npz", "hindsight_replay-1.npz"])
def test_a_golden_file_is_plain_arrays_and_json_never_a_pickle(name):
    data = (GOLDEN / name).read_bytes()
    assert data[:2] == b"PK" and b"\x80\x04\x95" not in data  # a zip of .npy members, no pickle stream


def test_a_zero_shot_table_of_any_version_reads_in_todays_layout_with_the_same_pairs(tmp_path):
    """Version 1 (a push study's rows before tables named their format), version 2 (before the
    told robot source) and version 3 read as the same table: every current column, ``format``
    first, the figures as written, a figure not measured then empty."""
    old, middle, new = (read_table(GOLDEN / f"zero_shot_table-{v}.csv") for v in (1, 2, 3))
    pd.testing.assert_frame_equal(old, new)
    pd.testing.assert_frame_equal(middle, new)
    assert list(new.columns) == list(COLUMNS) and set(new["format"]) == {"ps_ray.zero_shot_table/3"}
    assert new["told_robot_source_success"].isna().all()  # push has no markers to trade
    assert new["method"].tolist() == ["ablation", "ablation+affine", "ablation+affine@outcome"]
    np.testing.assert_allclose(new["success_mean"], [0.05, 0.31, 0.21])
    pairs = pairs_from_table(GOLDEN / "zero_shot_table-1.csv")
    assert pairs == pairs_from_table(GOLDEN / "zero_shot_table-2.csv") and len(pairs) == 3
    assert pairs[2].translation.fit == "outcome" and pairs[0].task_from_path.startswith(str(GOLDEN / "tune"))
    # a version-1 table whose rows name no files yet: read, its pairs left to the zoo
    older = pd.read_csv(GOLDEN / "zero_shot_table-1.csv").drop(columns=["task_from_path", "robot_from_path"])
    older.drop(columns=["task_blind_success"]).to_csv(tmp_path / "zero_shot.csv", index=False)
    assert read_table(tmp_path / "zero_shot.csv")["task_blind_success"].isna().all()
    assert pairs_from_table(tmp_path / "zero_shot.csv") is None


@pytest.mark.parametrize("found", ["ps_ray.zero_shot_table/4", "ps_ray.policy/2"])
def test_a_zero_shot_table_of_a_newer_ps_ray_or_another_format_is_refused_in_one_line(tmp_path, found):
    table = pd.read_csv(GOLDEN / "zero_shot_table-3.csv").assign(format=found)
    table.to_csv(tmp_path / "zero_shot.csv", index=False)
    with pytest.raises(UserError) as e:
        read_table(tmp_path / "zero_shot.csv")
    assert str(e.value) == (
        f"{tmp_path / 'zero_shot.csv'}: not a zero-shot table this ps_ray reads (format {found}; "
        "it reads ps_ray.zero_shot_table/1, ps_ray.zero_shot_table/2, ps_ray.zero_shot_table/3)"
    )


def test_the_learner_state_of_either_checkpoint_version_holds_a_generator_state(tmp_path):
    """Version 2 keeps torch's generator state in the learner file, and a restore sets it; a
    version-1 checkpoint written before it was kept draws on from the process's own."""
    import torch
    from safetensors.torch import save_file

    from ps_ray.rllib.sac_her import TORCH_RNG, read_learner_file

    torch.manual_seed(7)
    seeded = torch.get_rng_state()
    torch.manual_seed(0)
    state = read_learner_file(GOLDEN / "checkpoint-2")
    assert torch.equal(state[TORCH_RNG], seeded) and state["actor.weight"].tolist() == [[1.0, 2.0]]
    old = tmp_path / "checkpoint"
    shutil.copytree(GOLDEN / "checkpoint-1", old)
    save_file({"actor.weight": torch.ones(1, 2)}, old / "learner.safetensors")
    assert checkpoint.version(old) == 1
    torch.manual_seed(3)
    state = read_learner_file(old)  # the generator as the restore finds it: it draws on from there
    torch.manual_seed(3)
    assert torch.equal(state[TORCH_RNG], torch.get_rng_state()) and set(state) == {"actor.weight", TORCH_RNG}


def test_the_stopping_rules_state_of_either_checkpoint_version_reads_whole(tmp_path):
    """Version 2 keeps the streak, the best evaluation and the consolidation; a version-1
    checkpoint written before the last two were kept reads as having none yet."""
    assert checkpoint.progress(GOLDEN / "checkpoint-2") == {"streak": 1, "best": 0.5, "consolidated": {}}
    old = tmp_path / "checkpoint"
    shutil.copytree(GOLDEN / "checkpoint-1", old)
    assert checkpoint.progress(old) == {"streak": 0, "best": None, "consolidated": {}}  # none kept yet
    (old / checkpoint.PROGRESS_FILE).write_text(json.dumps({"streak": 2}))
    assert checkpoint.progress(old) == {"streak": 2, "best": None, "consolidated": {}}
    new = tmp_path / "checkpoint-2"
    shutil.copytree(GOLDEN / "checkpoint-2", new)
    (new / checkpoint.PROGRESS_FILE).unlink()
    with pytest.raises(
        checkpoint.CheckpointError, match=f"{new}: not a usable ps_ray checkpoint .no progress.json"
    ):
        checkpoint.progress(new)


def test_a_kept_chance_level_of_version_1_reads_back_and_another_version_is_measured_again(tmp_path):
    from ps_ray.pipeline.chance_levels import _kept_level

    kept = _kept_level(GOLDEN / "chance-1.json")
    assert (kept["chance_policy"], kept["chance_success"]) == ("random_actions", 0.07)
    assert kept["task_blind_success"] != kept["task_blind_success"]  # NaN: no shared scene on push
    newer = json.loads((GOLDEN / "chance-1.json").read_text().replace("NaN", "null"))
    (tmp_path / "c.json").write_text(json.dumps({**newer, "format": "ps_ray.chance/2"}))
    assert _kept_level(tmp_path / "c.json") is None


@pytest.mark.parametrize("version", [2, 3])
def test_a_zero_shot_table_without_a_column_its_version_wrote_is_refused_naming_it(tmp_path, version):
    table = pd.read_csv(GOLDEN / f"zero_shot_table-{version}.csv").drop(columns=["oracle_success"])
    table.to_csv(tmp_path / "zero_shot.csv", index=False)
    with pytest.raises(UserError) as e:
        read_table(tmp_path / "zero_shot.csv")
    without = f"a ps_ray.zero_shot_table/{version} table without its column(s) oracle_success"
    assert str(e.value) == f"{tmp_path / 'zero_shot.csv'}: {without}"
