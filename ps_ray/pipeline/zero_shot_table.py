"""The zero-shot stage's table: a row per stitched pair (``zero_shot.csv``), its summary per
method for the terminal, and the stage run's summary metrics in MLflow."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ps_ray.specs.names import CONTROL_ROLES
from ps_ray.stitching.pairs import StitchedPair
from ps_ray.store.atomic import atomic_path

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
    "best_unstitched",
    "best_control",
    "transfer_gain",
    "gain_over_chance",
)


def table_of(results: list[tuple[StitchedPair, dict[str, Any]]], root: Path | None = None) -> pd.DataFrame:
    """One row per stitched pair from (pair, metrics), in the given (the matrix's) order: the
    pair's record (:meth:`StitchedPair.to_row`: its sources' and controls' keys and files), its
    success and touching, each control's success (``<role>_success``, NaN where the role does not
    apply), ``chance_success``, ``best_unstitched``, ``best_control`` and ``transfer_gain``."""
    keys = (*RESULT_KEYS, *CONTROL_KEYS)
    return pd.DataFrame(
        [{**pair.to_row(root), **{k: metrics.get(k, np.nan) for k in keys}} for pair, metrics in results]
    )


def summary(table: pd.DataFrame) -> pd.DataFrame:
    """Mean over pairs per method (and the number of pairs) of success, touching, the better
    unstitched control, chance, the task-blind floor, the wrong-target rate, the oracle and the
    transfer gain, for the terminal and the note."""
    grouped = table.groupby("method")
    return pd.DataFrame(
        {
            "pairs": grouped.size(),
            "success": grouped["success_mean"].mean(),
            "touching": grouped["touching_mean"].mean(),
            "best unstitched": grouped["best_unstitched"].mean(),
            "chance": grouped["chance_success"].mean(),
            "task-blind floor": _mean_of(grouped, "task_blind_success"),
            "wrong target": _mean_of(grouped, "wrong_target_mean"),
            "oracle": grouped["oracle_success"].mean(),
            "transfer gain": grouped["transfer_gain"].mean(),
        }
    )


def _mean_of(grouped, column: str) -> pd.Series:
    """A column's mean per group; NaN for a table from before the column existed."""
    return grouped[column].mean() if column in grouped.obj.columns else grouped.size() * np.nan


def write_atomic_csv(table: pd.DataFrame, path: Path) -> None:
    """Write beside, then rename: a reader never sees half a table."""
    with atomic_path(path) as partial:
        table.to_csv(partial, index=False)


def stage_metrics(table: pd.DataFrame) -> dict[str, float]:
    """The stage run's summary in MLflow, per method: pairs, mean success, mean transfer gain,
    and the pairs whose success is above every control's."""
    metrics: dict[str, float] = {"pairs": len(table)}
    for method, rows in table.groupby("method"):
        metrics[f"{method}.pairs"] = len(rows)
        metrics[f"{method}.success"] = rows["success_mean"].mean()
        metrics[f"{method}.transfer_gain"] = rows["transfer_gain"].mean()
        metrics[f"{method}.pairs_above_every_control"] = int((rows["transfer_gain"] > 0).sum())
    return metrics
