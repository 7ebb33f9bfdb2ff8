"""`ps-ray grid`: one co-trained grid (:class:`ps_ray.specs.grid.GridSpec`) trained (or resumed)
into a run folder through the one training loop (:class:`ps_ray.rllib.loop.TrainingRun`).

A grid folder holds:
  grid.json          the GridSpec (a folder belongs to one grid; another is refused)
  anchors/<t>/       PS: task t's anchor set (k-means over random rollouts of its first cell)
  checkpoint/        learner tensors, one replay per cell, counters, each cell's policy; sealed
  cells/<cell>/      each trained cell as an ordinary source: spec.json (the cell's TrainSpec),
                     policy.safetensors (the grid's own modules for that cell), result.json
  metrics.csv        one row per training step: the worst cell's figures and each cell's
  result.json        the final figures, each cell's on episodes the stopping rule never read
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from ps_ray.envs.goals import ROBOT_KEY, TASK_KEYS
from ps_ray.envs.grid import cell_key
from ps_ray.rllib.loop import TrainingRun, start_local_ray
from ps_ray.rllib.run_loop import train_to_folder
from ps_ray.specs.grid import Cell, GridSpec, cell_text
from ps_ray.specs.methods import spec_json
from ps_ray.specs.train import require_same
from ps_ray.store import checkpoint
from ps_ray.store.atomic import write_text
from ps_ray.store.layout import LOG_FOLDER
from ps_ray.store.lock import folder_lock
from ps_ray.store.run_folder import latest_checkpoint
from ps_ray.store.run_layout import (
    CELLS_FOLDER,
    GRID_FILE,
    METRIC_FIELDS,
    POLICY_FILE,
    RESULT_FILE,
    SPEC_FILE,
    cell_policy_file,
    cell_spec_file,
)
from ps_ray.store.signature import Signature
from ps_ray.store.terminal import others_to


def cell_folder(cell: Cell) -> str:
    """A cell's folder name under ``cells/``: ``panda_far-reach_blue``."""
    return re.sub(r"[^\w.-]+", "-", cell_text(cell).replace("/", "-")).strip("-")


class GridRun(TrainingRun):
    """A :class:`TrainingRun` of a grid: the same loop, stopping rule (on the worst cell's greedy
    success) and checkpoints, with one policy file per trained cell."""

    def __init__(self, grid: GridSpec, anchor_sets: list, *, threads: int = 1) -> None:
        """``anchor_sets``: each task's (PS) or None; ``threads``: torch's CPU threads."""
        import torch

        from ps_ray.rllib.algo import grid_algo_config

        torch.set_num_threads(threads)
        self.grid = grid
        self.keys = [cell_key(i) for i in range(len(grid.cells))]
        self.metric_fields = METRIC_FIELDS + tuple(f"eval_{k}_success" for k in self.keys)
        anchors = [None if a is None else a.anchors for a in anchor_sets]
        self.begin(grid.base, grid_algo_config(grid, anchors).build_algo())
        replay = self.algo.replays[self.keys[0]]  # every cell has the same widths (GridSpec)
        self.signatures = [
            Signature(
                method=grid.base.method,
                settings=spec_json(grid.base.resolved),
                interface_dim=grid.base.interface_dim,
                hidden=grid.base.hidden,
                anchor_hash=""
                if anchor_sets[grid.tasks.index(t)] is None
                else anchor_sets[grid.tasks.index(t)].hash,
                task_dim=sum(replay.obs_spec[k][0][0] for k in TASK_KEYS),
                robot_dim=replay.obs_spec[ROBOT_KEY][0][0],
                action_dim=replay.action_dim,
            )
            for _, t in grid.cells
        ]

    def save(self, directory: Path) -> None:
        directory = Path(directory)
        self.algo.save_checkpoint(str(directory))
        self.algo.export_cells(
            [directory / cell_policy_file(i) for i in range(len(self.keys))], self.signatures
        )
        for index, cell in enumerate(self.grid.cells):  # each cell's spec, for the zoo
            spec_text = json.dumps(self.grid.cell_spec(cell).to_dict(), indent=2)
            (directory / cell_spec_file(index)).write_text(spec_text)
        (directory / GRID_FILE).write_text(json.dumps(self.grid.to_dict(), indent=2))
        progress = {"streak": self.streak, "best": self.best, "consolidated": self.consolidated}
        (directory / checkpoint.PROGRESS_FILE).write_text(json.dumps(progress))
        checkpoint.seal(directory)

    def progress_line(self, row: dict[str, Any]) -> str:
        cells = "  ".join(
            f"{cell_text(c)} {row.get(f'eval_{k}_success', 0):.2f}"
            for c, k in zip(self.grid.cells, self.keys)
        )
        return (
            f"[{self.grid.label()}] {row['env_steps']:>7}/{self.spec.env_steps} steps per cell "
            f"{row['updates']:>7} updates  eval success {cells}"
        )


