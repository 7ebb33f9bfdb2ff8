"""A sweep's stitching matrix: every stitched combination of its zoo's modules (which pairs meet
is :mod:`ps_ray.stitching.rule`'s answer) and the unstitched controls scored beside each.
Torch-free: listing the matrix loads no nets."""

from __future__ import annotations

from dataclasses import dataclass

from ps_ray.specs.grid import HELD_OUT_SEPARATOR
from ps_ray.specs.names import EnvPart
from ps_ray.stitching.rule import stitchable, target_problems
from ps_ray.stitching.zoo import ModuleZoo, ZooEntry


@dataclass(frozen=True)
class Combo:
    """One stitched policy of a sweep: task module, robot module and the env it is meant for."""

    task_from: ZooEntry
    robot_from: ZooEntry
    robot: EnvPart  # target env
    task: EnvPart

    @property
    def label(self) -> str:
        t, r = self.task_from.key, self.robot_from.key
        return f"t: {t.task}-{t.robot} & r: {r.task}-{r.robot}"


def combos(
    zoo: ModuleZoo,
    method: str,
    seed: int,
    interface_dim: int | None = None,
    robot_seed: int | None = None,
    grid: str = "",
) -> list[Combo]:
    """Every valid (task module, robot module) pair of one method: task module from (task X, robot
    Ra) of ``seed``, robot module from (task Y, robot Rb) of ``robot_seed`` (default: the same
    seed; another seed makes cross-seed pairs, modules of separate training runs), X != Y, Ra != Rb
    (different arms), target env (Rb, X); pairs that cannot be stitched or cannot run their target
    are left out. With ``grid`` (a co-trained grid's held-out cells, :mod:`ps_ray.pipeline.grid`),
    both modules come from that grid's cells (of each seed), and only held-out targets are kept:
    the grid trained every other target itself."""
    tasks = zoo.select(method=method, seed=seed, interface_dim=interface_dim, grid=grid)
    robots = (
        tasks
        if robot_seed in (None, seed)
        else zoo.select(method=method, seed=robot_seed, interface_dim=interface_dim, grid=grid)
    )
    held_out = grid.split(HELD_OUT_SEPARATOR) if grid else None
    found = []
    for t in tasks:
        for r in robots:
            target = stitchable(t.spec, r.spec, t.signature, r.signature)
            if target is not None and (held_out is None or f"{target[0].text}/{target[1].text}" in held_out):
                found.append(Combo(t, r, *target))
    return found


def controls(zoo: ModuleZoo, combo: Combo) -> dict[str, ZooEntry]:
    """The unstitched policies to score beside a stitched pair, on its target env and episodes
    (docs/controls.md): ``robot_source``, the robot module's own policy (task Y, robot Rb) run on
    task X as it is; ``task_source``, the task module's own policy (task X, robot Ra) run on robot
    Rb; ``oracle``, the policy the sweep trained on the target pair itself (task X, robot Rb, the
    robot module's seed; trained alone, also beside a co-trained grid's pair). A role is left out
    where its policy cannot run the target (other widths) or, for the oracle, where the sweep did
    not train it."""
    target = (combo.robot, combo.task)
    found = {
        role: entry
        for role, entry in (("robot_source", combo.robot_from), ("task_source", combo.task_from))
        if entry.signature.stitchable and not target_problems(entry.signature, target)
    }
    r = combo.robot_from.key
    for entry in zoo.select(method=r.method, seed=r.seed, interface_dim=r.interface_dim):
        if (entry.key.robot, entry.key.task) == (r.robot, combo.task_from.key.task):
            if entry.signature.stitchable and not target_problems(entry.signature, target):
                found["oracle"] = entry
    return found
