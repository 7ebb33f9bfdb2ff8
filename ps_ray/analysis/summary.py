"""The report's answer-first parts: the headline table per method at the top, and the cost
that ``ps-ray sweep --check`` projected beside what the stages used."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ps_ray.analysis import tables
from ps_ray.analysis.alignment import chance_mrr
from ps_ray.analysis.latent import QUADRANTS
from ps_ray.analysis.page import Report, Section
from ps_ray.analysis.stats import SIGN_TEST_MIN_SEEDS
from ps_ray.specs.modes import same_seed_first
from ps_ray.specs.sweep import SweepSpec


def cost_section(report: Report, spec: SweepSpec, root: Path) -> None:
    """The cost `--check` projected beside what the stages used."""
    from ps_ray.analysis import cost
    from ps_ray.store.stages import stage_wall_s

    projection = cost.project(spec)
    used = cost.spent(root)
    rows = {}
    for load in projection.loads:
        attempts, core_s = used.get(load.stage, (0, 0.0))
        rows[load.stage] = {
            "trials (projected)": len(load.trials),
            "core-hours (projected)": round(sum(cost.trial_seconds(load, projection.rates)) / 3600, 3),
            "attempts (ran)": attempts,
            "core-hours in trials (used)": round(core_s / 3600, 3),
        }
    if not any(r["attempts (ran)"] for r in rows.values()):
        return
    walls = [w for stage in spec.stages if stage != "report" and (w := stage_wall_s(spec, stage)) is not None]
    measured = f"measured {sum(walls) / 60:.1f} min over the pipeline's stages" if walls else "not measured"
    section = report.section(
        "Cost: projected and used",
        f"Projected by `ps-ray sweep --check` from {projection.rates.source}: "
        f"{projection.core_s / 3600:.2f} core-hours, wall time {projection.wall_s_here / 60:.1f} min "
        f"on {projection.cores_here} cores; {measured}. Used core-hours count time inside trials "
        "only (starting Ray workers and stages is not in them), over every attempt.",
    )
    frame = pd.DataFrame.from_dict(rows, orient="index")
    frame.index.name = "stage"
    report.table(section, "cost", "Projected and used cost per stage", frame)


def _zero_shot_columns(pooled: pd.Series | None, transfer_rows: pd.DataFrame) -> dict[str, str]:
    """A method's zero-shot cells of the headline: where its pairs were scored beside their controls,
    success per pairing (same seed first: a co-trained grid's cell transfers within its seed, not
    across, and a mean over both hides it) and the gain; else the mean over every pair and its IQM.
    Touching and the count of cells are over every pair."""
    row: dict[str, str] = {}
    scored = len(transfer_rows) and transfer_rows["gain_diff"].notna().any()
    for _, r in transfer_rows.iterrows() if scored else ():
        name = f"zero-shot success, {r['pairing'].replace('_', ' ')} [95% CI]"
        row[name] = f"{r['success_mean']:.2f} " + tables.ci(r["success_mean_lo"], r["success_mean_hi"])
    if pooled is not None and not scored:
        row["zero-shot success, mean [95% CI]"] = f"{pooled['success_mean']:.2f} " + tables.ci(
            pooled["success_mean_lo"], pooled["success_mean_hi"]
        )
        row["zero-shot success IQM"] = f"{pooled['success_iqm']:.2f}"
    if pooled is not None:
        if "touching_mean" in pooled and pooled["touching_mean"] == pooled["touching_mean"]:
            row["touching, mean [95% CI]"] = f"{pooled['touching_mean']:.2f} " + tables.ci(
                pooled["touching_mean_lo"], pooled["touching_mean_hi"]
            )
        row["cells"] = str(int(pooled["success_cells"]))
    for _, r in transfer_rows.iterrows():
        if r["gain_diff"] == r["gain_diff"]:
            if r["gain_p"] != r["gain_p"]:
                p = ", units share runs"
            elif r["seeds"] < SIGN_TEST_MIN_SEEDS:  # the sign-flip p cannot reach 0.05
                p = f", {int(r['gain_wins'])}/{int(r['seeds'])} seeds up"
            else:
                p = f", p {r['gain_p']:.2g}"
            row[f"transfer gain, {r['pairing'].replace('_', ' ')}"] = (
                f"{r['gain_diff']:+.2f} " + tables.ci(r["gain_lo"], r["gain_hi"]) + p
            )
    return row


def summary_section(report: Report, spec: SweepSpec, target: float) -> None:
    """The answer first: per method, zero-shot success and touching with CIs, cross-robot
    alignment and training success, with the budget in one sentence; put at the top."""
    h = report.headline
    rows = {}
    translated = [] if h.zero_shot is None else list(h.zero_shot.index)
    for method in tables.method_order([*spec.methods, *translated]):  # "ablation+affine" rows too
        row: dict[str, str] = {}
        zs, tr = h.zero_shot, h.transfer
        pooled = zs.loc[method] if zs is not None and method in zs.index else None
        mine = pd.DataFrame() if tr is None else tr[tr["method"] == method]
        if len(mine):
            mine = mine.sort_values("pairing", key=lambda s: s.map(same_seed_first))
        row |= _zero_shot_columns(pooled, mine)
        al = h.alignment
        if al is not None:
            part = al[(al["method"] == method) & (al["comparison"] == "robots")]
            if len(part):
                r = part.sort_values("interface_dim").iloc[-1]
                row["across robots: MRR"] = f"{r['mrr_mean']:.3f}"
                row["across robots: cosine dist."] = f"{r['cosine_mean']:.4f}"
        if h.collapsed is not None and method in h.collapsed.index:
            row["collapsed interfaces"] = str(int(h.collapsed[method]))
        steps = h.steps
        if steps is not None and method in steps.index:
            r = steps.loc[method]
            reached, runs = int(r["reached"]), int(r["runs"])
            row[f"env steps to {target:.2f}"] = (
                f"not within {r['steps_mean']:.0f} (0/{runs} runs)"
                if reached == 0
                else f"{r['steps_mean']:.0f} ({reached}/{runs} runs reached it)"
            )
        src = h.sources
        if src is not None and (src["method"] == method).any():
            sources = src[src["method"] == method]
            row["training success (mean)"] = f"{sources['success'].mean():.2f}"
            row[f"sources < {target:.2f}"] = f"{int(sources['below_target'].sum())}/{len(sources)}"
        if row:
            rows[method] = row
    if not rows:
        return
    train = spec.train
    budget = (
        f"Budget: {len(spec.seeds)} seed(s), up to {train.get('env_steps', 'default')} env "
        f"steps per source"
        + (
            f", stopping early at greedy success {train['target_success']}"
            if train.get("target_success") is not None
            else ""
        )
        + ". "
    )
    from ps_ray.analysis.cost import budget_note

    note = budget_note(spec)
    budget += f"{note} " if note else ""
    probes = len(QUADRANTS) * spec.report.probes_per_group
    section = Section(
        "Summary",
        budget + "Zero-shot: stitched pairs in their target env, no "
        "training; 95% t intervals over per-seed means (fewer than two seeds: n/a). Transfer gain: "
        "stitched success minus the best of the unstitched sources, chance and the task-blind floor "
        "on the same episodes. "
        "MRR: retrieval of the same probe state across networks (1 = perfect; chance with "
        f"{probes} probes: {chance_mrr(probes):.3f}; a collapsed interface cannot score).",
    )
    frame = pd.DataFrame.from_dict(rows, orient="index").fillna("–")
    frame.index.name = "method"
    path = report.root / "tables" / "summary.csv"
    frame.to_csv(path)
    section.items.append(("table", ("Headline per method", frame)))
    report.sections.insert(0, section)
