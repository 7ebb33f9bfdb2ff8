"""Figures of the report (matplotlib, Agg): distance heatmaps, interface PCA, curves, bars.

Every function draws one figure and writes a PNG; it returns the path. Colours of goal
quadrants are fixed so that the same region has the same colour in every panel.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from ps_ray.analysis.latent import QUADRANTS, Group, Probes, mean_matrix, shared_pca  # noqa: E402
from ps_ray.specs.names import readable  # noqa: E402

QUADRANT_COLOURS = dict(zip(QUADRANTS, ("tab:red", "tab:blue", "tab:green", "tab:orange")))
METRIC_TITLES = {"cosine": "cosine distance", "l2": "L2 distance"}


# Text a reader can read once the page scales a figure to its 1200-pixel column.
plt.rcParams.update(
    {
        "font.size": 11,
        "axes.titlesize": 12,
        "axes.labelsize": 11,
        "xtick.labelsize": 10,
        "ytick.labelsize": 10,
        "legend.fontsize": 9,
    }
)


def save_figure(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    return path


def distance_heatmaps(by_method: Mapping[str, Sequence[Group]], title: str, path: Path) -> Path:
    """Rows: methods; columns: cosine and L2. Each cell: the mean matrix of the method's groups.
    Methods share one colour scale per metric (cosine from 0 to at least 1), so they compare."""
    methods = list(by_method)
    matrices = {
        (m, metric): mean_matrix(by_method[m], metric) for m in methods for metric in ("cosine", "l2")
    }
    top = {
        metric: max(float(matrices[m, metric].to_numpy().max()) for m in methods)
        for metric in ("cosine", "l2")
    }
    top["cosine"] = max(1.0, top["cosine"])
    fig, axes = plt.subplots(len(methods), 2, figsize=(8, 3.4 * len(methods)), squeeze=False)
    for row, method in enumerate(methods):
        for col, metric in enumerate(("cosine", "l2")):
            matrix = matrices[method, metric]
            ax = axes[row, col]
            vmax = top[metric] or 1.0
            image = ax.imshow(matrix.to_numpy(), cmap="viridis", vmin=0, vmax=vmax)
            ax.set_xticks(range(len(matrix)), matrix.columns, rotation=30, ha="right")
            ax.set_yticks(range(len(matrix)), matrix.index)
            for (i, j), value in np.ndenumerate(matrix.to_numpy()):
                ax.text(
                    j,
                    i,
                    f"{value:.3f}" if metric == "cosine" else f"{value:.2f}",
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="white" if value < 0.6 * vmax else "black",
                )
            ax.set_title(f"{method}: {METRIC_TITLES[metric]}")
            fig.colorbar(image, ax=ax, fraction=0.046)
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


def interface_scatter(group: Group, probes: Probes, title: str, path: Path) -> Path:
    """One panel per member: the interface on the probe states, coloured by goal quadrant.

    3-D interfaces are drawn raw in 3-D; wider ones on a PCA basis shared by the whole group."""
    names = list(group.members)
    values = [group.members[n].values for n in names]
    three_d = values[0].shape[1] == 3
    points = values if three_d else shared_pca(values)
    fig = plt.figure(figsize=(3.2 * len(names), 3.3))
    first = None
    for index, (name, xy) in enumerate(zip(names, points)):
        shared = {} if three_d or first is None else {"sharex": first, "sharey": first}
        ax = fig.add_subplot(1, len(names), index + 1, projection="3d" if three_d else None, **shared)
        first = first or ax
        for quadrant in QUADRANTS:
            mask = probes.labels == quadrant
            coords = [xy[mask, c] for c in range(xy.shape[1])]
            ax.scatter(*coords, s=4, color=QUADRANT_COLOURS[quadrant], label=quadrant)
        ax.set_title(f"{group.comparison[:-1]} {readable(str(name))}")
        ax.tick_params(labelsize=9)
        axis_names = ("x", "y", "z") if three_d else ("principal component 1", "principal component 2")
        ax.set_xlabel(axis_names[0], fontsize=9)
        ax.set_ylabel(axis_names[1], fontsize=9)
        if index == 0:
            ax.legend(fontsize=8, markerscale=2, loc="best")
    fig.suptitle(readable(title))  # the fixed task or robot as a reader writes it, not its JSON
    fig.tight_layout()
    return save_figure(fig, path)


def learning_curves(
    curves: pd.DataFrame,
    *,
    x: str,
    y: str,
    panel: str,
    line: str,
    title: str,
    path: Path,
    ylabel: str = "greedy success",
) -> Path:
    """One panel per ``panel`` value; one line per ``line`` value: the mean over the rows' runs
    (column ``run``) at each x, with the min-max band."""
    panels = list(dict.fromkeys(curves[panel]))
    columns = min(3, len(panels))
    rows = -(-len(panels) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.6 * columns, 3.2 * rows), squeeze=False)
    for ax, name in zip(axes.flat, panels):
        part = curves[curves[panel] == name]
        for label, lines in part.groupby(line, sort=True):
            stats = lines.groupby(x)[y].agg(["mean", "min", "max"])
            ax.plot(stats.index, stats["mean"], label=f"{readable(str(label))} ({lines['run'].nunique()})")
            ax.fill_between(stats.index, stats["min"], stats["max"], alpha=0.2)
        ax.set_title(readable(str(name)))
        ax.set_xlabel(x.replace("_", " "))
        ax.set_ylabel(ylabel)
        ax.set_ylim(-0.05, 1.05)
        ax.legend(fontsize=8)
    for ax in list(axes.flat)[len(panels) :]:
        ax.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


# few-shot starts, in the order legends list them, with what a legend says of each
START_LABELS = {
    "stitched": "stitch as it is",
    "aligned": "stitch aligned by its translation",
    "task_module": "its task module, a fresh robot module",
    "robot_module": "its robot module, a fresh task module",
    "unstitched": "robot source as it is",
    "scratch": "scratch",
}
START_ORDER = tuple(START_LABELS)
LINE_STYLES = [("-", "o"), ("--", "s"), (":", "^"), ("-.", "D"), ((0, (5, 1)), "v")]


def seed_interval_curves(
    table: pd.DataFrame, title: str, path: Path, references: Mapping[str, Mapping[str, float]] | None = None
) -> Path:
    """:func:`seed_interval_figure`, saved at ``path``."""
    return save_figure(seed_interval_figure(table, title, references), path)


def seed_interval_figure(
    table: pd.DataFrame, title: str, references: Mapping[str, Mapping[str, float]] | None = None
):
    """A panel per method, a line per start kind: the mean over seeds of ``seed_curves``' table
    (ps_ray.analysis.transfer) with its 95% t interval as a band (none from one seed, and the
    title says which); ``references``: per method, levels drawn across its panel (the target
    envs' zero-shot floor and oracle, ps_ray.analysis.transfer.few_shot_references)."""
    methods = list(dict.fromkeys(table["method"]))
    fig, axes = plt.subplots(1, len(methods), figsize=(8.6 * len(methods), 3.6), squeeze=False)
    for ax, method in zip(axes[0], methods):
        lines = table[table["method"] == method]
        kinds = sorted(dict.fromkeys(lines["kind"]), key=lambda k: (START_ORDER + (k,)).index(k))
        for kind, style in zip(kinds, LINE_STYLES * len(kinds)):  # lines that coincide stay told apart
            line = lines[lines["kind"] == kind]
            seeds = int(line["seeds"].iloc[0])
            label = f"{START_LABELS.get(kind, kind)} ({seeds} seed{'' if seeds == 1 else 's'})"
            drawn = ax.plot(line["env_steps"], line["mean"], linestyle=style[0], marker=style[1], label=label)
            ax.fill_between(
                line["env_steps"], line["low"], line["high"], color=drawn[0].get_color(), alpha=0.15
            )
        for (label, level), style in zip((references or {}).get(method, {}).items(), (":", "--")):
            ax.axhline(level, color="0.35", linestyle=style, linewidth=1.2, label=f"{label}: {level:.2f}")
        ax.set_title(readable(str(method)))
        ax.set_xlabel("env steps")
        ax.set_ylabel("greedy success")
        ax.set_ylim(-0.05, 1.05)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside, over no line
    one = table["seeds"].max() < 2  # no interval titled over one seed
    fig.suptitle(f"{title}, {'one seed, no interval' if one else 'mean and 95% t interval over seeds'}")
    fig.tight_layout()
    return fig


_VERB = {"success": "reached the goal", "touching": "touched the object"}


def _note(ax, text: str) -> None:
    """A sentence in the middle of a panel whose data draw nothing."""
    ax.text(
        0.5,
        0.5,
        text,
        transform=ax.transAxes,
        ha="center",
        va="center",
        color="0.3",
        bbox={"facecolor": "white", "edgecolor": "0.7"},
    )


def zero_shot_bars(table: pd.DataFrame, path: Path) -> Path:
    """Success and touching per stitched combination (rows), one bar per method (mean over
    seeds, error bar: pooled std)."""
    from ps_ray.analysis.tables import method_order

    labels = list(dict.fromkeys(table["label"]))
    methods = method_order(table["method"])
    metrics = ["success"] + (["touching"] if table["touching_mean"].gt(0).any() else [])
    fig, axes = plt.subplots(
        1,
        len(metrics),
        figsize=(6 * len(metrics) + 3, 0.3 * len(labels) * len(methods) + 1.5),
        sharey=True,
        squeeze=False,
    )
    axes = axes[0]
    height = 0.8 / len(methods)
    for ax, metric in zip(axes, metrics):
        for index, method in enumerate(methods):
            part = table[table["method"] == method].set_index("label").reindex(labels)
            ax.barh(
                np.arange(len(labels)) + index * height,
                part[f"{metric}_mean"],
                height,
                xerr=part[f"{metric}_std"],
                label=method,
                capsize=2,
            )
        ax.set_yticks(np.arange(len(labels)) + 0.4 - height / 2, [readable(x) for x in labels])
        ax.set_xlim(0, 1)
        ax.set_xlabel(f"zero-shot {metric} rate")
        ax.invert_yaxis()
        if not table[f"{metric}_mean"].fillna(0).any():  # bars of length 0 draw nothing: say so
            _note(ax, f"every {metric} rate is 0: no stitched policy\n{_VERB[metric]} on any episode")
    axes[0].legend()
    fig.tight_layout()
    return save_figure(fig, path)


def search_curves(curves: pd.DataFrame, path: Path) -> Path:
    """A search's trials (ps_ray.analysis.search): greedy success and the entropy temperature
    against env steps, a line per drawn setting."""
    fig, (success, alpha) = plt.subplots(1, 2, figsize=(11, 3.8))
    for name, part in curves.groupby("setting", sort=True):
        evals = part.dropna(subset=["eval_success"])
        (line,) = success.plot(evals["env_steps"], evals["eval_success"], label=name, linewidth=1.2)
        temps = part.dropna(subset=["alpha"])
        alpha.plot(temps["env_steps"], temps["alpha"], color=line.get_color(), linewidth=1.2)
    success.set(xlabel="env steps", ylabel="greedy success", ylim=(-0.05, 1.05), title="greedy success")
    alpha.set(xlabel="env steps", ylabel="entropy temperature (alpha)", yscale="log", title="temperature")
    success.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    return save_figure(fig, path)
