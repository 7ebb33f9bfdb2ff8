"""A population's training run: the one training loop (:class:`ps_ray.rllib.loop.TrainingRun`)
over a :class:`ps_ray.rllib.population_sac.PopulationSAC`, with a stopping rule per member.

Each member stops as its source alone would: at ``target_success`` in ``target_evals`` greedy
evaluations in a row (its own, ``eval_c<i>_success``). A member that stops is finally evaluated
then (on the episodes its source's final evaluation would use), its policy file kept as it was at
that moment, and it is updated no more (its minibatches leave the updates) nor stepped (its env
is frozen: ``GridEnv.freeze``). The run ends when every member has stopped, or at the budget.

A checkpoint holds the population's learner and replays (a grid's), each member's policy file,
spec and, once stopped, result, and population.json.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ps_ray.envs.goals import ROBOT_KEY, TASK_KEYS
from ps_ray.envs.grid import cell_key
from ps_ray.rllib.loop import TrainingRun
from ps_ray.specs.methods import spec_json
from ps_ray.specs.population import PopulationSpec
from ps_ray.store import checkpoint
from ps_ray.store.run_layout import (
    METRIC_FIELDS,
    POPULATION_FILE,
    cell_policy_file,
    cell_result_file,
    cell_spec_file,
)
from ps_ray.store.signature import Signature

MEMBER_FIGURES = ("success", "touching")  # each member's own columns of a row: train_c00_success, ...


def member_streaks(
    streaks: Sequence[int], row: Mapping[str, Any], target: float, evals: int
) -> tuple[list[int], list[int]]:
    """Each member's evaluations in a row at or above ``target`` after ``row`` (a member not
    evaluated in it keeps its streak), and the members whose streak reaches ``evals`` now."""
    after, met = [], []
    for index, streak in enumerate(streaks):
        success = row.get(f"eval_{cell_key(index)}_success")
        if success is not None:
            streak = streak + 1 if success >= target else 0
            if streak == evals:
                met.append(index)
        after.append(streak)
    return after, met


class PopulationRun(TrainingRun):
    """A :class:`TrainingRun` of a population: the same loop and checkpoints; each member stops on
    its own, and the run is done once all have (or at the budget)."""

    def __init__(
        self, population: PopulationSpec, anchor_sets: Sequence, *, threads: int = 1, gpu: float = 0
    ) -> None:
        """``anchor_sets``: each member's (PS) or None; ``gpu``: the learner's GPU share."""
        import torch

        from ps_ray.rllib.algo import population_algo_config

        torch.set_num_threads(threads)
        self.population = population
        members = population.members
        self.keys = [cell_key(i) for i in range(len(members))]
        self.metric_fields = METRIC_FIELDS + tuple(
            f"{stage}_{k}_{figure}"
            for k in self.keys
            for stage in ("train", "eval")
            for figure in MEMBER_FIGURES
        )
        anchors = [None if a is None else a.anchors for a in anchor_sets]
        self.begin(population.base, population_algo_config(population, anchors, gpu=gpu).build_algo())
        replay = self.algo.replays[self.keys[0]]  # every member has the same widths (PopulationSpec)
        widths = {
            "task_dim": sum(replay.obs_spec[k][0][0] for k in TASK_KEYS),
            "robot_dim": replay.obs_spec[ROBOT_KEY][0][0],
            "action_dim": replay.action_dim,
        }
        self.signatures = [
            Signature(
                method=m.method,
                settings=spec_json(m.resolved),
                interface_dim=m.interface_dim,
                hidden=m.hidden,
                anchor_hash="" if a is None else a.hash,
                **widths,
            )
            for m, a in zip(members, anchor_sets)
        ]
        self.streaks = [0] * len(members)
        self.stopped: dict[int, dict[str, float]] = {}  # member -> its final figures, at its stop
        self._stopped_now = False  # a member stopped in the latest step: checkpoint it at once
        self._stopped_files: dict[int, bytes] = {}  # member -> its policy file, as it stopped

    @property
    def converged(self) -> bool:
        """Every member met the success target (each in its own evaluations)."""
        return self.spec.target_success is not None and len(self.stopped) == len(self.keys)

    def step(self) -> dict[str, Any]:
        row = super().step()
        for index in self.stopped:  # a stopped member's figures end at its stop
            for name in [
                n for n in row if n.startswith(("train_", "eval_")) and f"_{self.keys[index]}_" in n
            ]:
                del row[name]
        if self.spec.target_success is None:
            return row
        self.streaks, met = member_streaks(
            self.streaks, row, self.spec.target_success, self.spec.target_evals
        )
        met = [i for i in met if i not in self.stopped]
        self._stopped_now = bool(met)
        if met:  # finally evaluated and exported now, as each member's source alone would be
            figures = self.algo.evaluate_greedy(self.spec.eval_episodes * 2, final=True)
            files = self._policy_files()
            for index in met:
                key = self.keys[index]
                self.stopped[index] = {
                    "success": figures[f"{key}_success"],
                    "touching": figures[f"{key}_touching"],
                    "env_steps": self.env_steps,
                }
                self._stopped_files[index] = files[index]
            self.algo.stopped = frozenset(self.keys[i] for i in self.stopped)
        return row

    def checkpoint_due(self, row: dict[str, Any]) -> bool:
        """Also at a member's stop, as a source alone checkpoints when it stops: a kill after it
        loses neither the stop nor the member's policy as it stopped."""
        return self._stopped_now or super().checkpoint_due(row)

    def _policy_files(self) -> list[bytes]:
        with tempfile.TemporaryDirectory() as directory:
            paths = [Path(directory) / cell_policy_file(i) for i in range(len(self.keys))]
            self.algo.export_cells(paths, self.signatures)
            return [p.read_bytes() for p in paths]

    def final_eval(self) -> dict[str, float]:
        """Each member's final figures (``c<i>_success``, ``c<i>_touching``) and the env steps they
        are at (``c<i>_env_steps``): a stopped member's from its stop, the others' now; ``success``
        and ``touching`` the worst member's, as a grid's."""
        live = [i for i in range(len(self.keys)) if i not in self.stopped]
        now = self.algo.evaluate_greedy(self.spec.eval_episodes * 2, final=True) if live else {}
        out: dict[str, float] = {}
        for index, key in enumerate(self.keys):
            figures = self.stopped.get(index) or {
                "success": now[f"{key}_success"],
                "touching": now[f"{key}_touching"],
                "env_steps": self.env_steps,
            }
            out.update({f"{key}_{name}": value for name, value in figures.items()})
        out["success"] = min(out[f"{k}_success"] for k in self.keys)
        touching = [out[f"{k}_touching"] for k in self.keys]
        out["touching"] = float("nan") if np.isnan(touching).all() else float(np.nanmin(touching))
        return out

    def save(self, directory: Path) -> None:
        directory = Path(directory)
        self.algo.save_checkpoint(str(directory))
        self.algo.export_cells(
            [directory / cell_policy_file(i) for i in range(len(self.keys))], self.signatures
        )
        for index, member in enumerate(self.population.members):
            (directory / cell_spec_file(index)).write_text(json.dumps(member.to_dict(), indent=2))
            if index in self.stopped:  # as it stopped, not as the population's weights are now
                (directory / cell_policy_file(index)).write_bytes(self._stopped_files[index])
                (directory / cell_result_file(index)).write_text(json.dumps(self.stopped[index], indent=2))
        (directory / POPULATION_FILE).write_text(json.dumps(self.population.to_dict(), indent=2))
        progress = {
            "streak": self.streak,
            "best": self.best,
            "consolidated": self.consolidated,
            "streaks": self.streaks,
            "stopped": {str(i): figures for i, figures in self.stopped.items()},
        }
        (directory / checkpoint.PROGRESS_FILE).write_text(json.dumps(progress))
        checkpoint.seal(directory)

    def restore(self, directory: Path) -> None:
        super().restore(directory)  # verified whole before anything is read
        state = checkpoint.progress(directory)
        self.streaks = [int(s) for s in state["streaks"]]
        self.stopped = {
            int(i): {k: int(v) if k == "env_steps" else float(v) for k, v in f.items()}
            for i, f in state["stopped"].items()
        }
        self._stopped_files = {i: (Path(directory) / cell_policy_file(i)).read_bytes() for i in self.stopped}
        self.algo.stopped = frozenset(self.keys[i] for i in self.stopped)

    def progress_line(self, row: dict[str, Any]) -> str:
        members = "  ".join(
            f"{m.label()} {row.get(f'eval_{k}_success', 0):.2f}{' (stopped)' if i in self.stopped else ''}"
            for i, (m, k) in enumerate(zip(self.population.members, self.keys))
        )
        return (
            f"[{self.population.label()}] {row['env_steps']:>7}/{self.spec.env_steps} steps per member "
            f"{row['updates']:>7} updates  eval success {members}"
        )
