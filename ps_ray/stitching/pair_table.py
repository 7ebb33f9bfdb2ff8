"""The zero-shot stage's table, ``zero_shot.csv``: a row per stitched pair, its record
(:meth:`StitchedPair.to_row`) with its figures and its controls'. Its format is
``ps_ray.zero_shot_table/<version>``, named in a ``format`` column; :func:`read_table` is its one
reader and :func:`upgrade` the one place that knows the versions:

- 1: tables written before the id (no ``format`` column); the earliest lack columns added later
  (the sources' files, the task-blind floor, the wrong-target rate, the ridge...).
- 2: every column of :data:`COLUMNS` but ``told_robot_source_success``, ``format`` first;
- 3: every column of :data:`COLUMNS` (:data:`ADDED` names what each version added).

Ray- and torch-free: the report reads the table through it."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ps_ray.errors import UserError
from ps_ray.specs.names import CONTROL_ROLES
from ps_ray.stitching.pairs import StitchedPair
from ps_ray.store.atomic import atomic_path
from ps_ray.store.formats import ZERO_SHOT_TABLE

RESULT_KEYS = (
    "success_mean",
    "success_std",
    "touching_mean",
    "touching_std",
    "contact_mean",
    "wrong_target_mean",  # ended at a candidate target the task does not name (NaN: one per scene)
    "episodes_per_s",
    "fit_env_steps",  # env steps the translation's fit rolled out (outcome matching; 0 for none)
    "translation_ridge",  # the ridge strength the actor's latent map chose (NaN: no latent map)
    "episodes_seed",  # the first reset seed of the pair's episodes (its training seed's own block)
)
# each control's success on the pair's episodes (ps_ray.stitching.matrix.controls), chance and the
# task-blind floor on them, the better unstitched source, the best of all those and the gain over
# it; the gain over the best of the sources and chance alone, as before the floor, beside it
CONTROL_KEYS = (
    *(f"{role}_success" for role in CONTROL_ROLES),
    "chance_success",
    "task_blind_success",
    "task_blind_wrong_target",
    "told_robot_source_success",  # the robot source told the task: every translation's ceiling
    "best_unstitched",
    "best_control",
    "transfer_gain",
    "gain_over_chance",
)
# a pair's record as :meth:`StitchedPair.to_row` writes it: its fields, then each control role's
# source key and file
RECORD_COLUMNS = (
    *(f.name for f in dataclasses.fields(StitchedPair) if f.name != "controls"),
    *(column for role in CONTROL_ROLES for column in (role, f"{role}_path")),
)
COLUMNS = ("format", *RECORD_COLUMNS, *RESULT_KEYS, *CONTROL_KEYS)
ADDED = {3: ("told_robot_source_success",)}  # the columns a version added to the one before it


def table_of(results: list[tuple[StitchedPair, dict[str, Any]]], root: Path | None = None) -> pd.DataFrame:
    """One row per stitched pair from (pair, metrics), in the given (the matrix's) order: the
    format, the pair's record (its sources' and controls' keys and files, inside ``root``
    relative to it), its success and touching, each control's success (``<role>_success``, NaN
    where the role does not apply), ``chance_success``, ``best_unstitched``, ``best_control`` and
    ``transfer_gain``."""
    figures = (*RESULT_KEYS, *CONTROL_KEYS)
    rows = [
        {"format": ZERO_SHOT_TABLE.id, **pair.to_row(root), **{k: metrics.get(k, np.nan) for k in figures}}
        for pair, metrics in results
    ]
    return pd.DataFrame(rows, columns=list(COLUMNS))


def write_table(table: pd.DataFrame, path: Path) -> None:
    """Write beside, then rename: a reader never sees half a table."""
    with atomic_path(path) as partial:
        table.to_csv(partial, index=False)


def read_table(path: Path, *, as_text: bool = False) -> pd.DataFrame | None:
    """``zero_shot.csv`` in the current layout, whichever version wrote it; None when there is no
    table. ``as_text``: every cell as written (an empty cell ""), for records; else pandas' types
    (an empty cell NaN). A table of another format or a newer ps_ray: UserError naming it."""
    if not path.is_file():
        return None
    try:
        table = pd.read_csv(path, dtype=str if as_text else None, keep_default_na=not as_text)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise UserError(f"{path}: unreadable zero-shot table ({e})") from None
    ids = set(table["format"]) if "format" in table.columns else {ZERO_SHOT_TABLE.readable[0]}
    ids = sorted(map(str, ids or {ZERO_SHOT_TABLE.id}))  # no rows: nothing to upgrade
    if len(ids) > 1 or not ZERO_SHOT_TABLE.reads(ids[0]):
        raise UserError(
            f"{path}: not a zero-shot table this ps_ray reads (format {', '.join(ids)}; "
            f"it reads {', '.join(ZERO_SHOT_TABLE.readable)})"
        )
    version = ZERO_SHOT_TABLE.version_of(ids[0])
    later = {c for v, added in ADDED.items() if v > version for c in added}
    missing = [c for c in COLUMNS if c not in table.columns and c not in later]
    if version >= 2 and missing:  # a version that wrote all its columns lacks one: damaged
        raise UserError(f"{path}: a {ids[0]} table without its column(s) {', '.join(missing)}")
    return upgrade(table, version, empty="" if as_text else np.nan)


def upgrade(table: pd.DataFrame, version: int, empty: Any = np.nan) -> pd.DataFrame:
    """A table of ``version`` as the current version writes it. An older one gets every column it
    lacks, empty (``empty``): a figure not measured then (version 2: the told robot source), or
    the sources' files of a table written before its rows named them (its pairs come from the
    zoo again); one from before chance joined the controls has its best unstitched source as its
    best control."""
    if version < ZERO_SHOT_TABLE.version:
        if "best_control" not in table.columns and "best_unstitched" in table.columns:
            # before chance joined the controls, the best of them was the best unstitched source
            table = table.assign(best_control=table["best_unstitched"])
        table = table.assign(**{c: empty for c in COLUMNS if c not in table.columns})
        table["format"] = ZERO_SHOT_TABLE.id
    return table[[*COLUMNS, *(c for c in table.columns if c not in COLUMNS)]]


def pairs_from_table(path: Path) -> list[StitchedPair] | None:
    """The pairs of a ``zero_shot.csv``, in its order (the matrix's,
    :func:`ps_ray.plan.zero_shot.matrix`); None when there is no table, or its rows name no
    sources' files (a version-1 table written before they did): the caller builds them from the
    zoo."""
    table = read_table(path, as_text=True)
    if table is None or table.empty or (table["task_from_path"] == "").any():
        return None
    try:
        return [StitchedPair.from_row(row, path.parent) for row in table.to_dict("records")]
    except (KeyError, ValueError, UserError) as e:  # a damaged table: one line naming it
        raise UserError(f"{path}: unreadable pair row ({e})") from None
