"""Checkpoints are ps_ray's own sealed files: complete ones resume, planted pickles never run,
cut-short or altered ones are refused in one line (docs/state.md)."""

from __future__ import annotations

import json
import subprocess

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


def test_train_resume_never_runs_planted_pickles_and_refuses_altered_state(tmp_path, train_cmd, planted):
    run_dir, marker = tmp_path / "run", planted.marker
    first = subprocess.run(train_cmd(run_dir, 300), capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr[-2000:]
    assert not list(run_dir.rglob("*.pkl"))
    planted(run_dir / "checkpoint")
    resumed = subprocess.run(train_cmd(run_dir, 400), capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "resumed at 320 env steps" in resumed.stdout  # whole episodes of 40 steps
    assert not marker.exists()

    # the replay buffer lives in segment files beside the checkpoint, named by its replay.json
    assert not (run_dir / "checkpoint" / "replay.npz").exists()
    (segment,) = sorted((run_dir / "replay").glob("*.npz"))[-1:]
    segment.write_bytes(b"PK\x03\x04 planted".ljust(segment.stat().st_size, b"\0"))
    refused = subprocess.run(train_cmd(run_dir, 500), capture_output=True, text=True, timeout=600)
    assert refused.returncode == 2
    last = refused.stderr.strip().splitlines()[-1]
    assert last.startswith("ps-ray train: error:") and "not a usable ps_ray checkpoint" in last
    assert f"replay segment {segment} does not match its checkpoint" in last and not marker.exists()
