"""Tune's attempt folders read back without Tune's pickles (the runner: ps_ray.pipeline.trials).

Tune keeps an experiment's state as pickles (``tuner.pkl``, each trial's ``params.pkl`` and the
pickled trial objects inside ``experiment_state-*.json``). ps_ray never reads them back: anyone who
can write to shared storage could plant code there. What a stage folder's plain JSON says is
enough instead. Every Tune trial folder is one *attempt* of a trial: its ``params.json`` names
the trial (the grid value), its ``result.json`` holds one JSON result per line, and a trial that
ran to its end reported ``FINISHED`` in its last result. Resuming a stage launches a fresh Tune
experiment of the trials without a finished attempt; a relaunched training trial continues from
the furthest verified checkpoint that any earlier attempt left (:mod:`ps_ray.store.checkpoint`).

Readers without Ray (the report, the zoo) use :func:`outcomes` and :func:`merged_rows`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ps_ray.errors import UserError
from ps_ray.store import checkpoint
from ps_ray.store.run_layout import REPLAY_FOLDER

FINISHED = "ps_ray_finished"  # in the last result of a trial that ran to its end
# beside the results of a trial a search's scheduler stopped early (ps_ray.pipeline.search): done too
STOPPED_FILE = "stopped_early.json"
START_STEPS = "start_env_steps"  # in a training trial's rows: the env steps it restored, not ran
UNFINISHED = "did not finish"  # the error of a trial that ended neither finished nor failed: interrupted
STOPPED = "stopped_early"  # set in the last row of such a trial as outcomes() read it
STAGE_DIR_KEY = "stage_dir"  # a constant of every grid: where earlier attempts lie
PARAMS_FILE = "params.json"
RESULT_FILE = "result.json"


class StageExistsError(UserError):
    """A stage folder already holds trials and resuming was not asked for."""


def identity(value: Any) -> str:
    """What makes two attempts the same trial: the grid value, as canonical JSON."""
    return json.dumps(value, sort_keys=True, default=str)


def read_rows(attempt: Path) -> list[dict]:
    """An attempt's results; a line cut short by a kill is skipped."""
    path = attempt / RESULT_FILE
    rows = []
    with contextlib.suppress(FileNotFoundError):
        for line in path.read_text().splitlines():
            with contextlib.suppress(json.JSONDecodeError):
                row = json.loads(line)
                if isinstance(row, dict):
                    rows.append(row)
    return rows


def _first_row(attempt: Path) -> dict | None:
    """An attempt's first result, reading only its first line (None: no complete first row)."""
    try:
        with open(attempt / RESULT_FILE) as f:
            row = json.loads(f.readline())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return row if isinstance(row, dict) else None


