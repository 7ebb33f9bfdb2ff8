"""The analysis stage: a sweep's stored results -> figures, tables, one self-contained HTML page,
and one MLflow run per sweep (``report``) holding them. Nothing is retrained.

Layout under ``<sweep>/report/`` (rebuilt in ``report.partial/`` and swapped in when complete):
  index.html                 self-contained report (figures embedded), opens offline
  figures/*.png              every figure of the page
  tables/*.csv               every table of the page, as numbers
  interfaces.safetensors     probe states and the interface dump of every modular module
"""

from __future__ import annotations

import base64
import html
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from ps_ray.analysis import clips, latent, plots, results, tables
from ps_ray.atomic import fsync_dir, write_text
from ps_ray.config import SweepSpec, short_name
from ps_ray.layout import SweepLayout

REPORT_RUN = "report"  # the MLflow run's trial key


@dataclass
class Section:
    title: str
    intro: str = ""
    # ("figure", Path) | ("table", (caption, frame)) | ("clips", (pair label, [Clip, ...]))
    items: list[tuple[str, object]] = field(default_factory=list)


@dataclass
class Report:
    """What the page shows, in order; files are written under ``root`` as they are added."""

    root: Path
    sections: list[Section] = field(default_factory=list)
    metrics: dict[str, float] = field(default_factory=dict)
    headline: dict[str, pd.DataFrame] = field(default_factory=dict)  # per-method figures for the top

    def section(self, title: str, intro: str = "") -> Section:
        self.sections.append(Section(title, intro))
        return self.sections[-1]

    def figure(self, section: Section, name: str, draw: Callable[[Path], Path]) -> None:
        section.items.append(("figure", draw(self.root / "figures" / f"{name}.png")))

    def table(
        self,
        section: Section,
        name: str,
        caption: str,
        frame: pd.DataFrame,
        numbers: pd.DataFrame | None = None,
    ) -> None:
        path = self.root / "tables" / f"{name}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        (frame if numbers is None else numbers).to_csv(path)
        section.items.append(("table", (caption, frame)))


