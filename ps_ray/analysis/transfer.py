"""Stitching against its controls: per method and pairing, the stitched success beside the
unstitched sources, chance, the task-blind floor and the oracle on the same episodes, the
wrong-target rate, and the transfer gain (stitched minus the best of the unstitched sources,
chance and the floor) as a paired comparison over seeds, beside the gain over the sources and
chance alone (docs/controls.md); the floor's wrong-target rate and the stitches' touching beside
them, and on a marker family the ceiling of every translation (the robot source told the task).
Cross-seed units share runs: their intervals are widened for it and carry no p-value
(ps_ray.analysis.stats). Rows whose translation reads the task's target
(``@swapped``) are upper bounds, listed after the label-free rows. A table is in the current
layout (:func:`ps_ray.stitching.pair_table.read_table`): a control not measured is NaN."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ps_ray.analysis.stats import SIGN_TEST_MIN_SEEDS, estimate, newcombe, paired, t_interval
from ps_ray.analysis.tables import ci, method_order
from ps_ray.specs.modes import Pairing, TrialKind, same_seed_first
from ps_ray.specs.names import CONTROL_ROLES, parse_spec_text, short_name

CONTROL_COLUMNS = {
    "robot_source_success": "robot source unstitched",
    "task_source_success": "task source unstitched",
    "chance_success": "chance (no task knowledge)",
    "task_blind_success": "task-blind floor (every task, not told which)",
    "oracle_success": "oracle (trained on the target)",
}
# not a control but what a perfect map would reach: the robot source told the task
# (ps_ray.stitching.told); on families whose tasks share a marker scene only
CEILING_COLUMNS = {"told_robot_source_success": "ceiling: robot source told the task (a perfect map)"}
# what each row's stitches (and its floor) did besides succeeding: shown after the controls
BEHAVIOUR_COLUMNS = {
    "wrong_target_mean": "wrong target (stitched)",
    "task_blind_wrong_target": "wrong target (floor)",
    "touching_mean": "touching (stitched)",
}
UPPER_BOUND_FITS = ("@swapped",)  # fits that read the task's target: the known correspondence


def reads_target(method: str) -> bool:
    """Whether a row's translation reads the task's target (an upper bound, not a label-free result)."""
    return any(fit in str(method) for fit in UPPER_BOUND_FITS)


def has_controls(table: pd.DataFrame) -> bool:
    """Whether any pair of a zero-shot table was scored beside its controls."""
    return bool(table["transfer_gain"].notna().any())


def transfer_numbers(table: pd.DataFrame, episodes: int | None = None) -> pd.DataFrame:
    """One row per (method, pairing): success means with t intervals over seeds for the stitched
    policies and each control, and the paired transfer gain with its sign-flip p-value. With the
    ``episodes`` each cell was scored on, also how many cells are above (below) every control by
    more than their episodes' chance: a verdict per pair where the seeds are too few for one."""
    rows = []
    for (method, pairing), part in table.groupby(["method", "pairing"], sort=False):
        seeds = part["seed"].to_numpy()
        shared = pairing == Pairing.CROSS_SEED  # cyclic units share runs
        row = {"method": method, "pairing": pairing, "cells": len(part), "seeds": len(np.unique(seeds))}
        row["upper_bound"] = reads_target(method)
        for column in ("success_mean", *CONTROL_COLUMNS, *CEILING_COLUMNS, *BEHAVIOUR_COLUMNS):
            cells = part.dropna(subset=[column])
            if cells.empty:
                row[column], row[f"{column}_lo"], row[f"{column}_hi"] = np.nan, np.nan, np.nan
                continue
            values = cells[column].to_numpy()
            e = estimate(values, cells["seed"].to_numpy(), shared_runs=shared, rate=True)
            row[column], row[f"{column}_lo"], row[f"{column}_hi"] = e.mean, e.mean_lo, e.mean_hi
        # a stage resumed across the ceiling's arrival has it on some cells only: say on how many
        row["ceiling_cells"] = int(part["told_robot_source_success"].notna().sum())
        cells = part.dropna(subset=["best_control"])
        best = cells["best_control"]
        gain = paired(cells["success_mean"], best, cells["seed"], shared) if len(cells) else None
        for field in ("diff", "lo", "hi", "p", "wins", "losses"):
            row[f"gain_{field}"] = np.nan if gain is None else getattr(gain, field)
        old = part.dropna(subset=["gain_over_chance"])
        before = (
            paired(old["success_mean"], old["success_mean"] - old["gain_over_chance"], old["seed"], shared)
            if len(old)
            else None
        )
        for field in ("diff", "lo", "hi"):
            row[f"chance_gain_{field}"] = np.nan if before is None else getattr(before, field)
        row["pairs_above_every_control"] = int((cells["transfer_gain"] > 0).sum())
        lo, hi = newcombe(cells["success_mean"], best, episodes or 1)
        row["pairs_surely_above"] = int((lo > 0).sum()) if episodes else np.nan
        row["pairs_surely_below"] = int((hi < 0).sum()) if episodes else np.nan
        row["episodes"] = episodes or np.nan
        row["fit_env_steps"] = part["fit_env_steps"].mean()
        rows.append(row)
    out = pd.DataFrame(rows)
    if out.empty:
        return out
    order = {m: i for i, m in enumerate(method_order(out["method"]))}
    keys = {"method": lambda s: s.map(order), "pairing": lambda s: s.map(same_seed_first)}
    return out.sort_values(
        ["upper_bound", "pairing", "method"], key=lambda s: keys.get(s.name, lambda s: s)(s)
    )


