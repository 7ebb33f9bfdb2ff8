"""Train one policy: progress on the terminal, periodic greedy evaluation, resumable checkpoints.

A run directory holds:
  spec.json          the TrainSpec (a directory belongs to one spec; a different one is refused)
  anchors.npz        the anchor set (PS only)
  checkpoint/        the latest RLlib checkpoint + replay buffer (replaced atomically)
  policy.safetensors actor, critics and targets with the interface signature
  metrics.csv        one row per training step
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ps_ray.config import SpecError, TrainSpec

CHECKPOINT_DIR = "checkpoint"
POLICY_FILE = "policy.safetensors"
METRICS_FILE = "metrics.csv"
METRIC_FIELDS = ["iteration", "env_steps", "updates", "train_success", "train_touching",
                 "eval_success", "eval_touching", "wall_s"]


def make_env(spec: TrainSpec):
    if spec.env_name == "ps_ray_point":
        from ps_ray.envs.point import PointGoalEnv

        return PointGoalEnv()
    from ps_ray.envs import make

    return make(**spec.env_config)


def prepare_anchors(spec: TrainSpec, run_dir: Path):
    """The anchor set of a PS run: from spec.anchors, else k-means over random-policy rollouts."""
    from ps_ray.anchors import (
        AnchorSet, anchors_from_file, collect_task_states, load_anchor_set, save_anchor_set,
        select_anchors,
    )

    path = run_dir / "anchors.npz"
    if path.exists():
        return load_anchor_set(path)
    if spec.anchors is not None:
        anchor_set = anchors_from_file(spec.anchors, spec.interface_dim, seed=0)
    else:
        states = collect_task_states(lambda: make_env(spec), episodes=spec.anchor_episodes,
                                     seed=spec.seed)
        anchor_set = AnchorSet.of(select_anchors(states, spec.interface_dim, seed=0), {
            "source": "random-policy rollouts", "env": spec.env_config,
            "episodes": spec.anchor_episodes, "num_states": int(len(states))})
    save_anchor_set(path, anchor_set)
    return anchor_set


def _check_run_dir(spec: TrainSpec, run_dir: Path) -> None:
    spec_file = run_dir / "spec.json"
    if spec_file.exists():
        stored = json.loads(spec_file.read_text())
        if stored != spec.to_dict():
            changed = sorted(k for k in set(stored) | set(spec.to_dict())
                             if stored.get(k) != spec.to_dict().get(k))
            raise SpecError(f"{run_dir} holds a run of another spec (differs in {', '.join(changed)});"
                            f" use another --run-dir")
    else:
        run_dir.mkdir(parents=True, exist_ok=True)
        spec_file.write_text(json.dumps(spec.to_dict(), indent=2))


def _save(algo, run_dir: Path, signature) -> None:
    """Checkpoint into a fresh directory, then swap it in: a kill never leaves half a checkpoint."""
    tmp, final, old = (run_dir / f"{CHECKPOINT_DIR}.tmp", run_dir / CHECKPOINT_DIR,
                       run_dir / f"{CHECKPOINT_DIR}.old")
    shutil.rmtree(tmp, ignore_errors=True)
    algo.save_checkpoint(str(tmp))
    if final.exists():
        os.replace(final, old)
    os.replace(tmp, final)
    shutil.rmtree(old, ignore_errors=True)
    algo.export_policy(run_dir / POLICY_FILE, signature)


def _row(result: dict[str, Any], wall: float) -> dict[str, Any]:
    ours = result.get("ps_ray", {})
    row = {k: ours.get(k) for k in METRIC_FIELDS if k in ours}
    row.update(iteration=result.get("training_iteration"), env_steps=ours.get("env_steps"),
               updates=ours.get("updates"), wall_s=round(wall, 1))
    return row


def train(spec: TrainSpec, run_dir: str | Path, *, progress: bool = True) -> dict[str, Any]:
    """Train (or resume) until spec.env_steps; returns the last metrics row."""
    import ray

    from ps_ray.rllib.algo import algo_config
    from ps_ray.weights import Signature

    torch.set_num_threads(1)
    run_dir = Path(run_dir)
    _check_run_dir(spec, run_dir)
    anchor_set = prepare_anchors(spec, run_dir) if spec.method == "ps" else None
    anchors = None if anchor_set is None else anchor_set.anchors
    if not ray.is_initialized():
        ray.init(address="local", num_cpus=max(1, os.cpu_count() or 1), include_dashboard=False,
                 log_to_driver=False, configure_logging=False)
    algo = algo_config(spec, anchors).build_algo()
    dims = algo.replay_dims
    signature = Signature(method=spec.method, interface_dim=spec.interface_dim, hidden=spec.hidden,
                          anchor_hash="" if anchor_set is None else anchor_set.hash, **dims)
    checkpoint = run_dir / CHECKPOINT_DIR
    if checkpoint.exists():
        algo.load_checkpoint(str(checkpoint))
        if progress:
            print(f"[{spec.label()}] resumed at {algo.counters['env_steps']} env steps", flush=True)
    start, row = time.time(), {}
    with open(run_dir / METRICS_FILE, "a", newline="") as f:
        writer = csv.DictWriter(f, METRIC_FIELDS)
        if f.tell() == 0:
            writer.writeheader()
        while algo.counters["env_steps"] < spec.env_steps:
            result = algo.train()
            row = _row(result, time.time() - start)
            writer.writerow(row)
            if result["training_iteration"] % spec.checkpoint_every == 0:
                f.flush()
                _save(algo, run_dir, signature)
            if progress and row.get("eval_success") is not None:
                rate = algo.counters["env_steps"] / max(time.time() - start, 1e-9)
                print(f"[{spec.label()}] {row['env_steps']:>7}/{spec.env_steps} steps "
                      f"{row['updates']:>7} updates  train success {row.get('train_success', 0):.2f}"
                      f"  eval success {row['eval_success']:.2f} touching "
                      f"{_fmt(row.get('eval_touching'))}  {rate:.0f} steps/s", flush=True)
    _save(algo, run_dir, signature)
    final = algo.evaluate_greedy(spec.eval_episodes * 2)
    row = {**row, **{f"final_{k}": v for k, v in final.items()}}
    (run_dir / "result.json").write_text(json.dumps(row, indent=2))
    algo.stop()
    if progress:
        print(f"[{spec.label()}] done: final greedy success {final['success']:.2f}, touching "
              f"{_fmt(final['touching'])}; policy in {run_dir / POLICY_FILE}", flush=True)
    return row


def _fmt(x: float | None) -> str:
    return "n/a" if x is None or np.isnan(x) else f"{x:.2f}"
