"""Which marker does an actor follow? On the marker family (docs/results/ps_family.md "Does ps learn
the marker family?") a policy that learned its task moves its action with the named marker and ignores the
other; one that did not moves with both alike. Selectivity = the mean change of the greedy action
(:class:`ps_ray.nets.policy.GreedyPolicy`'s) when the named marker moves ``step`` metres, over the
change when the other marker does, each axis in turn, over probe scenes, the arm at its robot
module's running mean (a typical arm state)."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from ps_ray.nets.modular import Actor
from ps_ray.nets.policy import GreedyPolicy

MARKER_STEP = 0.05  # metres: a marker moved well within the scene's box


class Selectivity(NamedTuple):
    named: float  # mean action change when the named marker moves
    other: float  # ... when the other marker moves

    @property
    def ratio(self) -> float:
        return self.named / self.other if self.other > 0 else float("inf")


@torch.no_grad()
def marker_selectivity(
    actor: Actor, scenes: Tensor, named: slice, other: slice, step: float = MARKER_STEP
) -> Selectivity:
    """``scenes``: task inputs (B x task_dim); ``named``/``other``: the two markers' columns."""
    norm = actor.robot.norm
    if norm is None:
        raise ValueError("marker selectivity needs a modular actor (its robot module's running mean)")
    act = GreedyPolicy(actor).net  # the greedy action on tensors (an eval-mode copy: no dropout)
    robot = norm.mean.expand(len(scenes), -1)
    base = act(scenes, robot)

    def moved(columns: slice) -> float:
        changes = []
        for column in range(columns.start, columns.stop):
            shifted = scenes.clone()
            shifted[:, column] += step
            changes.append((act(shifted, robot) - base).norm(dim=-1).mean())
        return float(torch.stack(changes).mean())

    return Selectivity(moved(named), moved(other))