def transfer_text(numbers: pd.DataFrame) -> pd.DataFrame:
    """The shown form: ``mean [95% CI]`` per column, the gain with its p-value and seed count."""
    out = pd.DataFrame(index=pd.MultiIndex.from_frame(numbers[["method", "pairing"]]))
    out["result"] = ["upper bound (reads the target)" if r else "label-free" for r in numbers["upper_bound"]]
    out["cells (pairs x seeds)"] = numbers["cells"].to_numpy()
    out["seeds"] = numbers["seeds"].to_numpy()
    shown = {"success_mean": "stitched", **CONTROL_COLUMNS, **CEILING_COLUMNS, **BEHAVIOUR_COLUMNS}
    for column, name in shown.items():
        out[name] = [
            ("absent (the tasks do not share a scene)" if column == "task_blind_success" else "–")
            if np.isnan(r[column])
            else f"{r[column]:.2f} {ci(r[f'{column}_lo'], r[f'{column}_hi'])}"
            + (_partial(r) if column in CEILING_COLUMNS else "")
            for _, r in numbers.iterrows()
        ]

    def p_text(r) -> str:
        if np.isnan(r["gain_p"]):
            return "units share runs, "
        return f"p {r['gain_p']:.2g}, " if r["seeds"] >= SIGN_TEST_MIN_SEEDS else ""

    out["transfer gain over every control and the floor (paired over seeds)"] = [
        "–"
        if np.isnan(r["gain_diff"])
        else f"{r['gain_diff']:+.2f} {ci(r['gain_lo'], r['gain_hi'])}, {p_text(r)}"
        f"{int(r['gain_wins'])}/{int(r['seeds'])} seeds up"
        for _, r in numbers.iterrows()
    ]
    out["gain over sources and chance (without the floor)"] = [
        "–"
        if np.isnan(r["chance_gain_diff"])
        else f"{r['chance_gain_diff']:+.2f} {ci(r['chance_gain_lo'], r['chance_gain_hi'])}"
        for _, r in numbers.iterrows()
    ]
    out["env steps of the fit per stitch"] = [
        "–" if np.isnan(r["fit_env_steps"]) else f"{r['fit_env_steps']:,.0f}" for _, r in numbers.iterrows()
    ]
    out["pairs above every control"] = [
        f"{int(r['pairs_above_every_control'])}/{int(r['cells'])}" for _, r in numbers.iterrows()
    ]
    out["pairs surely above / below every control (95% over a pair's episodes)"] = [
        "–"
        if np.isnan(r.get("episodes", np.nan))
        else f"{int(r['pairs_surely_above'])} / {int(r['pairs_surely_below'])} of {int(r['cells'])} "
        f"({int(r['episodes'])} episodes each)"
        for _, r in numbers.iterrows()
    ]
    return out


def _partial(row) -> str:
    """`` (on n of N cells)`` where the ceiling was measured on some of a row's cells only."""
    n = row.get("ceiling_cells", row["cells"])
    return f" (on {int(n)} of {int(row['cells'])} cells)" if n < row["cells"] else ""


def transfer_views(numbers: pd.DataFrame, touching: bool = True) -> tuple[pd.DataFrame, pd.DataFrame]:
    """:func:`transfer_text` as two tables that each fit a page's width: stitched success beside
    its controls, the ceiling and what the stitches did (without touching where no task moves an
    object, without the ceiling where no pair has one), then the gains (with the result kind and
    seed count repeated)."""
    text = transfer_text(numbers)
    split = list(text.columns).index(BEHAVIOUR_COLUMNS["touching_mean"]) + 1
    controls = text.iloc[:, :split]
    if not touching:
        controls = controls.drop(columns=[BEHAVIOUR_COLUMNS["touching_mean"]])
    if numbers["told_robot_source_success"].isna().all():
        controls = controls.drop(columns=list(CEILING_COLUMNS.values()))
    return controls, text[["result", "seeds", *text.columns[split:]]]


