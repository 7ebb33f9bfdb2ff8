"""The report's first section: each stitched pair beside its controls, the floor and the ceiling
(:mod:`ps_ray.analysis.transfer`'s numbers), the transfer gain, what co-training adds; its
figures into the report's MLflow run as metrics."""

from __future__ import annotations

import pandas as pd

from ps_ray.analysis import transfer, transfer_plots
from ps_ray.analysis.page import Report

# the transfer table's figures logged per method and pairing
LOGGED = (
    "success_mean",
    *transfer.CONTROL_COLUMNS,
    *transfer.CEILING_COLUMNS,
    *transfer.BEHAVIOUR_COLUMNS,
    "gain_diff",
    "gain_p",
)


def transfer_section(report: Report, table: pd.DataFrame, episodes: int, touching: bool) -> None:
    """Stitching against its controls: the transfer table and the transfer-gain figure, first;
    ``touching``: whether a task of the table moves an object (else its column is left out)."""
    numbers = transfer.transfer_numbers(table, episodes)
    section = report.section(
        "Transfer: stitching against its controls",
        "Each stitched pair (task module of (X, Ra), robot module of (Y, Rb), run on (X, Rb)) beside "
        "its robot source run on (X, Rb), its task source run on robot Rb, the oracle trained on "
        "(X, Rb), chance (no task knowledge: a random point of the target region; random actions) "
        "and the task-blind floor (every task of the scene but not told which: each episode driven "
        "to every candidate target in turn, averaged, so no draw; absent where the tasks do not "
        "share a scene), all on the pair's episodes, each seed on scenes of its own. Wrong target: "
        "ended at a target the task does not name (the floor's beside it); touching: the stitch "
        "touched the object (tasks that move one). Ceiling: the robot source run with the scene's "
        "markers traded in what it reads, so it is told the task: what a perfect latent map would "
        "give its robot module (tasks of one marker family; an upper bound, not a control). "
        "Transfer gain: stitched minus the best of the sources, chance and the floor, per seed; t "
        "interval over seeds (success rates on the logit scale, so they stay in [0, 1]) and, from "
        "six seeds, a sign-flip p-value (fewer: the count of seeds up); the gain over the sources "
        "and chance alone beside it. Cross-seed units (seed i's task modules, seed i+1's robot "
        "modules) share runs: their intervals are widened for it, without a p-value. Rows that read "
        "the task's target (@swapped) are upper bounds, last. Pairs surely above / below: by more "
        "than their episodes' 95% interval (Newcombe's).",
        first=True,
    )
    controls, gains = transfer.transfer_views(numbers, touching=touching)
    report.table(section, "transfer", "Stitched success beside its controls", controls, numbers=numbers)
    report.shown(section, "The transfer gain over those controls, per method and pairing", gains)
    report.figure(section, "transfer_gain", lambda p: transfer_plots.transfer_gain_bars(table, p))
    report.figure(section, "transfer_controls", lambda p: transfer_plots.controls_bars(numbers, p))
    co_trained = transfer.co_training_numbers(table)
    if len(co_trained):
        title = (
            "What co-training adds: a grid's held-out pairs beside the same pairs of sources trained alone"
        )
        report.table(section, "co_training", title, co_trained.set_index(["method", "pairing"]))
    report.headline.transfer = numbers
    for _, row in numbers.iterrows():
        prefix = f"transfer.{row['method']}.{row['pairing']}"
        for column in LOGGED:
            if row[column] == row[column]:
                report.metrics[f"{prefix}.{column}"] = float(row[column])
