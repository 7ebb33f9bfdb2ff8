"""Module zoo: every trained policy of one or more sweeps, indexed for stitching.

A key is (method, robot, task, seed, interface_dim); robots and tasks are rendered by
:func:`ps_ray.specs.names.short_name` (a name, or ``base{json}`` for a mapping). As a string a key is
the trial key (:func:`ps_ray.specs.names.trial_key`, also the MLflow run name): ``ps/panda/push/101``,
with ``/i<dim>`` appended off the default interface dim (``ps/panda/push/101/i16``).

Sweep layout read (:class:`ps_ray.store.layout.SweepLayout`): ``<sweep>/tune/<trial>/checkpoint_N/`` (stage
"train") and ``<sweep>/tune_plain/<trial>/checkpoint_N/`` (stage "plain_source", the anchors' plain
source policies), each with ``policy.safetensors`` and ``spec.json``. Of a trial's checkpoints
over all its attempts (:mod:`ps_ray.store.attempts`), the furthest one whose manifest verifies is used.
When one key appears twice, a "train" entry beats a "plain_source" one, then the newest file wins.

A co-trained grid's cells (``<sweep>/tune_grid/<trial>/checkpoint_N/``, stage "grid",
:mod:`ps_ray.pipeline.grid`) are entries too, their key tagged with the grid's held-out cells
(``ablation/panda/reach_red/401/held_out=panda_far/reach_blue``): :meth:`ModuleZoo.select` keeps
each grid's cells apart, and from the policies trained alone (its default). A population trial of
the train stage (``tune/``, :mod:`ps_ray.rllib.population_train`) gives each member as an ordinary
"train" entry (``policy_c<i>.safetensors`` and ``spec_c<i>.json`` of its checkpoint).
"""

from __future__ import annotations

import difflib
import json
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ps_ray.errors import UserError
from ps_ray.specs.methods import method_key
from ps_ray.specs.names import EnvPart, readable, short_name, trial_key
from ps_ray.specs.titles import ANCHOR_POLICY, env_title, title, width_tag
from ps_ray.specs.train import TrainSpec
from ps_ray.store.layout import SweepLayout
from ps_ray.store.run_layout import (
    GRID_FILE,
    POLICY_FILE,
    POPULATION_FILE,
    SPEC_FILE,
    cell_policy_file,
    cell_spec_file,
)
from ps_ray.store.signature import Signature, read_signature

STAGE_RANK = {"train": 0, "run": 0, "plain_source": 1}  # lower wins a duplicate key


@dataclass(frozen=True, order=True)
class ZooKey:
    method: str
    robot: str  # rendered by short_name
    task: str
    seed: int
    interface_dim: int
    grid: str = ""  # a co-trained grid's held-out cells (GridSpec.held_out_text); "": trained alone

    def __str__(self) -> str:
        key = trial_key(
            {
                "method": self.method,
                "robot": self.robot,
                "task": self.task,
                "seed": self.seed,
                "interface_dim": self.interface_dim,
            }
        )
        return f"{key}/held_out={self.grid}" if self.grid else key


@dataclass(frozen=True)
class ZooEntry:
    """One trained policy: its key, file, interface signature and training spec (a dict)."""

    key: ZooKey
    path: Path
    signature: Signature
    spec: Mapping[str, Any]
    stage: str  # "train", "plain_source" or "run"

    @property
    def names(self) -> tuple[str, ...]:
        """Every spelling a command takes for it: its key, the key as a reader writes it
        (``reach q1``), and, for a source trained alone, its MLflow run's name
        (:mod:`ps_ray.specs.titles`)."""
        key = self.key
        names = [str(key), readable(str(key))]
        if not key.grid:
            base = title(env_title(key.robot, key.task), key.method, key.seed, width_tag(key.interface_dim))
            names.append(title(base, ANCHOR_POLICY) if self.stage == "plain_source" else base)
        return tuple(dict.fromkeys(names))

    @property
    def robot(self) -> EnvPart:
        """The robot as trained, for making its env."""
        return EnvPart(self.spec["robot"])

    @property
    def task(self) -> EnvPart:
        return EnvPart(self.spec["task"])


def key_of(spec: Mapping[str, Any], grid: str = "") -> ZooKey:
    """The key of a TrainSpec dict; as a string, the trial key (MLflow run name)."""
    return ZooKey(
        method_key(str(spec["method"])),
        short_name(spec["robot"]),
        short_name(spec["task"]),
        int(spec["seed"]),
        int(spec["interface_dim"]),
        grid,
    )