def co_training_numbers(table: pd.DataFrame) -> pd.DataFrame:
    """What co-training adds (docs/transfer.md "Co-trained grids"): per method and pairing, the
    stitched success of a co-trained grid's held-out pairs beside the same pairs (target, seeds)
    stitched from sources trained alone, and their paired difference over seeds."""
    from ps_ray.stitching.pairs import CO_TRAINED

    suffix = f" {CO_TRAINED}"
    keys = ["pairing", "seed", "robot_seed", "robot", "task"]
    rows = []
    for method in [m for m in table["method"].unique() if str(m).endswith(suffix)]:
        alone = table[table["method"] == method.removesuffix(suffix)]
        both = table[table["method"] == method].merge(alone, on=keys, suffixes=("", "_alone"))
        for pairing, part in both.groupby("pairing", sort=False):
            shared = pairing == Pairing.CROSS_SEED  # cyclic units share runs
            diff = paired(part["success_mean"], part["success_mean_alone"], part["seed"], shared)
            seeds = part["seed"].to_numpy()
            rows.append(
                {
                    "method": method,
                    "pairing": pairing,
                    "pairs": len(part),
                    "co-trained": estimate(
                        part["success_mean"].to_numpy(), seeds, shared_runs=shared, rate=True
                    ).text(),
                    "trained alone": estimate(
                        part["success_mean_alone"].to_numpy(), seeds, shared_runs=shared, rate=True
                    ).text(),
                    "co-trained minus alone (paired over seeds)": diff.text(),
                }
            )
    return pd.DataFrame(rows)


def controls_met(numbers: pd.DataFrame, unstitched_max: float = 0.1, oracle_min: float = 0.9) -> pd.DataFrame:
    """Whether the testbed needs transfer, per method and pairing: both unstitched controls at or
    below ``unstitched_max`` and the oracle at or above ``oracle_min`` (means over cells)."""
    tol = 1e-9  # means of equal rates carry rounding
    return pd.DataFrame(
        {
            "method": numbers["method"],
            "pairing": numbers["pairing"],
            "unstitched fail": (numbers["robot_source_success"] <= unstitched_max + tol)
            & (numbers["task_source_success"].fillna(0) <= unstitched_max + tol),
            "oracle learns": numbers["oracle_success"] >= oracle_min - tol,
        }
    )


def curve_area(part: pd.DataFrame, budget: float | None = None) -> float:
    """The area under one run's greedy-success curve from its first evaluation to ``budget``
    (default: its last step), divided by that span: its mean success over the budget (1 = solved
    from the first evaluation on). A run that stopped before the budget, its success target met,
    keeps its last success to the budget, so stopping early is not read as a shorter, worse run."""
    part = part.sort_values("env_steps")
    steps, success = part["env_steps"].to_numpy(float), part["success"].to_numpy(float)
    if budget is not None and budget > steps[-1]:
        steps, success = np.append(steps, budget), np.append(success, success[-1])
    span = steps[-1] - steps[0]
    return float(success[0]) if span <= 0 else float(np.trapezoid(success, steps) / span)


def few_shot_steps(curves: pd.DataFrame, threshold: float = 0.8) -> pd.DataFrame:
    """Per start kind (stitched, its halves, unstitched, scratch) and method: env steps to
    ``threshold`` greedy success (mean over runs; a run that never got there counts at its last
    step, so the mean is a lower bound) and the area under the success curve (its mean success
    over the budget, a run stopped early at its target holding its last success), each with a t
    interval over seeds and its paired difference from scratch on
    the same target env and seed; and the runs that reached the threshold."""
    from ps_ray.analysis.tables import steps_to_target

    per_run = []
    budget = curves["env_steps"].max() if len(curves) else None  # the stage's budget: its longest run
    for (kind, _method), part in curves.groupby(["kind", "method"], sort=False):
        steps = steps_to_target(part, threshold).merge(
            part[["run", "robot", "task"]].drop_duplicates("run"), on="run"
        )
        areas = part.groupby("run").apply(curve_area, budget, include_groups=False).rename("area")
        steps = steps.merge(areas, left_on="run", right_index=True)
        steps["kind"] = kind
        steps["censored"] = steps["steps"].isna()
        steps["steps"] = steps["steps"].fillna(steps["last_step"])
        per_run.append(steps)
    if not per_run:
        return pd.DataFrame()
    runs = pd.concat(per_run, ignore_index=True)
    cell = runs.groupby(["kind", "method", "robot", "task", "seed"], as_index=False)[["steps", "area"]].mean()
    rows = []
    for (kind, method), part in cell.groupby(["kind", "method"], sort=False):
        mine = runs[(runs["kind"] == kind) & (runs["method"] == method)]
        row = {
            "start": kind,
            "method": method,
            "runs": len(mine),
            f"reached {threshold}": f"{int((~mine['censored']).sum())}/{len(mine)}",
        }
        scratch = cell[(cell["kind"] == "scratch") & (cell["method"] == method)]
        both = part.merge(scratch, on=["robot", "task", "seed"], suffixes=("", "_scratch"))
        for column, name, digits in (
            ("steps", f"env steps to {threshold}", 0),
            ("area", "area under curve", 2),
        ):
            e = estimate(part[column].to_numpy(), part["seed"].to_numpy())
            row[f"{name} [95% CI]"] = e.text(digits=digits)
            if kind != TrialKind.SCRATCH and len(both):
                diff = paired(both[column], both[f"{column}_scratch"], both["seed"])
                row[f"{name}: minus scratch (paired over seeds)"] = diff.text(digits=digits)
        rows.append(row)
    return pd.DataFrame(rows).set_index(["start", "method"]).fillna("–")


