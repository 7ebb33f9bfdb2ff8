"""The zero-shot table's summary per method, for the terminal, and the stage run's summary
metrics in MLflow (the table itself, ``zero_shot.csv``: :mod:`ps_ray.stitching.pair_table`)."""

from __future__ import annotations

import pandas as pd


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
            "task-blind floor": grouped["task_blind_success"].mean(),
            "wrong target": grouped["wrong_target_mean"].mean(),
            "oracle": grouped["oracle_success"].mean(),
            "transfer gain": grouped["transfer_gain"].mean(),
        }
    )


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
