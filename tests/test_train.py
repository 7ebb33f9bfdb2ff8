"""`ps-ray train`: a killed run resumes from its last checkpoint and ends with a loadable policy."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest
import torch
from safetensors.torch import load_file

from ps_ray.nets.policy_file import load_policy
from ps_ray.store.signature import read_signature
from tests.code_paths import PS_CONSOLIDATED
from tests.point_env import POINT_ENV


def test_a_killed_run_refuses_a_second_writer_while_alive_and_resumes_from_its_checkpoint(
    tmp_path, train_cmd, planted
):
    """Killed mid-run: a second writer is refused while it lives; the resume goes on from the
    checkpoint and ends as a run never killed, bit for bit; a later resume, killed between the
    checkpoint's renames, goes on from checkpoint.old without running pickles planted in it, and one
    whose replay segment was altered is refused in one line."""
    run_dir = tmp_path / "run"
    first = subprocess.Popen(
        train_cmd(run_dir, 100_000),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.time() + 180
        while not (run_dir / "checkpoint" / "ps_ray_state.json").exists():
            assert time.time() < deadline, "no checkpoint was written"
            assert first.poll() is None, "training exited early"
            time.sleep(0.5)
        # one writer at a time: a second process on the folder is refused in one line
        second = subprocess.run(train_cmd(run_dir, 100_000), capture_output=True, text=True, timeout=120)
        assert second.returncode == 2
        lines = second.stderr.strip().splitlines()
        assert f"this run is being written by PID {first.pid} on " in lines[-1]
        assert "Traceback" not in second.stderr
    finally:
        os.killpg(first.pid, signal.SIGKILL)
        first.wait()
    saved = json.loads((run_dir / "checkpoint" / "ps_ray_state.json").read_text())["counters"]["env_steps"]
    assert saved > 0

    # The holder died, and its lock with it. Same policy, larger budget: allowed, and it
    # continues from the checkpoint.
    third = subprocess.run(train_cmd(run_dir, saved + 400), capture_output=True, text=True, timeout=300)
    assert third.returncode == 0, third.stdout[-2000:] + third.stderr[-2000:]
    assert f"resumed at {saved} env steps" in third.stdout
    # only ps_ray's own lines on the terminal: Ray's and RLlib's notices went to logs/ray.log
    assert third.stderr == "" and all(line.startswith("[") for line in third.stdout.splitlines())
    assert "on the new API stack" in (run_dir / "logs" / "ray.log").read_text()
    metrics = pd.read_csv(run_dir / "metrics.csv")
    assert metrics["env_steps"].iloc[-1] >= saved + 400
    steps = metrics["env_steps"]
    assert steps.is_unique and steps.is_monotonic_increasing  # the resume appended no row twice
    result = json.loads((run_dir / "result.json").read_text())
    assert result["env_steps"] == steps.iloc[-1]
    assert result["best_eval_success"] >= metrics["eval_success"].max()  # best-so-far survives the kill
    nets, signature = load_policy(run_dir / "policy.safetensors")
    assert signature.method == "ps" and signature.interface_dim == 8
    assert signature.anchor_hash and (run_dir / "anchors.npz").exists()

    # The kill lost nothing: the same run without one ends with the same weights, bit for bit
    # (replay sampling, reset seeds and torch's generator all go on from the checkpoint).
    straight_dir = tmp_path / "straight"
    straight = subprocess.run(
        train_cmd(straight_dir, saved + 400), capture_output=True, text=True, timeout=300
    )
    assert straight.returncode == 0, straight.stdout[-2000:] + straight.stderr[-2000:]
    resumed, uninterrupted = (load_file(d / "policy.safetensors") for d in (run_dir, straight_dir))
    assert resumed.keys() == uninterrupted.keys()
    assert all(torch.equal(resumed[k], uninterrupted[k]) for k in resumed)
    straight_metrics = pd.read_csv(straight_dir / "metrics.csv")
    assert metrics.drop(columns="wall_s").equals(straight_metrics.drop(columns="wall_s"))

    # Checkpoints are ps_ray's own files (docs/state.md): pickles planted where Ray or RLlib would
    # look are never run by a resume, and a replay segment altered since its checkpoint is refused.
    # This resume also meets a kill between the checkpoint's two renames: checkpoint/ moved aside
    # to checkpoint.old, the new one not yet in, and a metrics row written after the old one.
    assert not list(run_dir.rglob("*.pkl"))
    planted(run_dir / "checkpoint")
    ended = json.loads((run_dir / "result.json").read_text())["env_steps"]
    best_before = float(read_signature(run_dir / "best_policy.safetensors")[1]["eval_success"])
    os.replace(run_dir / "checkpoint", run_dir / "checkpoint.old")  # the moment of the kill
    with open(run_dir / "metrics.csv", "a") as f:  # a row after that checkpoint, claiming best 1.0
        f.write(f"999,{ended + 100},1,0.0,,,,1.0,1.0\n")
    again = subprocess.run(train_cmd(run_dir, ended + 400), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-2000:]
    assert f"resumed at {ended} env steps" in again.stdout and not planted.marker.exists()
    assert (run_dir / "checkpoint").is_dir() and not (run_dir / "checkpoint.old").exists()
    metrics = pd.read_csv(run_dir / "metrics.csv")
    assert metrics["env_steps"].is_unique and metrics["env_steps"].is_monotonic_increasing
    assert 999 not in metrics["iteration"].values
    best = metrics["best_eval_success"].dropna()  # the running best, as logged, never fell
    best_after = float(read_signature(run_dir / "best_policy.safetensors")[1]["eval_success"])
    assert best.is_monotonic_increasing and best.iloc[-1] == best_after >= best_before
    assert not (run_dir / "checkpoint" / "replay.npz").exists()  # the buffer lives in segment files
    (segment,) = sorted((run_dir / "replay").glob("*.npz"))[-1:]
    segment.write_bytes(b"PK\x03\x04 planted".ljust(segment.stat().st_size, b"\0"))
    refused = subprocess.run(train_cmd(run_dir, ended + 800), capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2
    last = refused.stderr.strip().splitlines()[-1]
    assert last.startswith("ps-ray train: error:") and "not a usable ps_ray checkpoint" in last
    assert f"replay segment {segment} does not match its checkpoint" in last and not planted.marker.exists()


def test_a_run_directory_refuses_another_policy(tmp_path, train_cmd):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "spec.json").write_text(json.dumps({"method": "ablation", "env": POINT_ENV}))
    proc = subprocess.run(train_cmd(run_dir, 100), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "holds a run of another spec (changed: " in proc.stderr
    assert "method" in proc.stderr


@pytest.mark.slow
def test_training_stops_early_at_the_success_target(tmp_path):
    """A source stops once greedy success reaches the target in two evaluations in a row, well
    before its budget cap; the result says so and the metrics end at that evaluation."""
    run_dir = tmp_path / "run"
    cmd = [
        sys.executable,
        "-m",
        "ps_ray.cli",
        "train",
        "--env",
        POINT_ENV,
        "--method",
        "ablation",
        "--interface-dim",
        "16",
        "--hidden",
        "64",
        "--learning-starts",
        "200",
        "--random-episodes",
        "2",
        "--episodes-per-step",
        "4",
        "--batch-size",
        "64",
        "--updates-per-step",
        "0.5",
        "--eval-every",
        "5",
        "--eval-episodes",
        "20",
        "--target-success",
        "0.3",  # an untrained policy scores 0-0.15 here; two evaluations at 0.3 come near 3k steps
        "--target-evals",
        "2",
        "--env-steps",
        "40000",
        "--run-dir",
        str(run_dir),
        "--quiet",
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    result = json.loads((run_dir / "result.json").read_text())
    evals = pd.read_csv(run_dir / "metrics.csv").dropna(subset=["eval_success"])
    assert result["converged"] is True
    assert result["env_steps"] < 40000
    assert (evals["eval_success"].iloc[-2:] >= 0.3).all() and (evals["eval_success"].iloc[:2] < 0.3).all()
    assert evals["env_steps"].iloc[-1] == pd.read_csv(run_dir / "metrics.csv")["env_steps"].iloc[-1]


def test_resume_drops_rows_after_the_checkpoint_and_a_row_a_kill_cut_short(tmp_path):
    from ps_ray.store.run_folder import metrics_up_to
    from ps_ray.store.run_layout import METRIC_FIELDS, METRICS_FILE

    def row(steps):
        return ",".join(str(steps) if f == "env_steps" else "1" for f in METRIC_FIELDS)

    path = tmp_path / METRICS_FILE
    header = ",".join(METRIC_FIELDS)
    path.write_text(f"{header}\n{row(100)}\n{row(200)}\n{row(300)}\n4,4")  # killed mid-row
    metrics_up_to(tmp_path, 200)
    assert path.read_text().split() == [header, row(100), row(200)]
    path.write_text(f"{header}\n{row(100)}\n1,1")  # cut short before the checkpoint's steps
    metrics_up_to(tmp_path, 200)
    assert pd.read_csv(path)["env_steps"].tolist() == [100]
    with open(path, "a", newline="") as f:  # the resumed run appends cleanly
        f.write(row(200) + "\n")
    assert pd.read_csv(path)["env_steps"].tolist() == [100, 200]
    # written by a ps_ray with other columns: rewritten in today's, each value under its name
    path.write_text("env_steps,gone,eval_success\n100,7,0.5\n")
    metrics_up_to(tmp_path, 200)
    again = pd.read_csv(path)
    assert list(again.columns) == list(METRIC_FIELDS) and again.loc[0, "eval_success"] == 0.5
    assert (
        again.loc[0, "env_steps"] == 100
        and again.drop(columns=["env_steps", "eval_success"]).isna().all().all()
    )


# 300 of the default 2,000 consolidation updates: at this size they shrink the gap as far
# (0.30 -> 0.004, against 0.001 after 600), in a third of the run's time
@pytest.mark.parametrize(
    "method",
    [
        PS_CONSOLIDATED + "+consolidate_updates=300",
        "ps_distilled+consolidate_updates=300",
    ],
)
def test_a_consolidating_method_aligns_once_when_training_ends_and_keeps_it_on_resume(
    tmp_path, train_cmd, method
):
    """The consolidation runs after the last training step, on the run's replay: its gap to the
    input reference shrinks, and the checkpoint, the policy file and the result hold it. Running
    the finished run again consolidates nothing twice (checked on one of the two methods).
    ps_distilled's policy file carries its projection switched on."""
    run_dir = tmp_path / "run"
    cmd = [*train_cmd(run_dir, 600), "--method", method, "--quiet"]
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stdout[-2000:] + first.stderr[-2000:]
    result = json.loads((run_dir / "result.json").read_text())
    assert result["consolidation_gap_after"] < 0.5 * result["consolidation_gap_before"]
    progress = json.loads((run_dir / "checkpoint" / "progress.json").read_text())
    assert progress["consolidated"]["gap_after"] == result["consolidation_gap_after"]
    policy = load_file(run_dir / "policy.safetensors")
    assert policy.get("actor.task.relative_on", torch.tensor(True)).item()

    resumed = result
    if method.startswith("ps_distilled"):  # run again once (both methods share this path)
        again = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-2000:]
        again_policy = load_file(run_dir / "policy.safetensors")  # (its header's key order is not fixed)
        assert again_policy.keys() == policy.keys()
        assert all(torch.equal(again_policy[k], policy[k]) for k in policy)
        resumed = json.loads((run_dir / "result.json").read_text())
        assert resumed["consolidation_gap_after"] == result["consolidation_gap_after"]
        # both final evaluations ran the consolidated actor (the resume loads it from the checkpoint)
        assert resumed["final_return"] == result["final_return"]

    spec_before = (run_dir / "spec.json").read_text()
    raised = subprocess.run(
        [*train_cmd(run_dir, 800), "--method", method, "--quiet"], capture_output=True, text=True, timeout=600
    )
    extended = json.loads((run_dir / "result.json").read_text())
    if method.startswith("ps_distilled"):  # its actor is no longer the network its training trained
        assert raised.returncode == 2, raised.stdout[-2000:] + raised.stderr[-2000:]
        assert "switched its actor to the relative interface" in raised.stderr.strip().splitlines()[-1]
        assert (run_dir / "spec.json").read_text() == spec_before and extended == resumed
    else:  # a raised budget trains on and consolidates again at its new end
        assert raised.returncode == 0, raised.stdout[-2000:] + raised.stderr[-2000:]
        assert extended["env_steps"] > result["env_steps"]
        assert extended["consolidation_gap_before"] != result["consolidation_gap_before"]
