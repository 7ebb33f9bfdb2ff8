"""A search's trials read back (:mod:`ps_ray.specs.search`): each drawn setting with its curve,
the env steps and core-hours it took to reach greedy success 0.5 and 0.9, and how it ended (ran
out, reached the target, or stopped by ASHA at a rung). The report's "Search" section."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd

from ps_ray.analysis.plots import search_curves
from ps_ray.specs.modes import Scheduler
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.trial import TrainTrial
from ps_ray.store.attempts import PARAMS_FILE, STOPPED, UNFINISHED, outcomes, read_rows

LEVELS = (0.5, 0.9)  # greedy success levels whose first crossing the table gives
CURVE_KEYS = ("eval_success", "best_eval_success", "alpha", "entropy")


def trial_rows(spec: SweepSpec, stage_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(one row per trial: its setting, first env steps at each of :data:`LEVELS`, best and final
    greedy success, how it ended, env steps and core-hours; the curves, one row per result)."""
    cpus = spec.resources.train.cpu
    rows, curves = [], []
    configs = {}
    for folder in sorted(Path(stage_dir).glob(f"*/{PARAMS_FILE}")):
        trial = json.loads(folder.read_text())["trial"]
        configs[json.dumps(trial, sort_keys=True)] = trial
    for outcome in outcomes(Path(stage_dir), "trial", list(configs.values())):
        trial = TrainTrial.of(outcome.config["trial"])
        name = trial.label or trial.run_name
        merged = outcome.rows
        for row in merged:
            curves.append(
                {"setting": name, "env_steps": row.get("env_steps"), **{k: row.get(k) for k in CURVE_KEYS}}
            )
        evals = [(r["env_steps"], r["eval_success"]) for r in merged if r.get("eval_success") is not None]
        last = outcome.metrics
        wall = sum(max((r.get("wall_s") or 0 for r in read_rows(f)), default=0) for f in outcome.attempts)
        record = {"setting": name, **{k: getattr(trial.spec, k) for k in spec.search.space}}
        for level in LEVELS:
            record[f"env_steps_to_{level}"] = next((s for s, v in evals if v >= level), math.nan)
        record.update(
            best_eval=max((v for _, v in evals), default=math.nan),
            final_success=last.get("final_success", math.nan),
            ended=_ended(outcome, last),
            env_steps=last.get("env_steps", math.nan),
            core_hours=wall * cpus / 3600,
        )
        rows.append(record)
    table = pd.DataFrame(rows)
    if not table.empty:
        table = table.sort_values(["final_success", "best_eval"], ascending=False, na_position="last")
    return table.reset_index(drop=True), pd.DataFrame(curves)


def _ended(outcome, last: dict) -> str:
    if outcome.error:
        return "did not finish" if outcome.error == UNFINISHED else "failed"
    if last.get(STOPPED):
        return f"stopped by ASHA at {int(last['env_steps']):,}"
    return "reached the target" if last.get("converged") else "ran its budget"


def search_section(report, spec: SweepSpec, stage_dir: Path) -> None:
    """The report's "Search" section: the trials' table (best first) and their curves."""
    if not spec.search.active:
        return
    table, curves = trial_rows(spec, stage_dir)
    section = report.section(
        "Search",
        f"{spec.search.samples} training settings drawn by Ray Tune's random search (seed "
        f"{spec.search.seed}); {_scheduler_words(spec)}. Env steps to a level: the first "
        f"evaluation at or above it. Final: fresh episodes after the run (none for a stopped trial).",
    )
    if table.empty:
        section.intro = "No search trials yet."
        return
    report.figure(section, "search_curves", lambda p: search_curves(curves, p))
    report.table(section, "search_trials", "Every drawn setting, best first", table.set_index("setting"))
    best = table.iloc[0]
    for key in ("best_eval", "final_success"):
        report.metrics[f"search_best_{key}"] = float(best[key])


def _scheduler_words(spec: SweepSpec) -> str:
    search = spec.search
    if search.scheduler == Scheduler.NONE:
        return "every trial ran its budget"
    cap = max(t.env_steps for t in spec.trials())
    rungs = ", ".join(f"{r:,}" for r in search.rungs(cap))
    return (
        f"Tune's ASHA stopped a trial whose {search.metric} was in the bottom "
        f"{search.reduction_factor - 1}/{search.reduction_factor} at {rungs} env steps"
    )
