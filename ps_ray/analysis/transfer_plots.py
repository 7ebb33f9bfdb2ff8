"""The transfer section's figures (matplotlib, Agg): per stitched combination the transfer gain
over the best control, and each method's stitched success beside its controls, one panel per
pairing, same seed first."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import pyplot as plt
from matplotlib.patches import Patch

from ps_ray.analysis.plots import save_figure
from ps_ray.analysis.tables import method_order
from ps_ray.specs.modes import same_seed_first
from ps_ray.specs.names import readable


def transfer_gain_bars(table: pd.DataFrame, path: Path) -> Path:
    """:func:`transfer_gain_figure`, saved at ``path``."""
    return save_figure(transfer_gain_figure(table), path)


def transfer_gain_figure(table: pd.DataFrame):
    """The report's main figure: per stitched combination (groups) and method (bars), the transfer
    gain, stitched success minus the best of its controls (unstitched sources, chance, the
    task-blind floor) on the same episodes (mean over seeds, written beside each bar; error bar:
    the seeds' range); one panel per pairing (same seed first). A combination shows only
    the methods that stitched it in some pairing (a co-trained grid stitches its held-out cell
    alone); one stitched in another pairing but not this one says "no pairs"."""
    table = table.dropna(subset=["transfer_gain"])  # pairs scored without their controls have none
    pairings = sorted(dict.fromkeys(table["pairing"]), key=same_seed_first)
    methods = method_order(table["method"])
    colours = {method: f"C{i}" for i, method in enumerate(methods)}
    stitched_by = table.groupby("label", sort=False)["method"].agg(set)
    groups = [(label, [m for m in methods if m in stitched_by[label]]) for label in stitched_by.index]
    # one row per bar, a blank row between groups; each group's tick at its middle
    bar_rows, ticks, row = [], [], 0
    for label, present in groups:
        bar_rows += [(label, method, row + i) for i, method in enumerate(present)]
        ticks.append(row + (len(present) - 1) / 2)
        row += len(present) + 1
    fig, axes = plt.subplots(
        1, len(pairings), figsize=(6 * len(pairings) + 3, 0.3 * row + 1.5), sharey=True, squeeze=False
    )
    gains = table.groupby(["pairing", "label", "method"])["transfer_gain"].agg(["mean", "min", "max"])
    for ax, pairing in zip(axes[0], pairings):
        for label, method, y in bar_rows:
            key = (pairing, label, method)
            mean, low, top = gains.loc[key] if key in gains.index else (np.nan, np.nan, np.nan)
            if mean == mean:
                ax.barh(y, mean, 0.8, xerr=[[mean - low], [top - mean]], color=colours[method], capsize=2)
            # every bar says its value, so a gain of 0 (no bar) or a missing pair still reads
            text = "no pairs" if mean != mean else f"{mean:+.2f}"
            right = 0.0 if top != top else max(top, 0.0)
            ax.text(right + 0.03, y, text, va="center", fontsize=8, color=colours[method])
        ax.axvline(0.0, color="black", linewidth=0.8)
        ax.set_yticks(ticks, [readable(label) for label, _ in groups])
        ax.set_ylim(row - 1.0, -1.0)  # top to bottom, in the table's order
        ax.set_xlim(-1.05, 1.3)
        ax.set_xlabel("transfer gain: stitched - best control (sources, chance, task-blind floor)")
        ax.set_title(pairing.replace("_", " "))
    handles = [Patch(color=colours[m]) for m in methods]
    fig.legend(handles, methods, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=min(len(methods), 4))
    fig.tight_layout()
    return fig


# the bars of :func:`controls_bars`, in the order shown: (column of transfer_numbers, legend label)
CONTROL_BARS = (
    ("success_mean", "stitched"),
    ("robot_source_success", "robot source"),
    ("task_source_success", "task source"),
    ("chance_success", "chance"),
    ("task_blind_success", "task-blind floor"),
    ("oracle_success", "oracle"),
    ("told_robot_source_success", "ceiling: robot source told the task"),
)


def controls_bars(numbers: pd.DataFrame, path: Path) -> Path:
    """:func:`controls_figure`, saved at ``path``."""
    return save_figure(controls_figure(numbers), path)


def controls_figure(numbers: pd.DataFrame):
    """Stitched success beside its controls, one panel per pairing (same seed first) and one group
    per method of :func:`ps_ray.analysis.transfer.transfer_numbers` (upper bounds last): stitched,
    robot source, task source, chance, the task-blind floor, oracle and the ceiling of a marker
    family, each a mean over seeds with its 95% t interval; a control that was not run is left out
    of every group, a method without pairs in a pairing says so."""
    pairings = sorted(dict.fromkeys(numbers["pairing"]), key=same_seed_first)
    rank = {m: i for i, m in enumerate(method_order(numbers["method"]))}
    by_rank = numbers.assign(rank=numbers["method"].map(rank)).sort_values(["upper_bound", "rank"])
    methods = list(dict.fromkeys(by_rank["method"]))
    # each bar keeps its colour whichever are left out, so figures of different sweeps read alike
    bars = [(f"C{i}", c, label) for i, (c, label) in enumerate(CONTROL_BARS) if numbers[c].notna().any()]
    height = 0.8 / len(bars)
    fig, axes = plt.subplots(
        1, len(pairings), figsize=(7 * len(pairings) + 2, len(bars) * 0.2 * len(methods) + 1.8), squeeze=False
    )
    rows = np.arange(len(methods))
    for ax, pairing in zip(axes[0], pairings):
        part = numbers[numbers["pairing"] == pairing].set_index("method").reindex(methods)
        for index, (colour, column, label) in enumerate(bars):
            mean, lo, hi = (part[f"{column}{end}"].to_numpy(float) for end in ("", "_lo", "_hi"))
            errors = np.nan_to_num(np.stack([mean - lo, hi - mean]).clip(min=0))
            ax.barh(rows + index * height, mean, height, xerr=errors, label=label, capsize=2, color=colour)
        for row in rows[part["success_mean"].isna().to_numpy()]:
            ax.text(0.02, row + 0.4 - height / 2, "no pairs", va="center", color="0.3")
        for gap in rows[:-1] + 0.9 - height / 2:  # a faint line between groups
            ax.axhline(gap, color="0.85", linewidth=0.8)
        ax.set_yticks(rows + 0.4 - height / 2, [readable(m) for m in methods] if ax is axes[0][0] else [])
        ax.set_ylim(len(methods) - 0.1, -0.1 - height / 2)  # top to bottom, in the table's order
        ax.set_xlim(0, 1.05)
        ax.set_title(pairing.replace("_", " "))
        ax.set_xlabel("zero-shot success on the stitched pairs' episodes\n(mean over seeds, 95% interval)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=4)
    fig.tight_layout()
    return fig