def read_entry(
    policy_path: str | Path, stage: str = "run", spec_path: Path | None = None, grid: str = ""
) -> ZooEntry:
    """A policy file and its spec (default: the ``spec.json`` beside it); ValueError naming the
    file if either is bad. ``grid``: the held-out cells of the grid it was co-trained in."""
    path = Path(policy_path)
    if not path.is_file():
        raise UserError(f"{path}: no such policy file")
    signature, _ = read_signature(path)
    spec_path = spec_path or path.parent / SPEC_FILE
    try:
        spec = TrainSpec.upgrade(json.loads(spec_path.read_text()))
        key = key_of(spec, grid)
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise UserError(f"{spec_path}: missing or unreadable training spec ({e})") from None
    if (key.method, key.interface_dim) != (signature.method, signature.interface_dim):
        raise UserError(
            f"{path}: signature ({signature.method}, interface dim "
            f"{signature.interface_dim}) disagrees with {spec_path}"
        )
    return ZooEntry(key, path, signature, spec, stage)


def _latest_checkpoints(stage_dir: Path) -> tuple[list[Path], list[str]]:
    """The policy file of each trial's furthest checkpoint over its attempts (ps_ray.store.attempts)
    whose manifest and policy file verify, and a problem line per trial that has none."""
    from ps_ray.store import checkpoint
    from ps_ray.store.attempts import attempts, checkpoint_dirs

    policies, problems = [], []
    for trial, folders in attempts(stage_dir, "trial").items():
        if "population" in json.loads(trial):
            continue  # its members are read by _population_members
        found = checkpoint_dirs(folders)
        best = checkpoint.latest(found, checkpoint.POLICY_ONLY)
        if best is not None:
            policies.append(best / POLICY_FILE)
        elif found:
            try:
                checkpoint.verify(found[-1], checkpoint.POLICY_ONLY)
            except checkpoint.CheckpointError as e:
                problems.append(str(e))
    return policies, problems


class ModuleZoo:
    """Trained policies by key. ``strict=False`` skips unreadable ones, listed in ``problems``."""

    def __init__(self, entries: Iterable[ZooEntry] = (), problems: Iterable[str] = ()) -> None:
        self._entries: dict[ZooKey, ZooEntry] = {}
        self._by_name: dict[str, ZooEntry] = {}  # by trial key: a lookup is one dict read
        # another spelling of a key (None: two keys share it); every entry's spellings, winner or not
        self._by_alias: dict[str, ZooKey | None] = {}
        self.problems = list(problems)
        for entry in entries:
            self._add(entry)

    def _add(self, entry: ZooEntry) -> None:
        old = self._entries.get(entry.key)
        if old is None or _preference(entry) < _preference(old):
            self._entries[entry.key] = self._by_name[str(entry.key)] = entry
        for name in entry.names[1:]:
            other = self._by_alias.get(name, entry.key)  # absent: this key's
            self._by_alias[name] = entry.key if other == entry.key else None

    @classmethod
    def from_sweep(cls, *sweep_dirs: str | Path, strict: bool = True) -> ModuleZoo:
        """Index ``tune/``, ``tune_plain/`` and ``tune_grid/`` of each sweep directory
        (``<storage>/<name>``); a sweep with none of them trained is refused in one line."""
        entries, problems = [], []
        for sweep in map(Path, sweep_dirs):
            found = []
            layout = SweepLayout(sweep)
            for folder, stage in ((layout.tune_train, "train"), (layout.tune_plain, "plain_source")):
                policies, unusable = _latest_checkpoints(folder)
                found += [(p, stage) for p in policies]
                if unusable and strict:
                    raise UserError(unusable[0])
                problems += unusable
            grids, unusable = _grid_cells(layout.tune_grid)
            members, unusable_members = _population_members(layout.tune_train)
            unusable += unusable_members
            if unusable and strict:
                raise UserError(unusable[0])
            problems += unusable
            grids += members  # a population's members: sources trained alone, in one learner
            if not found and not grids:  # a sweep may co-train grids and train nothing alone
                raise UserError(
                    f"{sweep}: no trained policies (expected tune/<trial>/checkpoint_*/{POLICY_FILE})"
                )
            for path, stage in found:
                try:
                    entries.append(read_entry(path, stage))
                except UserError as e:
                    if strict:
                        raise
                    problems.append(str(e))
            entries += grids
        return cls(entries, problems)

    # -- lookup ---------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._entries)

    def __iter__(self) -> Iterator[ZooEntry]:
        return iter(sorted(self._entries.values(), key=lambda e: e.key))

    def __contains__(self, key: object) -> bool:
        try:
            self.get(key)  # type: ignore[arg-type]
        except UserError:
            return False
        return True

    def keys(self) -> list[ZooKey]:
        return sorted(self._entries)

    def get(self, key: str | ZooKey) -> ZooEntry:
        """By ZooKey or trial key (``ps/panda/push/101``, ``ps/panda/push/101/i16``)."""
        by_name = self._by_name
        if str(key) in by_name:
            return by_name[str(key)]
        if (alias := self._by_alias.get(str(key))) is not None:  # as MLflow, --check, the report print it
            return self._entries[alias]
        close = difflib.get_close_matches(str(key), sorted(by_name), n=5, cutoff=0.5)
        hint = (
            f"close keys: {', '.join(close)}"
            if close
            else f"valid keys include: {', '.join(sorted(by_name)[:5])}"
        )
        raise UserError(f"no policy {str(key)!r} in the zoo ({len(self)} policies); {hint}")

    def select(
        self,
        *,
        method: str | None = None,
        seed: int | None = None,
        interface_dim: int | None = None,
        grid: str = "",
    ) -> list[ZooEntry]:
        """The entries of ``method``, ``seed`` and ``interface_dim`` (None: any) trained alone, or
        with ``grid`` those of the co-trained grid that held those cells out."""
        return [
            e
            for e in self
            if (method is None or e.key.method == method)
            and (seed is None or e.key.seed == seed)
            and (interface_dim is None or e.key.interface_dim == interface_dim)
            and e.key.grid == grid
        ]

    def grids(self, method: str) -> list[str]:
        """The held-out cells of every co-trained grid of ``method`` in the zoo."""
        return sorted({e.key.grid for e in self if e.key.method == method and e.key.grid})


