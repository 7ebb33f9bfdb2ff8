"""Consolidation: align a trained relative actor's interface without env steps (docs/alignment.md).

A pull toward the input reference during training aligns sources but slows their learning: the
robot module must learn to read an interface that is being moved under it. Consolidation moves the
interface after the source has learned instead. The actor is distilled into itself on replay
states: it keeps the actions of its frozen pre-consolidation copy (squared error of the squashed
mean summed over action dims, plus ``log_std_weight`` x the mean squared error of the log-std),
while ``pull`` x the interface's gap to the input reference
(:meth:`RelativeProjection.reference_gap`) draws every source toward the same function of the
anchors. Supervised updates on states already collected: no env steps, no critic. The norm
penalty of training (``norm_reg``) is not applied.

A method with a deferred projection (``MethodSpec.defer_relative``) trains on the raw latent, as
the ablation does; consolidation first switches its projection on, so the teacher is the trained
raw-latent actor and the robot module learns to read the relative interface from it (distillation
into a new interface rather than into itself).
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from ps_ray.specs.methods import ConsolidateSpec

if TYPE_CHECKING:
    from ps_ray.nets.modular import Actor


def consolidate(actor: Actor, task_in: Tensor, robot_in: Tensor, spec: ConsolidateSpec) -> dict[str, float]:
    """Consolidate ``actor`` in place on ``spec.rows`` states (task_in, robot_in), taken as
    ``spec.updates`` consecutive minibatches. Returns the reference gap before and after and the
    last minibatch's action error (``bc``)."""
    relative = actor.task.relative
    if relative is None:
        raise ValueError(f"method {actor.spec.name!r} has no relative interface to consolidate")
    if len(task_in) != spec.rows or len(robot_in) != spec.rows:
        raise ValueError(f"consolidation needs {spec.rows} states, got {len(task_in)} and {len(robot_in)}")
    device = next(actor.parameters()).device  # replay states arrive on the CPU
    task_in, robot_in = task_in.to(device), robot_in.to(device)
    teacher = copy.deepcopy(actor).requires_grad_(False)
    if actor.task.projection is None:
        actor.task.switch_relative_on()
    probe = task_in[: spec.batch_size]
    with torch.no_grad():
        gap_before = relative.reference_gap(actor.task.encode, probe).item()
    optimizer = torch.optim.Adam(actor.parameters(), lr=spec.lr)
    bc = torch.zeros((), device=device)
    for task, robot in zip(task_in.split(spec.batch_size), robot_in.split(spec.batch_size), strict=True):
        mean, log_std = actor(task, robot)
        with torch.no_grad():
            mean_kept, log_std_kept = teacher(task, robot)
        bc = (torch.tanh(mean) - torch.tanh(mean_kept)).pow(2).sum(-1).mean()
        bc = bc + spec.log_std_weight * (log_std - log_std_kept).pow(2).mean()
        loss = bc + spec.pull * relative.reference_gap(actor.task.encode, task)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        gap_after = relative.reference_gap(actor.task.encode, probe).item()
    return {"gap_before": gap_before, "gap_after": gap_after, "bc": bc.item()}
