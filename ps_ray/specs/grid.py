"""GridSpec: one co-trained robot x task grid (Devin et al. 2017; docs/transfer.md "Co-trained
grids"): the task modules of its tasks and the robot modules of its robots, trained together on
every cell but the held-out ones. Each trained cell is also a :class:`TrainSpec` (the base spec
with its robot and task), so its exported policy is an ordinary source to every later stage."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ps_ray.envs.core import env_widths
from ps_ray.errors import UserError
from ps_ray.specs.defaults import INTERFACE_DIM
from ps_ray.specs.engine import Seq, spec
from ps_ray.specs.modes import AnchorPolicy
from ps_ray.specs.names import EnvPart, parse_spec_text
from ps_ray.specs.titles import env_title, title, width_tag
from ps_ray.specs.train import SpecError, TrainSpec

Cell = tuple[EnvPart, EnvPart]  # (robot, task)
HELD_OUT_SEPARATOR = ";"  # between the cells of a grid's held-out text (a task's JSON has commas)


def cell_text(cell: Cell) -> str:
    """``"panda_far/reach_blue"``: a cell as a command line and a table name it."""
    return f"{cell[0].text}/{cell[1].text}"


def parse_cell(text: str, where: str = "held-out cell") -> tuple[str, str]:
    """``"robot/task"`` -> (robot, task); one line for anything else."""
    robot, sep, task = str(text).partition("/")
    if not sep or not robot or not task:
        raise SpecError(f"{where} {text!r} is not 'robot/task' (e.g. panda_far/reach_blue)")
    return robot, task


@dataclass(frozen=True)
class GridSpec:
    """``base``: method, seed, sizes and the budget per cell (its robot and task become the first
    trained cell's);
    ``held_out``: cells never trained (nor sampled), stitched zero-shot afterwards."""

    base: TrainSpec
    robots: tuple[EnvPart, ...]
    tasks: tuple[EnvPart, ...]
    held_out: tuple[Cell, ...] = ()

    def __post_init__(self) -> None:
        for name in ("robots", "tasks"):
            parts = tuple(EnvPart(p) for p in getattr(self, name))
            if not parts:
                raise SpecError(f"a grid needs at least one of {name}")
            if len(set(parts)) != len(parts):
                raise SpecError(f"grid {name} repeat one: {[p.text for p in parts]}")
            object.__setattr__(self, name, parts)
        if self.base.env is not None:
            raise SpecError(f"a grid trains robot x task cells; env {self.base.env!r} has no robot and task")
        cells = [(r, t) for r in self.robots for t in self.tasks]
        held = []
        for robot, task in self.held_out:
            cell = (EnvPart(robot), EnvPart(task))
            if cell not in cells:
                raise SpecError(
                    f"held-out cell {cell_text(cell)!r} is not in the grid; its cells: "
                    + ", ".join(cell_text(c) for c in cells)
                )
            held.append(cell)
        object.__setattr__(self, "held_out", tuple(dict.fromkeys(held)))
        trained = self.cells
        if trained:  # the base names the first trained cell: one grid, one spelling
            base = dataclasses.replace(self.base, robot=trained[0][0], task=trained[0][1])
            object.__setattr__(self, "base", base)
        for task in self.tasks:  # what the base checks of its own task (hindsight marker), every task
            dataclasses.replace(self.base, task=task)
        for kind, parts, index in (("robot", self.robots, 0), ("task", self.tasks, 1)):
            for part in parts:
                if not any(c[index] == part for c in trained):
                    raise SpecError(
                        f"the held-out cells {[cell_text(c) for c in self.held_out]} leave {kind} "
                        f"{part.text!r} with no trained cell, so its module would never learn"
                    )
        widths = {cell_text(c): env_widths(*c) for c in trained}
        if len(set(widths.values())) > 1:
            raise SpecError(
                "a grid's cells must share their widths (task input, robot state, action); got "
                + ", ".join(f"{k} {v}" for k, v in widths.items())
            )

    @classmethod
    def of(
        cls, base: TrainSpec, robots: Sequence[Any], tasks: Sequence[Any], held_out: Sequence[str] = ()
    ) -> GridSpec:
        """``held_out`` spelt ``"robot/task"``."""
        cells = [parse_cell(c) for c in held_out]
        held = tuple((parse_spec_text(r), parse_spec_text(t)) for r, t in cells)
        return cls(base, tuple(robots), tuple(tasks), held)  # type: ignore[arg-type]

    @property
    def cells(self) -> list[Cell]:
        """The trained cells, robot by robot, in the grid env's order."""
        return [(r, t) for r in self.robots for t in self.tasks if (r, t) not in self.held_out]

    def cell_spec(self, cell: Cell) -> TrainSpec:
        """The cell as an ordinary training spec (its policy file's spec.json)."""
        return dataclasses.replace(self.base, robot=cell[0], task=cell[1])

    def to_dict(self) -> dict[str, Any]:
        return {
            "base": self.base.to_dict(),
            "robots": [p.spelling for p in self.robots],
            "tasks": [p.spelling for p in self.tasks],
            "held_out": [[c[0].spelling, c[1].spelling] for c in self.held_out],
        }

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], where: str = "grid spec") -> GridSpec:
        unknown = sorted(set(data) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise SpecError(f"{where}: unknown key {unknown[0]!r}; valid keys: base, robots, tasks, held_out")
        base = TrainSpec.from_mapping(data["base"], where=f"{where}.base")
        held = tuple(tuple(c) for c in data.get("held_out", ()))
        return cls(base, tuple(data["robots"]), tuple(data["tasks"]), held)  # type: ignore[arg-type]

    def identity(self) -> dict[str, Any]:
        """What defines the grid being trained; the base's budget and reporting may change on
        resume (its robot and task follow the cells)."""
        base = {k: v for k, v in self.base.identity().items() if k not in ("robot", "task")}
        return {**self.to_dict(), "base": base}

    def label(self) -> str:
        return f"grid {self.base.method} seed {self.base.seed} held out {self.held_out_text or 'none'}"

    @property
    def run_key(self) -> str:
        """The grid's MLflow run name: ``grid/<method>/<seed>[/i<dim>]/held_out=<cells>``."""
        spec = self.base
        width = "" if spec.interface_dim == INTERFACE_DIM else f"/i{spec.interface_dim}"
        return f"grid/{spec.method}/{spec.seed}{width}/held_out={self.held_out_text}"

    @property
    def title(self) -> str:
        """Its MLflow run name (:mod:`ps_ray.specs.titles`): ``held out panda_far/reach_blue ·
        ablation · 411``."""
        held = " + ".join(env_title(*c) for c in self.held_out) or "none"
        return title(f"held out {held}", self.base.method, self.base.seed, width_tag(self.base.interface_dim))

    @property
    def held_out_text(self) -> str:
        """The held-out cells as one string (a zoo key's tag, :mod:`ps_ray.stitching.zoo`)."""
        return HELD_OUT_SEPARATOR.join(cell_text(c) for c in self.held_out)

    def digest_text(self) -> str:
        return json.dumps(self.identity(), sort_keys=True)


def grid_run_of(source_key: str) -> str | None:
    """The run key of the grid a co-trained cell's zoo key (``<trial key>/held_out=<cells>``,
    :mod:`ps_ray.stitching.zoo`) comes from; None for a source trained alone."""
    head, sep, held = source_key.partition("/held_out=")
    if not sep:
        return None
    method, _robot, _task, seed, *width = head.split("/")
    return f"grid/{method}/{seed}{''.join('/' + w for w in width)}/held_out={held}"


@spec("grid")
class GridSettings:
    """The sweep's grid stage (key ``grid``): for each method, seed and interface width, one
    co-trained grid over the sweep's robots x tasks per held-out cell."""

    held_out: Seq[str] = ()  # "robot/task", one grid each; () : each cell in turn
    methods: Seq[str] = ()  # default: the sweep's methods

    def __post_init__(self) -> None:
        from ps_ray.specs.methods import method_key

        try:
            object.__setattr__(self, "methods", tuple(method_key(m) for m in self.methods))
        except UserError as e:
            raise SpecError(f"grid.methods: {e}") from None
        for text in self.held_out:
            parse_cell(text, "grid.held_out: cell")

    def grids(self, sweep) -> list[GridSpec]:
        """The grids of a sweep (a :class:`ps_ray.specs.sweep.SweepSpec`): the base of each is the
        sweep's trial of its method, seed and width; a held-out cell outside the grid is refused
        in one line."""
        robots, tasks, trials = sweep.robots, sweep.tasks, sweep.trials()
        cells = self.held_out or [f"{r.text}/{t.text}" for r in robots for t in tasks]
        by_key = {(t.method, t.seed, t.interface_dim): t for t in trials}
        out = []
        for method in self.methods or sweep.methods:
            for seed in sweep.seeds:
                for dim in sweep.interface_dims:
                    for cell in cells:
                        try:
                            out.append(GridSpec.of(by_key[(method, seed, dim)], robots, tasks, [cell]))
                        except SpecError as e:
                            raise SpecError(f"grid: {e}") from None
        anchors = sweep.anchors
        if "train" not in sweep.stages and anchors.policy == AnchorPolicy.PLAIN and not anchors.file:
            if any(g.base.resolved.uses_anchors for g in out):
                raise SpecError(
                    "grid: anchors.policy 'plain' rolls out the plain sources the train stage "
                    "trains; add train to stages, or set anchors.policy: random or anchors.file"
                )
        return out
