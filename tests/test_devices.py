"""The maths that would run on a GPU, checked on a device other than the data's: PyTorch's ``meta``
device (shapes only, no memory) stands in for CUDA, so a CPU tensor that leaks into a computation
on the learner's device fails here as it would there."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ps_ray.nets.consolidate import consolidate
from ps_ray.nets.normalize import RunningNorm
from ps_ray.nets.sac import SACHyper, build_sac_nets, sac_forward, sac_losses
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import ConsolidateSpec
from tests.code_paths import CODE_PATHS

DIMS = NetDims(6, 8, 7)


def _nets(method: str, device: str):
    anchors = np.random.default_rng(0).normal(size=(8, DIMS.task_dim)).astype(np.float32)
    with torch.device(device):
        return build_sac_nets(method, DIMS, interface_dim=8, hidden=16, anchors=anchors)


def _batch(device: str, n: int = 4) -> dict[str, torch.Tensor]:
    widths = {"task_in": 6, "robot_in": 8, "next_task_in": 6, "next_robot_in": 8, "actions": 7}
    return {k: torch.zeros(n, w, device=device) for k, w in widths.items()}


def test_a_running_norm_merges_a_cpu_batch_into_statistics_on_another_device():
    with torch.device("meta"):
        norm = RunningNorm(3)
    norm.update(torch.randn(5, 3))  # a CPU batch, as the replay buffer gives it
    assert norm.mean.device.type == norm.var.device.type == norm.count.device.type == "meta"
    cpu = RunningNorm(3)
    cpu.update(torch.tensor([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]]))
    assert cpu.mean.tolist() == [2.0, 2.0, 2.0] and cpu.var.tolist() == [1.0, 0.0, 1.0]


@pytest.mark.parametrize("method", CODE_PATHS)
def test_the_sac_losses_stay_on_the_learners_device(method):
    nets = _nets(method, "meta")
    fwd = sac_forward(nets, _batch("meta"))
    losses = sac_losses(fwd, torch.zeros(4, device="meta"), torch.zeros((), device="meta"), SACHyper(), 7)
    assert {v.device.type for v in losses.values()} == {"meta"}
    losses["total"].backward()  # the backward pass too
    assert all(p.grad is None or p.grad.device.type == "meta" for p in nets.parameters())


def test_consolidation_moves_cpu_replay_states_to_the_actors_device():
    """On a real accelerator the figures come back as floats; meta has no values to return, so
    the check stops at the first read-out, after every tensor met on the actor's device."""
    nets = _nets("ps_distilled", "meta")
    spec = ConsolidateSpec(updates=2, batch_size=4)
    task_in, robot_in = torch.randn(spec.rows, 6), torch.randn(spec.rows, 8)  # on the CPU
    with pytest.raises(RuntimeError, match="meta"):
        consolidate(nets.actor, task_in, robot_in, spec)
    # the same call with a CPU actor returns its figures: the CPU path is unchanged
    stats = consolidate(_nets("ps_distilled", "cpu").actor, task_in, robot_in, spec)
    assert set(stats) == {"gap_before", "gap_after", "bc"}