def _cell_entries(
    stage_dir: Path, spec_file: str, read_spec, entry_of, trials=lambda trial: True
) -> tuple[list[ZooEntry], list[str]]:
    """The cells of each trial (``trials`` picks them by config) whose checkpoints hold several
    policies (a grid's, a population's): from its furthest checkpoint whose ``spec_file`` and every
    cell's policy and spec verify (an earlier one where a later is damaged, as for a source alone),
    the spec read by ``read_spec(path)`` -> (spec, cell count), each cell's entry ``entry_of(spec,
    policy path, spec path)``; a problem line per trial without one."""
    from ps_ray.store import checkpoint
    from ps_ray.store.attempts import attempts, checkpoint_dirs

    entries, problems = [], []
    for trial, folders in attempts(stage_dir, "trial").items():
        if not trials(json.loads(trial)):
            continue
        found = checkpoint_dirs(folders)
        best = checkpoint.latest(found, (checkpoint.STATE_FILE, spec_file))
        try:
            if best is None:
                if found:
                    checkpoint.verify(found[-1], (checkpoint.STATE_FILE, spec_file))  # names the problem
                continue
            _, n = read_spec(best / spec_file)  # a trial's checkpoints share its spec
            cells = tuple(f(i) for i in range(n) for f in (cell_policy_file, cell_spec_file))
            whole = checkpoint.latest(found, (checkpoint.STATE_FILE, spec_file, *cells))
            if whole is None:
                checkpoint.verify(best, cells)  # names the problem
            best = whole
            spec, n = read_spec(best / spec_file)
        except UserError as e:
            problems.append(str(e))
            continue
        entries += [entry_of(spec, best / cell_policy_file(i), best / cell_spec_file(i)) for i in range(n)]
    return entries, problems


def _grid_cells(stage_dir: Path) -> tuple[list[ZooEntry], list[str]]:
    """Every trained cell of each grid trial, tagged with the grid's held-out cells."""
    from ps_ray.specs.grid import GridSpec

    def read(path: Path):
        grid = GridSpec.from_mapping(json.loads(path.read_text()), where=str(path))
        return grid, len(grid.cells)

    return _cell_entries(
        stage_dir,
        GRID_FILE,
        read,
        lambda grid, policy, spec: read_entry(policy, "grid", spec, grid.held_out_text),
    )


def _population_members(stage_dir: Path) -> tuple[list[ZooEntry], list[str]]:
    """Every member of each population trial of the train stage's ``tune/``
    (:mod:`ps_ray.rllib.population_train`), each an ordinary train-stage source."""
    from ps_ray.specs.population import PopulationSpec

    def read(path: Path):
        population = PopulationSpec.from_mapping(json.loads(path.read_text()), where=str(path))
        return population, len(population.members)

    return _cell_entries(
        stage_dir,
        POPULATION_FILE,
        read,
        lambda _, policy, spec: read_entry(policy, "train", spec),
        trials=lambda trial: "population" in trial,
    )


def _preference(entry: ZooEntry) -> tuple[int, float]:
    """Lower wins a duplicate key: the stage's rank, then the newest file (a planned module has
    no file: the first planned stays)."""
    newest = -entry.path.stat().st_mtime if entry.path.exists() else 0.0
    return STAGE_RANK.get(entry.stage, 2), newest
