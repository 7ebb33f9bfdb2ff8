"""Module zoo: every trained policy of one or more sweeps, indexed for stitching.

A key is (method, robot, task, seed, interface_dim); robots and tasks are rendered by
:func:`ps_ray.specs.names.short_name` (a name, or ``base{json}`` for a mapping). As a string a key is
the trial key (:func:`ps_ray.specs.names.trial_key`, also the MLflow run name): ``ps/panda/push/101``,
with ``/i<dim>`` appended off the default interface dim (``ps/panda/push/101/i16``).

Sweep layout read (see :mod:`ps_ray.pipeline.sweep`): ``<sweep>/tune/<trial>/checkpoint_N/`` (stage
"train") and ``<sweep>/tune_plain/<trial>/checkpoint_N/`` (stage "plain_source", the anchors' plain
source policies), each with ``policy.safetensors`` and ``spec.json``. Of a trial's checkpoints
over all its attempts (:mod:`ps_ray.store.attempts`), the furthest one whose manifest verifies is used.
When one key appears twice, a "train" entry beats a "plain_source" one, then the newest file wins.
"""

from __future__ import annotations

import difflib
import json
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ps_ray.errors import UserError
from ps_ray.specs.methods import method_key
from ps_ray.specs.names import EnvPart, short_name, trial_key
from ps_ray.store.layout import SweepLayout
from ps_ray.store.run_layout import POLICY_FILE, SPEC_FILE
from ps_ray.store.signature import Signature, read_signature

if TYPE_CHECKING:
    pass

STAGE_RANK = {"train": 0, "run": 0, "plain_source": 1}  # lower wins a duplicate key


@dataclass(frozen=True, order=True)
class ZooKey:
    method: str
    robot: str  # rendered by short_name
    task: str
    seed: int
    interface_dim: int

    def __str__(self) -> str:
        return trial_key(
            {
                "method": self.method,
                "robot": self.robot,
                "task": self.task,
                "seed": self.seed,
                "interface_dim": self.interface_dim,
            }
        )


@dataclass(frozen=True)
class ZooEntry:
    """One trained policy: its key, file, interface signature and training spec (a dict)."""

    key: ZooKey
    path: Path
    signature: Signature
    spec: Mapping[str, Any]
    stage: str  # "train", "plain_source" or "run"

    @property
    def robot(self) -> EnvPart:
        """The robot as trained, for making its env."""
        return EnvPart(self.spec["robot"])

    @property
    def task(self) -> EnvPart:
        return EnvPart(self.spec["task"])


def key_of(spec: Mapping[str, Any]) -> ZooKey:
    """The key of a TrainSpec dict; as a string, the trial key (MLflow run name)."""
    return ZooKey(
        method_key(str(spec["method"])),  # a folder written before the menu may name an old row
        short_name(spec["robot"]),
        short_name(spec["task"]),
        int(spec["seed"]),
        int(spec["interface_dim"]),
    )


def read_entry(policy_path: str | Path, stage: str = "run") -> ZooEntry:
    """A policy file and the ``spec.json`` beside it; ValueError naming the file if either is bad."""
    path = Path(policy_path)
    if not path.is_file():
        raise UserError(f"{path}: no such policy file")
    signature, _ = read_signature(path)
    spec_path = path.parent / SPEC_FILE
    try:
        spec = json.loads(spec_path.read_text())
        key = key_of(spec)
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
    for folders in attempts(stage_dir, "trial").values():
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
        self.problems = list(problems)
        for entry in entries:
            self._add(entry)

    def _add(self, entry: ZooEntry) -> None:
        old = self._entries.get(entry.key)
        if old is None or _preference(entry) < _preference(old):
            self._entries[entry.key] = entry

    @classmethod
    def from_sweep(cls, *sweep_dirs: str | Path, strict: bool = True) -> ModuleZoo:
        """Index ``tune/`` and ``tune_plain/`` of each sweep directory (``<storage>/<name>``)."""
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
            if not found:
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
        by_name = {str(k): e for k, e in self._entries.items()}
        if str(key) in by_name:
            return by_name[str(key)]
        close = difflib.get_close_matches(str(key), sorted(by_name), n=5, cutoff=0.5)
        hint = (
            f"close keys: {', '.join(close)}"
            if close
            else f"valid keys include: {', '.join(sorted(by_name)[:5])}"
        )
        raise UserError(f"no policy {str(key)!r} in the zoo ({len(self)} policies); {hint}")

    def select(
        self, *, method: str | None = None, seed: int | None = None, interface_dim: int | None = None
    ) -> list[ZooEntry]:
        return [
            e
            for e in self
            if (method is None or e.key.method == method)
            and (seed is None or e.key.seed == seed)
            and (interface_dim is None or e.key.interface_dim == interface_dim)
        ]


def _preference(entry: ZooEntry) -> tuple[int, float]:
    return STAGE_RANK.get(entry.stage, 2), -entry.path.stat().st_mtime
