"""Tables of the report: latent distances (the paper's appendix layout), zero-shot results
(Table 1 layout: combinations as rows, methods as columns, touching and success) and training."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ps_ray.specs.methods import table_order
from ps_ray.specs.names import short_name


def pm(mean: float, std: float, digits: int = 2) -> str:
    """``mean ± std`` with ``digits`` decimals."""
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def ci(lo: float, hi: float, digits: int = 2) -> str:
    """``[lo, hi]``, or ``[n/a]`` where there is no interval (fewer than two seeds)."""
    return "[n/a]" if np.isnan(lo) else f"[{lo:.{digits}f}, {hi:.{digits}f}]"


def method_order(methods) -> list[str]:
    """Distinct methods, PS first, then the baselines in the paper's order."""
    return sorted(set(methods), key=table_order)


def latent_table(distances: pd.DataFrame, comparison: str, interface_dim: int) -> pd.DataFrame:
    """One of the paper's appendix tables: rows = methods, columns = cosine and L2 distance."""
    part = distances[(distances["comparison"] == comparison) & (distances["interface_dim"] == interface_dim)]
    part = part.sort_values("method", key=lambda s: s.map(table_order))
    return pd.DataFrame(
        {
            "pairs": part["pairs"].to_numpy(),
            "cosine distance": [pm(m, s, 4) for m, s in zip(part["cosine_mean"], part["cosine_std"])],
            "L2 distance": [pm(m, s, 3) for m, s in zip(part["l2_mean"], part["l2_std"])],
            "cosine 95% CI": [ci(lo, hi, 4) for lo, hi in zip(part["cosine_lo"], part["cosine_hi"])],
            "retrieval MRR [95% CI]": [
                f"{m:.3f} {ci(lo, hi, 3)}"
                for m, lo, hi in zip(part["mrr_mean"], part["mrr_lo"], part["mrr_hi"])
            ],
            "top-1": [f"{m:.3f}" for m in part["top1_mean"]],
        },
        index=pd.Index(part["method"].to_numpy(), name="method"),
    )


def pool_seeds(table: pd.DataFrame) -> pd.DataFrame:
    """Zero-shot rows of several seeds per (method, label) -> one row: the mean of the seeds'
    means, and the pooled std over every repeat (within-seed variance + between-seed variance)."""
    out = []
    for (method, label), part in table.groupby(["method", "label"], sort=False):
        row = {"method": method, "label": label, "seeds": len(part)}
        for metric in ("success", "touching"):
            means, stds = part[f"{metric}_mean"].to_numpy(float), part[f"{metric}_std"].to_numpy(float)
            row[f"{metric}_mean"] = float(np.mean(means))
            row[f"{metric}_std"] = float(np.sqrt(np.mean(stds**2) + np.var(means)))
        out.append(row)
    return pd.DataFrame(out)


def paper_names() -> dict[str, str]:
    """ps_ray-style combination label -> the paper's name, e.g. ``E1 (t: Pu1-R1 & r: Pu2-R2)``."""
    from ps_ray.stitching.paper import PAPER_COMBOS

    names = {}
    for combo in PAPER_COMBOS:
        t, r = combo.task_from, combo.robot_from
        label = f"t: {t.task}-{short_name(t.robot)} & r: {r.task}-{short_name(r.robot)}"
        names[label] = f"{combo.name} ({combo.label})"
    return names


UNSTITCHED, UNSTITCHED_KEY = "best unstitched", "best_unstitched"  # the control the paper lacks
NOT_REPORTED = "not reported"


def paper_zero_shot(table: pd.DataFrame) -> pd.DataFrame | None:
    """The paper's zero-shot figures beside ours for every E-combination the table holds: rows
    (combination, ps_ray | paper), columns (method, touching | success | best unstitched),
    ``mean ± std`` as fractions (the paper's % / 100); best unstitched: the better of the pair's
    two sources run as they are in the target env, our seeds' mean (the paper reports none).
    None when the table holds none of them."""
    from ps_ray.stitching.paper import PAPER_ZERO_SHOT

    pooled, names = pool_seeds(table), paper_names()
    pooled = pooled[pooled["label"].isin(names) & pooled["method"].isin(PAPER_ZERO_SHOT["E1"])]
    if pooled.empty:
        return None
    methods = method_order(pooled["method"])
    scored = table[UNSTITCHED_KEY].notna().any()  # a table of pairs scored beside their sources
    controls = table.groupby(["method", "label"])[UNSTITCHED_KEY].mean() if scored else None
    rows = {}
    for label in sorted(pooled["label"].unique(), key=names.get):
        paper = PAPER_ZERO_SHOT[names[label].split()[0]]
        ours = {r["method"]: r for _, r in pooled[pooled["label"] == label].iterrows()}
        for source in ("ps_ray", "paper"):
            cells = {}
            for m in methods:
                for i, metric in enumerate(("touching", "success")):
                    if source == "paper":
                        cells[(m, metric)] = pm(paper[m][2 * i] / 100, paper[m][2 * i + 1] / 100)
                    elif m in ours:
                        cells[(m, metric)] = pm(ours[m][f"{metric}_mean"], ours[m][f"{metric}_std"])
                if controls is not None:
                    value = controls.get((m, label))
                    mean = "–" if value is None or pd.isna(value) else f"{value:.2f}"
                    cells[(m, UNSTITCHED)] = NOT_REPORTED if source == "paper" else mean
            rows[(names[label], source)] = cells
    frame = pd.DataFrame.from_dict(rows, orient="index").fillna("–")
    frame.index.names = ["combination", "figures"]
    return frame