def build_report(spec: SweepSpec, *, progress: bool = True, log_to_mlflow: bool = True) -> Path:
    """Rebuild ``<sweep>/report/`` from the stored results; returns the path of ``index.html``."""
    from ps_ray.sweep import sweep_dir

    root = sweep_dir(spec)
    say = print if progress else (lambda *a, **k: None)
    final = SweepLayout(root).report
    partial = final.with_name(f"{final.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    report = Report(partial)
    target = source_target(spec)
    _training(report, root, target, say)
    _latent(report, spec, root, say)
    _zero_shot(report, root, target, say)
    _few_shot(report, root, say)
    _clips(report, spec, say)
    _cost(report, spec, root)
    _summary(report, spec, target)
    write_text(partial / "index.html", render_html(spec, report))
    _swap_in(partial, final)
    if log_to_mlflow:
        log_report(spec, final, report.metrics)
        say(f"report: logged to MLflow run {REPORT_RUN!r} of experiment {spec.name!r}")
    return final / "index.html"


def _swap_in(new: Path, final: Path) -> None:
    """Replace the folder ``final`` by ``new`` with renames only: at every moment a complete
    report exists (``final``, or ``<final>.old`` between the two renames)."""
    old = final.with_name(f"{final.name}.old")
    shutil.rmtree(old, ignore_errors=True)
    if final.exists():
        os.replace(final, old)
    os.replace(new, final)
    fsync_dir(final.parent)
    shutil.rmtree(old, ignore_errors=True)


def _success_curves(report: Report, section: Section, name: str, frame, panel: str, line: str, title: str):
    """Greedy success against env steps, a panel per ``panel`` value and a line per ``line``."""
    draw = plots.learning_curves
    report.figure(
        section,
        name,
        lambda p: draw(frame, x="env_steps", y="success", panel=panel, line=line, title=title, path=p),
    )


# -- sections -------------------------------------------------------------------------------------
def source_target(spec: SweepSpec) -> float:
    """The success a source must reach to be trusted: the sweep's early-stop target, else 0.9."""
    target = spec.train.get("target_success")
    return float(target) if target is not None else 0.9


def _training(report: Report, root: Path, target: float, say) -> None:
    frame = results.curves(root / "tune")
    section = report.section(
        "Training",
        "Greedy success of the sweep's policies during training "
        "(mean over robots and seeds; band: min to max).",
    )
    if frame.empty:
        section.intro = "No training results yet."
        return
    frame["panel"] = frame["task"] + (
        ", interface " + frame["interface_dim"].astype(str) if frame["interface_dim"].nunique() > 1 else ""
    )
    _success_curves(report, section, "training_curves", frame, "panel", "method", "training: greedy success")
    final = results.final_success(frame)
    report.table(
        section,
        "training_final",
        "Final greedy success per method, task and interface",
        tables.training_table(final),
    )
    shown, numbers = tables.steps_to_target_table(tables.steps_to_target(frame, target), target)
    report.table(
        section,
        "training_steps_to_target",
        f"Env steps to greedy success {target:.2f} "
        "per method (first evaluation at or above it; a run that never got there counts "
        "as its last step, marked ≥)",
        shown,
        numbers=numbers,
    )
    report.headline["steps"] = numbers
    sources = final.set_index("run")[["method", "robot", "task", "seed", "env_steps", "success"]]
    sources = sources.assign(below_target=sources["success"] < target)
    report.table(
        section,
        "training_sources",
        f"Every source policy's final greedy success "
        f"(below_target: under {target:.2f}; stitched pairs built on it are flagged)",
        sources,
        numbers=sources,
    )
    report.headline["sources"] = sources
    say(
        f"report: training curves of {frame['run'].nunique()} runs "
        f"({int(sources['below_target'].sum())} below the {target:.2f} target)"
    )


def _latent(report: Report, spec: SweepSpec, root: Path, say) -> None:
    from ps_ray.zoo import ModuleZoo

    section = report.section(
        "Latent alignment",
        "Average pairwise cosine and L2 distances between the interfaces of "
        "modules that differ only in their training seed or only in their robot, on fixed probe "
        "task states (the paper's appendix tables; PS: relative vector, others: raw latent). "
        "Scatter plots: the interface on the probe states coloured by goal quadrant, on one PCA "
        "basis per group (3-D interfaces drawn raw).",
    )
    try:
        zoo = ModuleZoo.from_sweep(root)
    except ValueError:
        section.intro = "No trained modules yet."
        return
    entries = [e for e in zoo if e.stage == "train"]
    probes: dict[str, latent.Probes] = {}

    def probes_for(task) -> latent.Probes:
        name = short_name(task)
        if name not in probes:
            probes[name] = latent.probe_states(task, spec.report.probes_per_group, spec.report.seed)
        return probes[name]

    dumps = latent.dump_interfaces(entries, probes_for)
    say(
        f"report: interfaces of {len(dumps)} modular modules on "
        f"{sum(len(p.states) for p in probes.values())} probe states"
    )
    if not dumps:
        section.intro = "No modular modules in this sweep (plain has no task-only interface)."
        return
    latent.save_dumps(report.root / "interfaces.safetensors", probes, dumps)
    spreads = latent.spread_table(dumps)
    flagged = spreads[spreads["collapsed"]]
    report.table(
        section,
        "interface_spread",
        "Within-network spread of every interface "
        "(sqrt(total variance) / RMS norm; below 0.05 is flagged as collapsed: its "
        f"distances say nothing) — {len(flagged)} of {len(spreads)} flagged",
        spreads.round(4),
        numbers=spreads,
    )
    report.headline["collapsed"] = spreads.groupby("method")["collapsed"].sum()
    all_groups = {c: latent.groups(dumps, c) for c in latent.COMPARISONS}
    distances = latent.distance_table([g for gs in all_groups.values() for g in gs])
    if distances.empty:
        section.intro += " Distances need two or more seeds or robots per method."
        return
    report.table(
        section,
        "latent_distances",
        "All distances (mean and std over pairs)",
        distances.round(5),
        numbers=distances,
    )
    report.headline["alignment"] = distances
    for _, row in distances.iterrows():
        base = f"latent.{row['comparison']}.i{row['interface_dim']}.{row['method']}"
        for metric in latent.ALIGNMENT_METRICS:
            report.metrics[f"{base}.{metric}"] = float(row[f"{metric}_mean"])
    for comparison, found in all_groups.items():
        for dim in sorted({g.interface_dim for g in found}):
            chosen = [g for g in found if g.interface_dim == dim]
            what = f"across {comparison}, interface {dim}"
            report.table(
                section,
                f"latent_{comparison}_i{dim}",
                f"Distances {what}",
                tables.latent_table(distances, comparison, dim),
            )
            by_method = {
                m: [g for g in chosen if g.method == m] for m in tables.method_order(g.method for g in chosen)
            }
            report.figure(
                section,
                f"heatmap_{comparison}_i{dim}",
                lambda p, by_method=by_method, what=what: plots.distance_heatmaps(
                    by_method, f"mean pairwise distance {what}", p
                ),
            )
            for method, method_groups in by_method.items():
                group = method_groups[0]
                report.figure(
                    section,
                    f"interface_{comparison}_i{dim}_{method}",
                    lambda p, group=group, method=method, what=what: plots.interface_scatter(
                        group,
                        probes[group.members[next(iter(group.members))].task],
                        f"{method}, {what} ({group.fixed})",
                        p,
                    ),
                )
    say(f"report: latent distances of {sum(map(len, all_groups.values()))} groups")


def _zero_shot(report: Report, root: Path, target: float, say) -> None:

    table = results.zero_shot_results(SweepLayout(root).zero_shot_table)
    if table is None:
        return
    if not _has_object(table["task"]):  # reach: nothing to touch, so touching means nothing
        table = table.assign(touching_mean=float("nan"), touching_std=float("nan"))
    section = report.section(
        "Zero-shot stitching",
        "Stitched policies (task module of one "
        "robot-task pair, robot module of another) in their target env "
        "without training: touching and success, mean ± std over repeats "
        "and seeds, identical evaluation episodes for every method.",
    )
    report.table(
        section,
        "zero_shot",
        "Zero-shot results (Table 1 layout)",
        tables.zero_shot_table(table),
        numbers=tables.pool_seeds(table),
    )
    sources = report.headline.get("sources")
    if sources is not None:
        weak = set(sources.index[sources["below_target"]])
        table = table.assign(weak_source=table["task_from"].isin(weak) | table["robot_from"].isin(weak))
        flagged = table[table["weak_source"]]
        report.table(
            section,
            "zero_shot_weak_sources",
            f"{len(flagged)} of {len(table)} stitched "
            f"pairs are built on a source below the {target:.2f} target",
            flagged[["method", "seed", "label", "task_from", "robot_from", "success_mean"]],
        )
    numbers = tables.zero_shot_estimates(table)
    report.table(
        section,
        "zero_shot_summary",
        "Per method over (pair, seed) cells: mean and IQM with bootstrap 95% CIs resampling seeds",
        tables.estimates_text(numbers),
        numbers=numbers,
    )
    report.headline["zero_shot"] = numbers
    for method, row in numbers.iterrows():
        for metric in ("success", "touching"):
            for stat in ("mean", "mean_lo", "mean_hi", "iqm"):
                if f"{metric}_{stat}" in row:
                    name = metric if stat == "mean" else f"{metric}_{stat}"
                    report.metrics[f"zero_shot.{method}.{name}"] = float(row[f"{metric}_{stat}"])
    report.figure(section, "zero_shot", lambda p: plots.zero_shot_bars(tables.pool_seeds(table), p))
    say(f"report: zero-shot table of {len(table)} stitched pairs")


def _has_object(tasks: pd.Series) -> bool:
    """Whether any of these tasks (short names, e.g. ``reach{"goal_region": "east"}``) has an
    object, i.e. a task state beyond the goal."""
    from ps_ray.envs.tasks import resolve_task

    return any(resolve_task(str(name).split("{")[0]).family.state_dim > 0 for name in tasks.unique())


def _few_shot(report: Report, root: Path, say) -> None:
    frame = results.curves(SweepLayout(root).tune_few_shot)
    if frame.empty:
        return
    section = report.section(
        "Few-shot fine-tuning",
        "Stitched policies fine-tuned in their "
        "target env (after a collection phase without updates) beside the "
        "same env trained from scratch: greedy success vs env steps.",
    )
    frame["target"] = frame["robot"] + " / " + frame["task"]
    frame["line"] = frame["kind"] + ": " + frame["method"]
    title = "few-shot: greedy success in the target env"
    _success_curves(report, section, "few_shot_curves", frame, "target", "line", title)
    final = results.final_success(frame)
    summary = final.groupby(["target", "line"])["success"].mean().unstack("line")
    report.table(
        section, "few_shot_final", "Final greedy success per target env", summary.round(3), numbers=summary
    )
    say(f"report: few-shot curves of {frame['run'].nunique()} runs")


def _clips(report: Report, spec: SweepSpec, say) -> None:
    """GIFs of the same stitched pairs and start state under every method, beside their sources."""
    if "zero_shot" not in spec.stages:
        return
    rows = clips.stitched_clips(spec, report.root / "clips")
    if not rows:
        return
    section = report.section(
        "Rollouts",
        "One episode per policy from the same start state (env seed "
        f"{clips.START_SEED}): each stitched pair under every method in its target env, then the "
        "task-module source and the robot-module source in their own envs. Captions name the env "
        "(robot, task) and say whether the episode ended at the goal.",
    )
    section.items += [("clips", row) for row in rows]
    say(f"report: {sum(len(c) for _, c in rows)} rollout clips of {len(rows)} stitched pair(s)")


def _cost(report: Report, spec: SweepSpec, root: Path) -> None:
    """The cost `--check` projected beside what the stages used."""
    from ps_ray import cost
    from ps_ray.pipeline import stage_wall_s

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


def _summary(report: Report, spec: SweepSpec, target: float) -> None:
    """The answer first: per method, zero-shot success and touching with CIs, cross-robot
    alignment and training success, with the budget in one sentence; put at the top."""
    h = report.headline
    rows = {}
    translated = [] if h.get("zero_shot") is None else list(h["zero_shot"].index)
    for method in tables.method_order([*spec.methods, *translated]):  # "ablation+affine" rows too
        row: dict[str, str] = {}
        zs = h.get("zero_shot")
        if zs is not None and method in zs.index:
            r = zs.loc[method]
            row["zero-shot success, mean [95% CI]"] = f"{r['success_mean']:.2f} " + tables.ci(
                r["success_mean_lo"], r["success_mean_hi"]
            )
            row["zero-shot success IQM"] = f"{r['success_iqm']:.2f}"
            if "touching_mean" in r and r["touching_mean"] == r["touching_mean"]:
                row["touching, mean [95% CI]"] = f"{r['touching_mean']:.2f} " + tables.ci(
                    r["touching_mean_lo"], r["touching_mean_hi"]
                )
            row["cells"] = str(int(r["success_cells"]))
        al = h.get("alignment")
        if al is not None:
            part = al[(al["method"] == method) & (al["comparison"] == "robots")]
            if len(part):
                r = part.sort_values("interface_dim").iloc[-1]
                row["across robots: MRR"] = f"{r['mrr_mean']:.3f}"
                row["across robots: cosine dist."] = f"{r['cosine_mean']:.4f}"
        if h.get("collapsed") is not None and method in h["collapsed"].index:
            row["collapsed interfaces"] = str(int(h["collapsed"][method]))
        steps = h.get("steps")
        if steps is not None and method in steps.index:
            r = steps.loc[method]
            row[f"env steps to {target:.2f}"] = (
                f"{r['steps_mean']:.0f} ({int(r['reached'])}/{int(r['runs'])} reached)"
            )
        src = h.get("sources")
        if src is not None and (src["method"] == method).any():
            mine = src[src["method"] == method]
            row["training success (mean)"] = f"{mine['success'].mean():.2f}"
            row[f"sources < {target:.2f}"] = f"{int(mine['below_target'].sum())}/{len(mine)}"
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
    from ps_ray.cost import budget_note

    note = budget_note(spec)
    budget += f"{note} " if note else ""
    section = Section(
        "Summary",
        budget + "Zero-shot: stitched pairs in their target env, no "
        "training; CIs resample seeds (fewer than two seeds: n/a). MRR: retrieval of "
        "the same probe state across networks (1 = perfect; a collapsed interface "
        "cannot score).",
    )
    frame = pd.DataFrame.from_dict(rows, orient="index").fillna("–")
    frame.index.name = "method"
    path = report.root / "tables" / "summary.csv"
    frame.to_csv(path)
    section.items.append(("table", ("Headline per method", frame)))
    report.sections.insert(0, section)


# -- HTML -----------------------------------------------------------------------------------------
STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
h1 { border-bottom: 2px solid #444; } h2 { margin-top: 2em; border-bottom: 1px solid #bbb; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: right; }
th { background: #f0f0f0; } caption { font-weight: bold; text-align: left; padding: 4px 0; }
img { max-width: 100%; display: block; margin: 1em 0; } .meta td { text-align: left; }
.clips td { text-align: left; vertical-align: top; width: 240px; } .clips img { margin: 0; }
.caption { font-size: 0.8em; }
"""


def render_html(spec: SweepSpec, report: Report) -> str:
    """One page, figures embedded as data URIs, so the file opens anywhere without its folder."""
    from ps_ray.tracking import git_commit

    esc = html.escape
    meta = {
        "methods": ", ".join(spec.methods),
        "robots": ", ".join(map(short_name, spec.robots)),
        "tasks": ", ".join(map(short_name, spec.tasks)),
        "seeds": ", ".join(map(str, spec.seeds)),
        "interface dims": ", ".join(map(str, spec.interface_dims)),
        "stages": ", ".join(spec.stages),
        "code": git_commit() or "unknown",
    }
    parts = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>ps_ray report: {esc(spec.name)}</title><style>{STYLE}</style></head><body>",
        f"<h1>ps_ray report: {esc(spec.name)}</h1>",
        "<table class='meta'>",
        *(f"<tr><th>{esc(k)}</th><td>{esc(v)}</td></tr>" for k, v in meta.items()),
        "</table>",
    ]
    parts.append(
        "<ul>"
        + "".join(f"<li><a href='#s{i}'>{esc(s.title)}</a></li>" for i, s in enumerate(report.sections))
        + "</ul>"
    )
    for index, section in enumerate(report.sections):
        parts.append(f"<h2 id='s{index}'>{esc(section.title)}</h2><p>{esc(section.intro)}</p>")
        for kind, item in section.items:
            if kind == "figure":
                data = base64.b64encode(item.read_bytes()).decode()
                parts.append(f"<img alt='{esc(item.stem)}' src='data:image/png;base64,{data}'>")
            elif kind == "clips":
                label, row = item
                parts.append(f"<h3>{esc(label)}</h3><table class='clips'><tr><th>method</th>")
                parts += [f"<th>{esc(role)}</th>" for role in clips.ROLES]
                for method in dict.fromkeys(c.method for c in row):
                    parts.append(f"<tr><th>{esc(method)}</th>")
                    for clip in (c for c in row if c.method == method):
                        data = base64.b64encode(clip.path.read_bytes()).decode()
                        verdict = "reached the goal" if clip.success else "did not reach the goal"
                        parts.append(
                            f"<td><img alt='{esc(clip.path.stem)}' src='data:image/gif;base64,{data}'>"
                            f"<div class='caption'>{esc(clip.env)}: {verdict}</div></td>"
                        )
                    parts.append("</tr>")
                parts.append("</table>")
            else:
                caption, frame = item
                head, rest = frame.to_html(border=0, na_rep="–").split(">", 1)
                parts.append(f"{head}><caption>{esc(caption)}</caption>{rest}")
    parts.append("</body></html>")
    return "\n".join(parts)


# -- MLflow ---------------------------------------------------------------------------------------
def log_report(spec: SweepSpec, report_dir: Path, metrics: dict[str, float]) -> str:
    """One run per sweep (found again by its key), holding the report folder and headline
    numbers; a rebuild overwrites the same artifacts. Returns the run id."""
    from ps_ray.sweep import sweep_dir
    from ps_ray.tracking import STAGE_TAG, TrialTracker, default_tracking_uri, ensure_experiment, git_commit

    root = sweep_dir(spec)
    uri = spec.tracking_uri or default_tracking_uri(root)
    experiment = ensure_experiment(uri, spec.name, SweepLayout(root).artifacts)
    tracker = TrialTracker(
        uri,
        experiment,
        REPORT_RUN,
        params={"sweep": spec.name},
        tags={STAGE_TAG: "report", "ps_ray.sweep": spec.name, "git_commit": git_commit() or ""},
    )
    # MLflow names allow no "+": a translated stitch "ablation+affine" is logged as "ablation-affine"
    tracker.log_metrics({k.replace("+", "-"): v for k, v in metrics.items()}, step=0)
    for path in sorted(report_dir.iterdir()):
        tracker.log_artifact(path)
    tracker.log_dict(_run_index(tracker.client, experiment, tracker.run_id), "runs.json")
    tracker.close()
    return tracker.run_id


def _run_index(client, experiment_id: str, report_run: str) -> dict[str, dict[str, dict[str, str]]]:
    """Every run the report summarises, by stage and trial key: its run id, and for a stitched
    policy the runs of its two sources (``runs.json`` in the report run)."""
    from ps_ray.tracking import ROBOT_SOURCE_RUN_TAG, STAGE_TAG, TASK_SOURCE_RUN_TAG, TRIAL_KEY_TAG

    index: dict[str, dict[str, dict[str, str]]] = {}
    for run in client.search_runs([experiment_id], max_results=50_000):
        tags = run.data.tags
        if run.info.run_id == report_run or TRIAL_KEY_TAG not in tags:
            continue
        entry = {"run_id": run.info.run_id}
        for name, tag in (
            ("task_module_run", TASK_SOURCE_RUN_TAG),
            ("robot_module_run", ROBOT_SOURCE_RUN_TAG),
        ):
            if tag in tags:
                entry[name] = tags[tag]
        index.setdefault(tags.get(STAGE_TAG, "unknown"), {})[tags[TRIAL_KEY_TAG]] = entry
    return index