def _params(attempt: Path) -> dict | None:
    try:
        params = json.loads((attempt / PARAMS_FILE).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return params if isinstance(params, dict) else None


def attempts(stage_dir: Path, key: str) -> dict[str, list[Path]]:
    """Attempt folders of each trial (by :func:`identity` of ``params[key]``), oldest first."""
    found: dict[str, list[tuple[float, Path]]] = {}
    for params_path in sorted(Path(stage_dir).glob(f"*/{PARAMS_FILE}")):
        params = _params(params_path.parent)
        if params is None or key not in params:
            continue
        first = _first_row(params_path.parent)  # not the whole file: a resume reads little
        started = first.get("timestamp", 0) if first is not None else float("inf")
        found.setdefault(identity(params[key]), []).append((started, params_path.parent))
    return {k: [p for _, p in sorted(v, key=lambda sp: (sp[0], str(sp[1])))] for k, v in found.items()}


def merged_rows(folders: list[Path]) -> list[dict]:
    """One trial's results over its attempts (oldest first): a later attempt restarts from a
    checkpoint, so an earlier attempt's rows from that env step on are dropped, never doubled."""
    merged: list[dict] = []
    for folder in folders:
        rows = read_rows(folder)
        steps = [r["env_steps"] for r in rows if isinstance(r.get("env_steps"), int | float)]
        if steps:
            merged = [r for r in merged if r.get("env_steps", -1) < min(steps)]
        merged += rows
    return merged


def rows_naming(stage_dir: Path, field: str) -> dict[str, dict]:
    """Every result row of a stage folder that names ``field`` (e.g. one stitched pair of a
    batched trial), by that field's value; of several attempts' rows, the newest attempt's wins."""
    found: dict[str, tuple[float, dict]] = {}
    for result in Path(stage_dir).glob(f"*/{RESULT_FILE}"):
        for row in read_rows(result.parent):
            name = row.get(field)
            stamp = row.get("timestamp", 0)
            if isinstance(name, str) and (name not in found or stamp >= found[name][0]):
                found[name] = (stamp, row)
    return {name: row for name, (_, row) in found.items()}


@dataclass
class TrialOutcome:
    """A trial as the stage sees it after running: its config, last result and folder."""

    config: dict
    metrics: dict
    path: Path | None
    error: str | None = None
    attempts: list[Path] = field(default_factory=list)

    @property
    def checkpoint(self) -> Path | None:
        """The trial's furthest checkpoint over all its attempts whose policy file verifies."""
        return checkpoint.latest(checkpoint_dirs(self.attempts), checkpoint.POLICY_ONLY)

    @property
    def rows(self) -> list[dict]:
        return merged_rows(self.attempts)


def _finished(attempt: Path) -> dict | None:
    """The last row of an attempt that ran to its end or that a scheduler stopped early (marked
    ``STOPPED``), else None."""
    rows = read_rows(attempt)
    if rows and rows[-1].get(FINISHED):
        return rows[-1]
    if rows and (attempt / STOPPED_FILE).is_file():
        return {**rows[-1], STOPPED: True}
    return None


def outcomes(
    stage_dir: Path, key: str, trials: list, errors: dict[str, str] | None = None
) -> list[TrialOutcome]:
    """The outcome of every trial in ``trials`` (grid values under ``key``), read from
    ``stage_dir``: finished if an attempt finished, else failed with ``errors``' message or
    ``UNFINISHED`` (the stage was stopped before it: Ctrl-C)."""
    found = attempts(stage_dir, key)
    out = []
    for trial in trials:
        folders = found.get(identity(trial), [])
        done = [(f, row) for f in folders if (row := _finished(f)) is not None]
        if done:
            folder, row = done[-1]
            out.append(TrialOutcome(_params(folder) or {key: trial}, row, folder, None, folders))
            continue
        last = folders[-1] if folders else None
        error = (errors or {}).get(identity(trial)) or UNFINISHED
        metrics = read_rows(last)[-1:] if last else []
        out.append(TrialOutcome({key: trial}, metrics[0] if metrics else {}, last, error, folders))
    return out


def replay_store(config: dict, key: str) -> Path | None:
    """The folder of a trial's replay segments (:mod:`ps_ray.store.replay`), shared by all its
    attempts: ``<stage folder>/replay/<digest of the trial>``; None outside a stage."""
    stage_dir = config.get(STAGE_DIR_KEY)
    if not stage_dir:
        return None
    digest = hashlib.sha256(identity(config[key]).encode()).hexdigest()[:16]
    return Path(stage_dir) / REPLAY_FOLDER / digest


def earlier_checkpoint(config: dict, key: str) -> Path | None:
    """For a trial starting afresh: the furthest verified checkpoint of its earlier attempts in
    the stage folder (``config[STAGE_DIR_KEY]``), its replay segments included, or None."""
    stage_dir = config.get(STAGE_DIR_KEY)
    if not stage_dir:
        return None
    folders = attempts(Path(stage_dir), key).get(identity(config[key]), [])
    return checkpoint.latest(checkpoint_dirs(folders), replay_store=replay_store(config, key))


def checkpoint_dirs(folders: list[Path]) -> list[Path]:
    """Every Tune checkpoint folder of the given attempts."""
    return [c for folder in folders for c in sorted(folder.glob("checkpoint_*")) if c.is_dir()]


def require_fresh(folder: Path, key: str, stage: str) -> None:
    """A stage run afresh (no --resume) on a folder that holds attempts of it is refused, before
    anything is written: a second experiment is never mixed into the first."""
    if attempts(Path(folder), key):
        raise StageExistsError(
            f"{folder} holds an earlier run of stage {stage!r}; pass --resume to finish it "
            f"(or choose another storage or sweep name)"
        )