def seed_curves(curves: pd.DataFrame) -> pd.DataFrame:
    """Per start kind and method, greedy success against env steps as the mean over seeds with its
    t interval: each run's success held from one evaluation to the next and, past its last, to
    the stage's budget (a run stopped early at its target keeps its success, as in
    :func:`curve_area`); a seed's runs averaged first. Only steps every seed of the kind has
    reached are kept. Columns: kind, method, env_steps, mean, low, high, seeds."""
    grid = np.unique(curves["env_steps"])
    rows = []
    for (kind, method), part in curves.groupby(["kind", "method"], sort=False):
        held = []
        for _, run in part.groupby("run"):
            run = run.sort_values("env_steps")
            last = np.searchsorted(run["env_steps"].to_numpy(), grid, side="right") - 1
            success = np.where(last >= 0, run["success"].to_numpy()[np.maximum(last, 0)], np.nan)
            held.append(pd.DataFrame({"env_steps": grid, "success": success, "seed": run["seed"].iloc[0]}))
        per_seed = pd.concat(held).dropna().groupby(["env_steps", "seed"])["success"].mean()
        seeds = part["seed"].nunique()
        for steps, at in per_seed.groupby(level="env_steps"):
            if len(at) == seeds:
                mean, low, high = t_interval(at.to_numpy(), rate=True)
                rows.append(
                    dict(
                        kind=kind, method=method, env_steps=steps, mean=mean, low=low, high=high, seeds=seeds
                    )
                )
    return pd.DataFrame(rows, columns=["kind", "method", "env_steps", "mean", "low", "high", "seeds"])


# the zero-shot controls drawn beside the few-shot curves: (column, legend label)
FEW_SHOT_REFERENCES = (
    ("task_blind_success", "task-blind floor (zero-shot)"),
    ("oracle_success", "oracle (trained on the target)"),
)


def few_shot_references(curves: pd.DataFrame, zero_shot: pd.DataFrame | None) -> dict[str, dict[str, float]]:
    """Per method of few-shot ``curves``, the floor and oracle of its target envs read from the
    zero-shot table (same seed, the method's own sources, unstitched rows): each target's value
    averaged over its pairs, then over the few-shot runs' targets (the label says how many). Empty
    where no zero-shot pair of the method shares a target with the few-shot runs."""
    if zero_shot is None or zero_shot.empty:
        return {}
    same = zero_shot[zero_shot["pairing"] == Pairing.SAME_SEED]
    # the table holds a robot or task as its spec text, the curves as its short name
    same = same.assign(
        **{c: same[c].map(lambda t: short_name(parse_spec_text(str(t)))) for c in ("robot", "task")}
    )
    keys = ["robot", "task", "seed"]
    columns = [column for column, _ in FEW_SHOT_REFERENCES]
    out = {}
    for method, part in curves.groupby("method", sort=False):
        rows = same[same["method"] == method].merge(part[keys].drop_duplicates(), on=keys)
        per_target = rows.groupby(keys)[columns].mean()
        targets = f", mean of {len(per_target)} targets" if len(per_target) > 1 else ""
        found = {
            f"{label}{targets}": float(value)
            for (column, label), value in zip(FEW_SHOT_REFERENCES, per_target.mean())
            if value == value
        }
        if found:
            out[method] = found
    return out


__all__ = [
    "CONTROL_ROLES",
    "co_training_numbers",
    "controls_met",
    "curve_area",
    "few_shot_references",
    "few_shot_steps",
    "has_controls",
    "seed_curves",
    "transfer_numbers",
    "transfer_text",
]
