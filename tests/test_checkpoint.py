"""Checkpoints are ps_ray's own sealed files: complete ones verify, cut-short or altered ones are
refused (docs/state.md). A real run's resume past planted pickles and an altered replay segment:
tests/test_train.py's killed run."""

from __future__ import annotations

import json

import pytest

from ps_ray.store import checkpoint


def test_seal_and_verify_tell_complete_from_cut_short_and_altered(tmp_path):
    folder = tmp_path / "ckpt"
    folder.mkdir()
    (folder / checkpoint.STATE_FILE).write_text(json.dumps({"counters": {"env_steps": 300}, "iteration": 3}))
    (folder / "replay.npz").write_bytes(b"PK\x03\x04" + bytes(100))
    with pytest.raises(checkpoint.CheckpointError, match="no manifest.json"):
        checkpoint.verify(folder)
    checkpoint.seal(folder)
    assert checkpoint.verify(folder) == folder and checkpoint.env_steps(folder) == 300
    (folder / "replay.npz").write_bytes(b"PK\x03\x04" + bytes(99) + b"x")  # same size, other bytes
    with pytest.raises(checkpoint.CheckpointError, match="replay.npz does not match its hash"):
        checkpoint.verify(folder)
    checkpoint.verify(folder, hashed=(checkpoint.STATE_FILE,))  # a reader hashes what it loads
    (folder / "replay.npz").write_bytes(b"short")
    with pytest.raises(checkpoint.CheckpointError, match="replay.npz has 5 bytes"):
        checkpoint.verify(folder, hashed=(checkpoint.STATE_FILE,))
    assert checkpoint.latest([folder]) is None


def test_latest_skips_a_checkpoint_cut_short(tmp_path):
    folders = []
    for steps in (200, 400):
        folder = tmp_path / f"checkpoint_{steps}"
        folder.mkdir()
        (folder / checkpoint.STATE_FILE).write_text(json.dumps({"counters": {"env_steps": steps}}))
        checkpoint.seal(folder)
        folders.append(folder)
    assert checkpoint.latest(folders) == folders[1]
    (folders[1] / checkpoint.MANIFEST).unlink()  # the kill came before the manifest was copied
    assert checkpoint.latest(folders) == folders[0]
