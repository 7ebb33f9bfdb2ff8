"""Stored results of a sweep, read back without Ray: Tune trial folders and the zero-shot table.

A Tune trial folder holds ``params.json`` (the trial config) and ``result.json`` (one JSON result
per line); a trial relaunched by a resume has several such folders (:mod:`ps_ray.store.attempts`).
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from ps_ray.specs.names import short_name, trial_key
from ps_ray.specs.train import TrainSpec
from ps_ray.stitching.pair_table import read_table
from ps_ray.store.attempts import PARAMS_FILE, attempts, merged_rows

CURVE_COLUMNS = [
    "run",
    "kind",
    "label",
    "method",
    "robot",
    "task",
    "seed",
    "interface_dim",
    "env_steps",
    "success",
]


def curves(stage_dir: Path) -> pd.DataFrame:
    """Greedy success vs env steps of every trial in a Tune stage folder (``tune``,
    ``tune_few_shot``): the periodic evaluations, then the final evaluation at the last step."""
    records = []
    for folders in attempts(stage_dir, "trial").values():
        trial = json.loads((folders[-1] / PARAMS_FILE).read_text())["trial"]
        rows = merged_rows(folders)
        if "population" in trial:  # each member a run of its own, up to its stop
            for index, member in enumerate(trial["population"]):
                records += _points(member, rows, f"c{index:02d}_")
        else:
            records += _points(trial, rows)
    frame = pd.DataFrame(records, columns=CURVE_COLUMNS)
    # a final evaluation at the step of a periodic one replaces it (more episodes)
    return frame.drop_duplicates(["run", "env_steps"], keep="last").reset_index(drop=True)


def _points(trial: dict, rows: list[dict], member: str = "") -> list[dict]:
    """One source's curve points from its trial's rows (``member``: a population member's
    prefix, ``c00_``: its own evaluations, up to the step it stopped at)."""
    spec = TrainSpec.upgrade(trial["spec"])  # a trial stored before the method menu names an old row
    run = trial.get("key") or trial_key(spec)
    fields = {
        "run": run,
        "kind": trial.get("kind", "train"),
        "label": trial.get("label", run),
        "method": spec["method"],
        "robot": short_name(spec["robot"]),
        "task": short_name(spec["task"]),
        "seed": spec["seed"],
        "interface_dim": spec["interface_dim"],
    }
    final = next((r for r in reversed(rows) if r.get(f"final_{member}success") is not None), {})
    stop = final.get(f"final_{member}env_steps", final.get("env_steps"))
    points = []
    for row in rows:
        periodic, last = row.get(f"eval_{member}success"), row.get(f"final_{member}success")
        if periodic is not None and (stop is None or not member or row["env_steps"] <= stop):
            points.append({**fields, "env_steps": row["env_steps"], "success": periodic})
        if last is not None:  # a member's final figures are from its stop
            points.append({**fields, "env_steps": stop if member else row["env_steps"], "success": last})
    return points


def final_success(curves_frame: pd.DataFrame) -> pd.DataFrame:
    """The last point of every run."""
    return curves_frame.sort_values("env_steps").groupby("run", sort=True).tail(1)


def zero_shot_results(path: Path) -> pd.DataFrame | None:
    """``zero_shot.csv`` of a sweep (its pairs in the matrix's order) sorted by method, pairing,
    seed and label, as the report shows it; None when the stage has not run."""
    table = read_table(path)
    return (
        None
        if table is None
        else table.sort_values(["method", "pairing", "seed", "label"]).reset_index(drop=True)
    )