def _check_grid_dir(grid: GridSpec, run_dir: Path) -> None:
    path = run_dir / GRID_FILE
    if path.exists():
        stored = GridSpec.from_mapping(json.loads(path.read_text()), where=str(path)).identity()
        require_same(stored, grid.identity(), f"{run_dir} holds another grid", "use another --run-dir")


def grid_anchor_sets(grid: GridSpec, run_dir: Path) -> list:
    """Each task's anchor set (PS), from random rollouts of the task's first trained cell; None
    per task for methods without anchors. Saved into the folder, read back on resume."""
    from ps_ray.rllib.loop import prepare_anchors

    if not grid.base.resolved.uses_anchors:
        return [None] * len(grid.tasks)
    sets = []
    for index, task in enumerate(grid.tasks):
        first = next(c for c in grid.cells if c[1] == task)
        folder = run_dir / "anchors" / str(index)
        folder.mkdir(parents=True, exist_ok=True)
        sets.append(prepare_anchors(grid.cell_spec(first), folder))
    return sets


def train_grid(grid: GridSpec, run_dir: str | Path, *, progress: bool = True) -> dict[str, Any]:
    """Train (or resume) until the budget per cell or every cell's success target; returns the
    final figures. One process at a time per folder."""
    run_dir = Path(run_dir).resolve()
    _check_grid_dir(grid, run_dir)
    with folder_lock(run_dir, "grid"):
        return _train_grid(grid, run_dir, progress)


def _train_grid(grid: GridSpec, run_dir: Path, progress: bool) -> dict[str, Any]:
    anchor_sets = grid_anchor_sets(grid, run_dir)
    with others_to(run_dir / LOG_FOLDER / "ray.log"):
        start_local_ray()
        run = GridRun(grid, anchor_sets)
    resume_from = latest_checkpoint(run_dir)
    if resume_from is not None:
        run.restore(resume_from)
        if progress:
            print(f"[{grid.label()}] resumed at {run.env_steps} env steps per cell", flush=True)
    write_text(run_dir / GRID_FILE, json.dumps(grid.to_dict(), indent=2))
    cells = {
        cell_policy_file(i): f"{CELLS_FOLDER}/{cell_folder(c)}/{POLICY_FILE}"
        for i, c in enumerate(grid.cells)
    }
    for cell in grid.cells:
        spec_path = run_dir / CELLS_FOLDER / cell_folder(cell) / SPEC_FILE
        spec_path.parent.mkdir(parents=True, exist_ok=True)
        write_text(spec_path, json.dumps(grid.cell_spec(cell).to_dict(), indent=2))

    def on_row(row: dict[str, Any]) -> None:
        if progress and row.get("eval_success") is not None:
            print(run.progress_line(row), flush=True)

    result, final = train_to_folder(run, run_dir, run.metric_fields, copy_out=cells, on_row=on_row)
    for index, cell in enumerate(grid.cells):
        key = cell_key(index)
        figures = {"success": final[f"{key}_success"], "touching": final[f"{key}_touching"]}
        write_text(run_dir / CELLS_FOLDER / cell_folder(cell) / RESULT_FILE, json.dumps(figures, indent=2))
    write_text(run_dir / RESULT_FILE, json.dumps(result, indent=2))
    run.stop()
    if progress:
        text = ", ".join(
            f"{cell_text(c)} {final[f'{cell_key(i)}_success']:.2f}" for i, c in enumerate(grid.cells)
        )
        print(
            f"[{grid.label()}] done: final greedy success {text}; cells in {run_dir / CELLS_FOLDER}",
            flush=True,
        )
    return result
