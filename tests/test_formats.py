"""Golden files: a file of every on-disk format, as a released ps_ray wrote it
(tests/data/formats/<format>-<version>, and tests/data/policies_v1, policies_v2 for policy files),
read by today's readers. A format whose writer changes its id gets a new golden file beside the
old one, which must still read (or be refused in one line, if the reader says so)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from ps_ray.data import anchor_file, her
from ps_ray.data.anchor_file import load_anchor_set
from ps_ray.data.her import HindsightReplay
from ps_ray.envs.goals import goal_reward
from ps_ray.stitching.example import EXAMPLE_DIR
from ps_ray.store import checkpoint, replay, signature
from ps_ray.store.formats import FORMATS
from ps_ray.store.npz import read_npz

GOLDEN = Path(__file__).parent / "data" / "formats"


def _golden_ids() -> dict[str, object]:
    """The format id each golden file carries, as its reader finds it."""
    anchor = json.loads(str(read_npz(GOLDEN / "anchor_set-1.npz")["meta"]))
    return {
        "anchor_set": f"{anchor['format']}/{anchor['version']}",  # written as two fields then
        "hindsight_replay": json.loads(str(read_npz(GOLDEN / "hindsight_replay-1.npz")["meta"]))["format"],
        "checkpoint": json.loads((GOLDEN / "checkpoint-1" / "manifest.json").read_text())["format"],
        "replay_segments": json.loads((GOLDEN / "checkpoint-1" / "replay.json").read_text())["format"],
        "example_zoo": json.loads((EXAMPLE_DIR / "zoo.json").read_text())["format"],
    }


def test_every_format_has_one_id_style_and_a_golden_file_of_each_version_it_reads():
    """Every writer puts ``ps_ray.<name>/<version>`` in its files; each version a reader reads has
    a golden file (spelt as the ps_ray that wrote it did: old spellings resolve in
    ps_ray.store.formats alone). Bump a format and this fails until its new golden file is added."""
    assert {f.name for f in FORMATS} == {f"ps_ray.{name}" for name in (*_golden_ids(), "policy")}
    for fmt in FORMATS:
        assert re.fullmatch(r"ps_ray\.[a-z_]+/[1-9][0-9]*", fmt.id), fmt.id
        assert fmt.version_of(fmt.id) == fmt.version and fmt.reads(fmt.id)
        assert not fmt.reads(f"{fmt.name}/{fmt.version + 1}") and fmt.version_of("other/1") is None
    for name, found in _golden_ids().items():
        fmt = next(f for f in FORMATS if f.name == f"ps_ray.{name}")
        assert fmt.version_of(found) == fmt.version == 1, (name, found)
    assert (checkpoint.FORMAT, replay.FORMAT, her._FORMAT, anchor_file.FORMAT, signature.FORMAT) == (
        "ps_ray.checkpoint/1",
        "ps_ray.replay_segments/1",
        "ps_ray.hindsight_replay/1",
        "ps_ray.anchor_set/1",
        "ps_ray.policy/2",
    )
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


def test_a_checkpoint_of_version_1_verifies_and_its_replay_segments_restore_the_buffer():
    folder, store = GOLDEN / "checkpoint-1", GOLDEN / "replay_store-1"
    assert checkpoint.verify(folder, replay_store=store) == folder
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
