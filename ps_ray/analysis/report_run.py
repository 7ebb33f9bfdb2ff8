"""The report's MLflow run: one per sweep, holding the report folder, the headline numbers, the
resolved sweep spec (``sweep/``) and ``runs.json``, an index of every run of the sweep with the
links between stitched pairs and their sources."""

from __future__ import annotations

from pathlib import Path

from ps_ray.specs.sweep import SweepSpec
from ps_ray.store.layout import SweepLayout

REPORT_RUN = "report"  # the MLflow run's trial key


def log_report(spec: SweepSpec, report_dir: Path, metrics: dict[str, float]) -> str:
    """One run per sweep (found again by its key), holding the report folder and headline
    numbers; a rebuild overwrites the same artifacts. Returns the run id."""
    from ps_ray.store.layout import sweep_layout
    from ps_ray.store.tracking import (
        STAGE_TAG,
        TrialTracker,
        code_tags,
        default_tracking_uri,
        ensure_experiment,
    )

    root = sweep_layout(spec).root
    uri = spec.tracking_uri or default_tracking_uri(root)
    experiment = ensure_experiment(uri, spec.name, SweepLayout(root).artifacts)
    tracker = TrialTracker(
        uri,
        experiment,
        REPORT_RUN,
        params={"sweep": spec.name},
        tags={STAGE_TAG: "report", "ps_ray.sweep": spec.name, **code_tags()},
    )
    tracker.log_metrics(metrics, step=0)
    for path in sorted(report_dir.iterdir()):
        tracker.log_artifact(path)
    spec_file = SweepLayout(root).spec_file  # the resolved sweep spec the stages ran (base merged)
    if spec_file.is_file():
        tracker.log_artifact(spec_file, "sweep")
    tracker.log_dict(_run_index(tracker.client, experiment, tracker.run_id), "runs.json")
    tracker.close()
    return tracker.run_id


def _run_index(client, experiment_id: str, report_run: str) -> dict[str, dict[str, dict[str, str]]]:
    """Every run the report summarises, by stage and trial key: its run id, and for a stitched
    policy the runs of its two sources (``runs.json`` in the report run)."""
    from ps_ray.store.tracking import ROBOT_SOURCE_RUN_TAG, STAGE_TAG, TASK_SOURCE_RUN_TAG, TRIAL_KEY_TAG

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
