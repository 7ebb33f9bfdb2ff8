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

import numpy as np
import torch
from torch import Tensor

from ps_ray.specs.methods import ConsolidateSpec

if TYPE_CHECKING:
    from ps_ray.nets.modular import Actor


def consolidate(actor: Actor, task_in: Tensor, robot_in: Tensor, spec: ConsolidateSpec) -> dict[str, float]:
    """Consolidate ``actor`` in place on ``spec.rows`` states (task_in, robot_in), taken as
    ``spec.updates`` consecutive minibatches. Returns the reference gap before and after and the
    last minibatch's action error (``bc``)."""
    return consolidate_cells([actor], [task_in], [robot_in], spec)


def consolidate_cells(
    actors: list[Actor], task_ins: list[Tensor], robot_ins: list[Tensor], spec: ConsolidateSpec
) -> dict[str, float]:
    """Consolidate the cells of a co-trained grid together, in place: each cell's actor (views
    that share task and robot modules) on its own ``spec.rows`` states. Each update sums the
    cells' action errors and pulls, so a shared module is stepped once with the sum of its cells'
    gradients, as in the grid's training; every teacher is its cell's actor as it was before any
    projection was switched on. One cell is :func:`consolidate`. Returns the gaps before and
    after and the last minibatch's action error, means over cells."""
    for actor, task_in, robot_in in zip(actors, task_ins, robot_ins, strict=True):
        if actor.task.relative is None:
            raise ValueError(f"method {actor.spec.name!r} has no relative interface to consolidate")
        if len(task_in) != spec.rows or len(robot_in) != spec.rows:
            raise ValueError(
                f"consolidation needs {spec.rows} states, got {len(task_in)} and {len(robot_in)}"
            )
    device = next(actors[0].parameters()).device  # replay states arrive on the CPU
    task_ins = [t.to(device) for t in task_ins]
    robot_ins = [r.to(device) for r in robot_ins]
    teachers = [copy.deepcopy(actor).requires_grad_(False) for actor in actors]
    for actor in actors:
        if actor.task.projection is None:  # a task module shared by two cells is switched once
            actor.task.switch_relative_on()

    def gaps() -> list[float]:  # each cell's interface gap to the input reference, on a probe
        return [
            a.task.relative.reference_gap(a.task.encode, t[: spec.batch_size]).item()
            for a, t in zip(actors, task_ins)
        ]

    with torch.no_grad():
        gap_before = gaps()
    parameters = {id(p): p for actor in actors for p in actor.parameters()}  # shared modules once
    optimizer = torch.optim.Adam(parameters.values(), lr=spec.lr)
    bcs = [torch.zeros((), device=device)] * len(actors)
    batches = [
        zip(t.split(spec.batch_size), r.split(spec.batch_size), strict=True)
        for t, r in zip(task_ins, robot_ins)
    ]
    for step in zip(*batches, strict=True):
        loss, bcs = 0.0, []
        for actor, teacher, (task, robot) in zip(actors, teachers, step):
            mean, log_std = actor(task, robot)
            with torch.no_grad():
                mean_kept, log_std_kept = teacher(task, robot)
            bc = (torch.tanh(mean) - torch.tanh(mean_kept)).pow(2).sum(-1).mean()
            bc = bc + spec.log_std_weight * (log_std - log_std_kept).pow(2).mean()
            bcs.append(bc)
            loss = loss + (bc + spec.pull * actor.task.relative.reference_gap(actor.task.encode, task))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        gap_after = gaps()
    return {
        "gap_before": float(np.mean(gap_before)),
        "gap_after": float(np.mean(gap_after)),
        "bc": float(np.mean([b.item() for b in bcs])),
    }
