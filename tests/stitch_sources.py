"""Source policies for the stitching tests: random nets, and trials written as a sweep leaves them."""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np
import torch

from ps_ray.nets.from_signature import signature_of
from ps_ray.nets.modular import update_normalizers
from ps_ray.nets.policy_file import save_policy
from ps_ray.nets.sac import SACNets, build_sac_nets
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import method_spec, uses_anchors
from ps_ray.specs.names import EnvPart
from ps_ray.stitching.paper import PANDA_L3_GRIPPER
from ps_ray.stitching.stitch import env_dims
from ps_ray.store.attempts import FINISHED, PARAMS_FILE, RESULT_FILE
from ps_ray.store.checkpoint import STATE_FILE, seal
from ps_ray.store.signature import Signature

PUSH, PICK, REACH = NetDims(15, 8, 7), NetDims(15, 8, 8), NetDims(3, 8, 7)
K = 8  # interface dim = number of anchors


def anchors_for(k: int = K, task_dim: int = 15, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(k, task_dim)).astype(np.float32)


ANCHORS, OTHER_ANCHORS = anchors_for(), anchors_for(seed=1)
SEEDS = itertools.count(10)


def make_nets(
    method: str = "ps",
    dims: NetDims = PUSH,
    *,
    interface_dim: int = K,
    hidden: int = 16,
    anchors: np.ndarray | None = ANCHORS,
    seed: int = 0,
    finished: bool = True,
) -> tuple[SACNets, Signature]:
    """Random nets with non-trivial normaliser statistics and targets that differ from the critics;
    ``finished``: a deferred relative projection (ps_distilled) is switched on, as at a run's end."""
    torch.manual_seed(seed)
    nets = build_sac_nets(
        method,
        dims,
        interface_dim=interface_dim,
        hidden=hidden,
        anchors=anchors if uses_anchors(method) else None,
    )
    g = torch.Generator().manual_seed(seed)
    update_normalizers(
        nets,
        2 * torch.randn(64, dims.task_dim, generator=g) + 1,
        torch.randn(64, dims.robot_dim, generator=g),
    )
    with torch.no_grad():
        for p in [*nets.target_critic.parameters(), *nets.target_critic_twin.parameters()]:
            p.add_(0.05 * torch.randn(p.shape, generator=g))
    if finished and method_spec(method).defer_relative:
        nets.actor.task.switch_relative_on()
    return nets, signature_of(nets, method, interface_dim, hidden)


def spec(method: str, robot, task, seed: int = 1, interface_dim: int = K) -> dict:
    """A trial's spec.json as TrainSpec writes it (robot and task as spelled in JSON)."""
    return {
        "method": method,
        "robot": EnvPart(robot).spelling,
        "task": EnvPart(task).spelling,
        "seed": seed,
        "interface_dim": interface_dim,
        "hidden": 16,
        "env_steps": 300,
    }


def write_trial(
    root: Path,
    stage_dir: str,
    trial_spec: dict,
    *,
    checkpoint: int = 2,
    trial: str | None = None,
    seed: int | None = None,
    anchor_seed: int = 0,
) -> Path:
    """A trial as Tune and ps_ray leave it, with random nets: params.json naming the trial, a
    finished result row, and a sealed checkpoint (policy.safetensors, signature.json, spec.json,
    ps_ray_state.json, manifest.json); ``checkpoint`` x 100 env steps."""
    dims = env_dims(trial_spec["robot"], trial_spec["task"])
    k = trial_spec["interface_dim"]
    nets = make_nets(
        trial_spec["method"],
        dims,
        interface_dim=k,
        anchors=anchors_for(k, dims.task_dim, anchor_seed),
        seed=next(SEEDS) if seed is None else seed,
    )
    name = trial or f"sweep_trial_{next(SEEDS):05d}"
    directory = root / stage_dir / name / f"checkpoint_{checkpoint:06d}"
    save_policy(directory / "policy.safetensors", *nets)
    (directory / "signature.json").write_text(json.dumps(dataclasses.asdict(nets[1])))
    (directory / "spec.json").write_text(json.dumps(trial_spec))
    state = {"counters": {"env_steps": 100 * checkpoint}, "iteration": checkpoint}
    (directory / STATE_FILE).write_text(json.dumps(state))
    seal(directory)
    (directory.parent / PARAMS_FILE).write_text(json.dumps({"trial": {"spec": trial_spec}}))
    row = {"env_steps": 100 * checkpoint, FINISHED: True, "timestamp": checkpoint}
    with open(directory.parent / RESULT_FILE, "a") as f:
        f.write(json.dumps(row) + "\n")
    return directory / "policy.safetensors"


def fake_sweep(root: Path) -> Path:
    """A tune tree of random policies under ``root``: ps and ablation on two arms x push / pick_cube,
    a gripper push policy, a seed-2 and an i16 ps policy, and a plain anchor source."""
    for robot in ("panda", "panda_l3"):
        for task in ("push", "pick_cube"):
            write_trial(root, "tune", spec("ps", robot, task))
            write_trial(root, "tune", spec("ablation", robot, task))
    write_trial(root, "tune", spec("ps", PANDA_L3_GRIPPER, "push"))
    write_trial(root, "tune", spec("ps", "panda", "push", seed=2))
    write_trial(root, "tune", spec("ps", "panda", "push", interface_dim=16))
    write_trial(root, "tune_plain", spec("plain", "panda", "push"))
    return root