def zero_shot_table(table: pd.DataFrame) -> pd.DataFrame:
    """Table 1 layout: one row per stitched combination (paper E-names where they apply), columns
    (method, touching | success) holding ``mean ± std`` pooled over seeds. Touching is left out
    where no row has it (tasks without an object)."""
    pooled = pool_seeds(table)
    names = paper_names()
    pooled["row"] = pooled["label"].map(lambda label: names.get(label, label))
    methods = method_order(pooled["method"])
    rows = sorted(pooled["row"].unique())
    metrics = ["touching", "success"] if pooled["touching_mean"].notna().any() else ["success"]
    columns = pd.MultiIndex.from_product([methods, metrics])
    out = pd.DataFrame("–", index=pd.Index(rows, name="task module & robot module"), columns=columns)
    for _, r in pooled.iterrows():
        for metric in metrics:
            out.loc[r["row"], (r["method"], metric)] = pm(r[f"{metric}_mean"], r[f"{metric}_std"])
    return out


def training_table(final: pd.DataFrame) -> pd.DataFrame:
    """Final greedy success per (method, task, interface dim): mean ± std over robots and seeds."""
    grouped = final.groupby(["method", "task", "interface_dim"])["success"]
    out = pd.DataFrame(
        {
            "runs": grouped.size(),
            "final success": grouped.agg(lambda s: pm(float(s.mean()), float(s.std(ddof=0)))),
        }
    )
    return out.sort_index(level=0, key=lambda s: s.map(table_order) if s.name == "method" else s)


def zero_shot_estimates(table: pd.DataFrame) -> pd.DataFrame:
    """Per method, over (pair, seed) cells: mean and IQM of success and touching with 95% CIs
    that resample seeds (:mod:`ps_ray.analysis.stats`), as numbers."""
    from ps_ray.analysis.stats import estimates

    frames = []
    for metric in ("success", "touching"):
        cells = table.dropna(subset=[f"{metric}_mean"])
        if cells.empty:
            continue
        est = estimates(cells, f"{metric}_mean", rate=True)
        frames.append(est.drop(columns=["cells", "seeds"] if frames else []).add_prefix(f"{metric}_"))
    out = pd.concat(frames, axis=1) if frames else pd.DataFrame()
    return out.loc[method_order(out.index)] if not out.empty else out


def estimates_text(numbers: pd.DataFrame, metrics=("success", "touching")) -> pd.DataFrame:
    """The shown form of :func:`zero_shot_estimates`: ``mean [CI]`` and ``IQM [CI]`` columns."""
    out = pd.DataFrame(index=numbers.index)
    out["cells (pairs x seeds)"] = numbers["success_cells"].astype(int)
    out["seeds"] = numbers["success_seeds"].astype(int)
    for metric in metrics:
        if f"{metric}_mean" not in numbers:
            continue
        for stat in ("mean", "iqm"):
            out[f"{metric} {stat.upper() if stat == 'iqm' else stat} [95% CI]"] = [
                f"{r[f'{metric}_{stat}']:.2f} {ci(r[f'{metric}_{stat}_lo'], r[f'{metric}_{stat}_hi'])}"
                for _, r in numbers.iterrows()
            ]
    return out


def steps_to_target(curves: pd.DataFrame, target: float) -> pd.DataFrame:
    """Per run: the env steps of its first greedy evaluation at or above ``target`` (NaN if it
    never got there) and its last step (the cap it ran to)."""
    rows = []
    for run, part in curves.sort_values("env_steps").groupby("run", sort=True):
        hit = part[part["success"] >= target]["env_steps"]
        first = part.iloc[0]
        rows.append(
            {
                "run": run,
                "method": first["method"],
                "seed": first["seed"],
                "steps": float(hit.iloc[0]) if len(hit) else float("nan"),
                "last_step": float(part["env_steps"].max()),
            }
        )
    return pd.DataFrame(rows, columns=["run", "method", "seed", "steps", "last_step"])


def steps_to_target_table(per_run: pd.DataFrame, target: float) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per method: how many runs reached ``target``, and the env steps to it, mean with a
    seed-resampling 95% CI, counting a run that never got there as its last step (a lower
    bound, so the figure flatters slow methods). Returns (shown, numbers)."""
    from ps_ray.analysis.stats import estimate

    numbers, shown = [], []
    for method in method_order(per_run["method"]):
        part = per_run[per_run["method"] == method]
        steps = part["steps"].fillna(part["last_step"]).to_numpy()
        e = estimate(steps, part["seed"].to_numpy())
        censored = int(part["steps"].isna().sum())
        numbers.append(
            {
                "method": method,
                "runs": len(part),
                "reached": len(part) - censored,
                "steps_mean": e.mean,
                "steps_lo": e.mean_lo,
                "steps_hi": e.mean_hi,
                "steps_iqm": e.iqm,
            }
        )
        shown.append(
            {
                "method": method,
                "reached": f"{len(part) - censored}/{len(part)}",
                f"env steps to {target:.2f}, mean [95% CI]": ("≥ " if censored else "")
                + f"{e.mean:.0f} {ci(e.mean_lo, e.mean_hi, 0)}",
                "IQM": f"{e.iqm:.0f}",
            }
        )
    return (pd.DataFrame(shown).set_index("method"), pd.DataFrame(numbers).set_index("method"))
