"""The analysis stage: a sweep's stored results -> figures, tables, one self-contained HTML page,
and one MLflow run per sweep (``report``) holding them. Nothing is retrained.

Sections here; the page model and its HTML in :mod:`ps_ray.analysis.page`, the headline and
cost in :mod:`ps_ray.analysis.summary`, the MLflow run in :mod:`ps_ray.analysis.report_run`.

Layout under ``<sweep>/report/`` (rebuilt in ``report.partial/`` and swapped in when complete):
  index.html                 self-contained report (figures embedded), opens offline
  figures/*.png              every figure of the page
  tables/*.csv               every table of the page, as numbers
  interfaces.safetensors     probe states and the interface dump of every modular module
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd

from ps_ray.analysis import clips, latent, plots, results, tables, transfer
from ps_ray.analysis.page import Report, Section, render_html
from ps_ray.analysis.report_run import REPORT_RUN, log_report
from ps_ray.analysis.search import search_section
from ps_ray.analysis.summary import cost_section, summary_section
from ps_ray.analysis.transfer_section import transfer_section
from ps_ray.errors import UserError
from ps_ray.specs import reset_seeds
from ps_ray.specs.names import parse_spec_text, short_name
from ps_ray.specs.sweep import SweepSpec
from ps_ray.store.atomic import swap_folder, write_text
from ps_ray.store.layout import SweepLayout, sweep_layout


def build_report(spec: SweepSpec, *, progress: bool = True, log_to_mlflow: bool = True) -> Path:
    """Rebuild ``<sweep>/report/`` from the stored results; returns the path of ``index.html``."""
    layout = sweep_layout(spec)
    root = layout.root
    say = print if progress else (lambda *a, **k: None)
    final = layout.report
    partial = final.with_name(f"{final.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    report = Report(partial)
    target = source_target(spec)
    _training(report, root, target, say)
    search_section(report, spec, layout.tune_train)
    if not spec.search.active:  # a search's trials are candidate settings, not sources to compare
        _latent(report, spec, root, say)
    zero_shot_section(report, spec, target, say)
    _few_shot(report, spec, spec.report.few_shot_threshold, say)
    _clips(report, spec, say)
    cost_section(report, spec, root)
    summary_section(report, spec, target)
    write_text(partial / "index.html", render_html(spec, report))
    swap_folder(partial, final)
    if log_to_mlflow:
        log_report(spec, final, report.metrics)
        say(f"report: logged to MLflow run {REPORT_RUN!r} of experiment {spec.name!r}")
    return final / "index.html"


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
    frame = results.curves(SweepLayout(root).tune_train)
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
    report.headline.steps = numbers
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
    report.headline.sources = sources
    say(
        f"report: training curves of {frame['run'].nunique()} runs "
        f"({int(sources['below_target'].sum())} below the {target:.2f} target)"
    )


def _latent(report: Report, spec: SweepSpec, root: Path, say) -> None:
    from ps_ray.stitching.zoo import ModuleZoo

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
    except UserError:
        section.intro = "No trained modules yet."
        return
    entries = [e for e in zoo if e.stage == "train"]
    unswitched = [str(e.key) for e in entries if not e.signature.stitchable]
    if unswitched:  # their cut is still the raw latent: not comparable with the finished sources'
        entries = [e for e in entries if e.signature.stitchable]
        section.intro += (
            f" Left out: {', '.join(unswitched)}, whose runs did not finish, so their relative "
            f"projection (deferred until a run's end) was never switched on."
        )
    probes: dict[str, latent.Probes] = {}

    def probes_for(task) -> latent.Probes:
        name = short_name(task)
        if name not in probes:
            probes[name] = latent.probe_states(
                task, spec.report.probes_per_group, reset_seeds.fixed("probes", spec.report.seed)
            )
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
    report.headline.collapsed = spreads.groupby("method")["collapsed"].sum()
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
    report.headline.alignment = distances
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


def zero_shot_section(report: Report, spec: SweepSpec, target: float, say) -> None:
    table = results.zero_shot_results(sweep_layout(spec).zero_shot_table)
    if table is None:
        return
    if not _has_object(table["task"]):  # reach: nothing to touch, so touching means nothing
        table = table.assign(touching_mean=float("nan"), touching_std=float("nan"))
    section = report.section(
        "Zero-shot stitching",
        "Stitched policies (task module of one "
        "robot-task pair, robot module of another) in their target env "
        "without training: touching and success, mean ± std over repeats "
        "and seeds, identical evaluation episodes for every method. A pair reads "
        "'t: X-Ra & r: Y-Rb': the task module trained on task X with robot Ra, the robot module on "
        "task Y with robot Rb, run on task X with robot Rb.",
    )
    report.table(
        section,
        "zero_shot",
        "Zero-shot results (Table 1 layout)",
        tables.zero_shot_table(table),
        numbers=tables.pool_seeds(table),
    )
    paper = tables.paper_zero_shot(table)
    if paper is not None:
        caption = (
            "The paper's figures beside ours (its Table 1: 200 x 5 episodes; ours as above). Best "
            "unstitched: the better of the pair's two sources as they are in the target env, which "
            "the paper does not report; a stitch below it transferred nothing its sources lacked"
        )
        report.table(section, "zero_shot_paper", caption, paper)
    sources = report.headline.sources
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
        "Per method over (pair, seed) cells: mean with a t interval over per-seed means (95%), and the IQM",
        tables.estimates_text(numbers),
        numbers=numbers,
    )
    report.headline.zero_shot = numbers
    for method, row in numbers.iterrows():
        for metric in ("success", "touching"):
            for stat in ("mean", "mean_lo", "mean_hi", "iqm"):
                if f"{metric}_{stat}" in row:
                    name = metric if stat == "mean" else f"{metric}_{stat}"
                    report.metrics[f"zero_shot.{method}.{name}"] = float(row[f"{metric}_{stat}"])
    report.figure(section, "zero_shot", lambda p: plots.zero_shot_bars(tables.pool_seeds(table), p))
    if transfer.has_controls(table):
        episodes = spec.zero_shot.episodes * spec.zero_shot.repeats
        transfer_section(report, table, episodes, touching=_has_object(table["task"]))
    say(f"report: zero-shot table of {len(table)} stitched pairs")


def _has_object(tasks: pd.Series) -> bool:
    """Whether any of these tasks (spec text, ``{"goal_region": "east", "name": "reach"}``, or
    a short name of an older table, ``reach{"goal_region":"east"}``) moves an object (push, pick:
    touching means something; the markers are not moved)."""
    from ps_ray.envs.tasks import resolve_task

    names = {str(parse_spec_text(str(t)).name).split("{")[0].split("#")[0] for t in tasks.unique()}
    return any(resolve_task(name).has_object for name in names)


def _few_shot(report: Report, spec: SweepSpec, threshold: float, say) -> None:
    layout = sweep_layout(spec)
    frame = results.curves(layout.tune_few_shot)
    if frame.empty:
        return
    section = report.section(
        "Few-shot fine-tuning",
        "Stitched policies fine-tuned in their target env (after a collection phase without updates, "
        "then critic-only updates with the actor frozen) beside each pair's robot source fine-tuned "
        "as it is (unstitched) and the same env trained from scratch: greedy success vs env steps, "
        "mean over seeds (a seed's runs averaged first; a run stopped at its target keeps its last "
        "success) with a 95% t interval over seeds. Where the sweep asks for the halves "
        "(few_shot.halves): the pair's robot module under a fresh task module (robot_module) and "
        "its task module over a fresh robot module (task_module). Grey lines: the target envs' "
        "task-blind floor and oracle from the zero-shot table (same seed), where it has them.",
    )
    title = "few-shot: greedy success in the target envs"
    seed_table = transfer.seed_curves(frame)
    levels = transfer.few_shot_references(frame, results.zero_shot_results(layout.zero_shot_table))
    report.figure(
        section,
        "few_shot_curves",
        lambda p: plots.seed_interval_curves(seed_table, title=title, path=p, references=levels),
    )
    frame["target"] = frame["robot"] + " / " + frame["task"]
    frame["line"] = frame["kind"] + ": " + frame["method"]
    final = results.final_success(frame)
    summary = final.groupby(["target", "line"])["success"].mean().unstack("line")
    report.table(
        section, "few_shot_final", "Final greedy success per target env", summary.round(3), numbers=summary
    )
    report.table(
        section,
        "few_shot_steps",
        f"Env steps to {threshold} greedy success per start (report.few_shot_threshold), paired with scratch",
        transfer.few_shot_steps(frame, threshold),
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
