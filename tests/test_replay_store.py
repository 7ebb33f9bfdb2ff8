"""Incremental replay checkpoints (ps_ray.store.replay): what is written, what a restore gives back,
what pruning keeps, and what a damaged segment does. Real buffers of episodes that encode their id."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ps_ray.data.her import HindsightReplay
from ps_ray.store import checkpoint, replay
from tests.her_batches import SPEC, A, T, batch, make, reward_fn


@pytest.fixture(autouse=True)
def small_segments(monkeypatch):
    monkeypatch.setattr(replay, "SEGMENT_EPISODES", 4)


def save(buffer, store: Path, folder: Path, previous=None) -> dict:
    """A sealed checkpoint folder holding the buffer's replay manifest (and the state file that
    a checkpoint must list), as a training run writes it."""
    manifest = replay.write(buffer, store, previous)
    folder.mkdir(parents=True)
    replay.save_manifest(manifest, folder)
    (folder / checkpoint.STATE_FILE).write_text(
        json.dumps({"counters": {"env_steps": buffer.episodes_added}})
    )
    checkpoint.seal(folder)
    return manifest


def same_samples(a, b, n: int = 64) -> bool:
    x, y = a.sample(n), b.sample(n)
    return all(np.array_equal(x[k], y[k]) for k in x)


def test_each_checkpoint_writes_only_the_segments_the_last_one_lacks(tmp_path):
    buffer, store = make(capacity=40), tmp_path / "store"
    buffer.add_episodes(*batch(range(100, 110)))  # episodes 0-9: segments [0,4) [4,8) [8,10)
    first = replay.write(buffer, store)
    assert [(e["first"], e["count"]) for e in first["segments"]] == [(0, 4), (4, 4), (8, 2)]
    buffer.add_episodes(*batch(range(110, 113)))  # episodes 10-12
    second = replay.write(buffer, store, first)
    written = {e["file"] for e in second["segments"]} - {e["file"] for e in first["segments"]}
    # the two full segments are reused; only the one that was filling up, and the new one
    assert sorted(written) == sorted([replay.segment_file(8, 12), replay.segment_file(12, 13)])
    assert second["segments"][:2] == first["segments"][:2]


def test_a_restore_gives_back_the_same_buffer_also_after_the_ring_wrapped(tmp_path):
    buffer, store = make(capacity=10), tmp_path / "store"
    manifest = None
    for i, ids in enumerate([range(100, 107), range(107, 112), range(112, 125)]):  # wraps twice
        buffer.add_episodes(*batch(ids))
        previous, manifest = manifest, save(buffer, store, tmp_path / f"c{i}", manifest)
        replay.prune(store, previous, manifest)
    restored = make(capacity=10, seed=99)
    restored.add_episodes(*batch(range(500, 503)))  # stale content is replaced
    replay.load(restored, tmp_path / "c2", store)
    assert restored.episodes_added == buffer.episodes_added == 25
    assert restored.live_range() == (15, 25)
    for a, b in zip(buffer.episodes(15, 25).values(), restored.episodes(15, 25).values(), strict=True):
        assert np.array_equal(a, b)
    assert same_samples(buffer, restored)  # the RNG state came back too: training goes on the same


def test_pruning_keeps_what_the_last_two_checkpoints_name_so_a_kill_never_strands_both(tmp_path):
    buffer, store = make(capacity=8), tmp_path / "store"
    buffer.add_episodes(*batch(range(100, 106)))
    c0 = save(buffer, store, tmp_path / "c0")
    buffer.add_episodes(*batch(range(106, 116)))  # wrapped: episodes 8-15 held
    c1 = save(buffer, store, tmp_path / "c1", c0)
    freed = replay.prune(store, c0, c1)
    assert freed == 0  # c0's files are still named by c0, the checkpoint before the new one
    buffer.add_episodes(*batch(range(116, 118)))
    c2 = save(buffer, store, tmp_path / "c2", c1)
    assert replay.prune(store, c1, c2) > 0
    names = {p.name for p in store.iterdir()}
    assert names == {e["file"] for m in (c1, c2) for e in m["segments"]}
    for folder in ("c1", "c2"):  # both remaining checkpoints restore
        replay.load(make(capacity=8), tmp_path / folder, store)


def test_latest_passes_over_a_checkpoint_whose_segment_is_missing_or_altered(tmp_path):
    buffer, store = make(capacity=20), tmp_path / "store"
    buffer.add_episodes(*batch(range(100, 105)))
    c0 = save(buffer, store, tmp_path / "c0")
    buffer.add_episodes(*batch(range(105, 107)))
    save(buffer, store, tmp_path / "c1", c0)
    folders = [tmp_path / "c0", tmp_path / "c1"]
    assert checkpoint.latest(folders, replay_store=store) == tmp_path / "c1"
    tail = store / replay.segment_file(4, 7)  # only c1 names it
    tail.write_bytes(tail.read_bytes()[:-8] + b"\0" * 8)  # same size, other bytes
    assert checkpoint.latest(folders, replay_store=store) == tmp_path / "c0"
    with pytest.raises(
        checkpoint.CheckpointError, match=f"replay segment {tail} does not match its checkpoint"
    ):
        checkpoint.verify(tmp_path / "c1", replay_store=store)
    tail.unlink()
    with pytest.raises(checkpoint.CheckpointError, match=f"replay segment {tail} is missing"):
        checkpoint.verify(tmp_path / "c1", replay_store=store)
    with pytest.raises(replay.ReplayStoreError, match="is missing"):
        replay.load(make(capacity=20), tmp_path / "c1", store)


def test_a_segment_of_another_layout_is_refused_by_name(tmp_path):
    buffer, store = make(capacity=20), tmp_path / "store"
    buffer.add_episodes(*batch(range(100, 103)))
    save(buffer, store, tmp_path / "c0")
    other = HindsightReplay(SPEC, A + 1, T, 20, reward_fn)  # a robot with one more joint
    with pytest.raises(replay.ReplayStoreError, match=rf"'actions' is not float32\(3, {T}, {A + 1}\)"):
        replay.load(other, tmp_path / "c0", store)
