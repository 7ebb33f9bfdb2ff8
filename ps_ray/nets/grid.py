"""The modules of a co-trained grid: one task module per task and one robot module per robot, for
the actor and each critic, with the critics' targets; every trained cell is a view that joins its
task's and its robot's modules (the same objects every other cell of that task or robot uses).

A cell's view has the five attributes of :class:`ps_ray.nets.sac.SACNets`, so the SAC math
(:func:`ps_ray.nets.sac.sac_forward`), the normaliser updates and the policy file take it as they
take one trained policy; exporting a cell writes exactly the grid's own modules.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from ps_ray.nets.modular import Actor, Critic, build_actor, build_critic
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import MethodSpec

# (online, target) attribute names of the critics' module tables
CRITIC_TABLES = (
    ("critic_tasks", "target_critic_tasks"),
    ("critic_robots", "target_critic_robots"),
    ("critic_twin_tasks", "target_critic_twin_tasks"),
    ("critic_twin_robots", "target_critic_twin_robots"),
)
ACTOR_TABLES = ("actor_tasks", "actor_robots")
GRID_TABLES = ACTOR_TABLES + tuple(name for pair in CRITIC_TABLES for name in pair)


class CellNets(nn.Module):
    """One trained cell: the five SAC nets, made of the grid's shared modules."""

    def __init__(
        self, actor: Actor, critic: Critic, critic_twin: Critic, target: Critic, target_twin: Critic
    ):
        super().__init__()
        self.actor, self.critic, self.critic_twin = actor, critic, critic_twin
        self.target_critic, self.target_critic_twin = target, target_twin


def _frozen(table: nn.ModuleDict) -> nn.ModuleDict:
    target = copy.deepcopy(table)
    target.requires_grad_(False)
    return target


def add_grid_modules(
    owner: nn.Module,
    method: str | MethodSpec,
    dims: NetDims,
    *,
    tasks: int,
    robots: int,
    cells: Sequence[tuple[int, int]],
    interface_dim: int,
    hidden: int,
    anchors: Sequence[np.ndarray | None],
) -> list[CellNets]:
    """Give ``owner`` the grid's module tables (:data:`GRID_TABLES`, keyed by task or robot index)
    and return the views of ``cells`` ((task index, robot index) pairs). Every module comes from the
    one network builder; ``anchors``: each task's anchor set (PS) or None."""

    def anchor_t(index: int):
        a = anchors[index]
        return None if a is None else torch.as_tensor(np.asarray(a, np.float32))

    def options(task: int) -> dict:
        return dict(interface_dim=interface_dim, hidden=hidden, anchors=anchor_t(task))

    tables = {name: nn.ModuleDict() for name in GRID_TABLES}
    for role, build in (("actor", build_actor), ("critic", build_critic), ("critic_twin", build_critic)):
        for t in range(tasks):
            tables[f"{role}_tasks"][str(t)] = build(method, dims, **options(t)).task
        for r in range(robots):  # a robot module is built beside a task's (anchors do not reach it)
            tables[f"{role}_robots"][str(r)] = build(method, dims, **options(0)).robot
    for online, target in CRITIC_TABLES:
        tables[target] = _frozen(tables[online])
    for name, table in tables.items():
        setattr(owner, name, table)
    return [cell_view(owner, t, r) for t, r in cells]


def cell_view(owner: nn.Module, task: int, robot: int) -> CellNets:
    t, r = str(task), str(robot)
    pick = lambda role, cls: cls(getattr(owner, f"{role}_tasks")[t], getattr(owner, f"{role}_robots")[r])  # noqa: E731
    return CellNets(
        pick("actor", Actor),
        pick("critic", Critic),
        pick("critic_twin", Critic),
        pick("target_critic", Critic),
        pick("target_critic_twin", Critic),
    )


def grid_critic_pairs(owner: nn.Module) -> list[tuple[nn.Module, nn.Module]]:
    """(online, target) module tables, for Polyak averaging each shared module once."""
    return [(getattr(owner, online), getattr(owner, target)) for online, target in CRITIC_TABLES]
