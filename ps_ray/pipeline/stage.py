"""What every stage of the pipeline shares: Ray and the
sweep's MLflow experiment (:func:`connect`), the check that a folder keeps one sweep's work
(:func:`require_same_sweep`), and a stage's failed trials as one error (:func:`raise_on_errors`)."""

from __future__ import annotations

from ps_ray.specs.sweep import SweepSpec, load_stored_sweep
from ps_ray.specs.train import require_same
from ps_ray.store.layout import sweep_layout


def require_same_sweep(spec: SweepSpec) -> None:
    """A folder that holds a sweep's work keeps it: a spec with other training settings is refused
    before anything is written, resumed or not, so two experiments never mix. A folder that holds
    only the spec of a start that failed early (no trial, no anchor set) takes the new spec."""

    from ps_ray.store.attempts import attempts

    layout = sweep_layout(spec)
    spec_file = layout.spec_file
    holds_work = (
        attempts(layout.tune_train, "trial")
        or attempts(layout.tune_plain, "trial")
        or attempts(layout.tune_grid, "trial")
        or any(layout.anchors.glob("*.npz"))
    )
    if spec_file.exists() and holds_work:
        stored = load_stored_sweep(spec_file)
        require_same(
            stored.training_identity(),
            spec.training_identity(),
            f"{sweep_layout(spec).root} was trained from a different sweep spec",
            "resume with the same training settings, or give the sweep another name or storage",
        )


def record_spec(spec: SweepSpec) -> None:
    """Write the spec into its sweep folder (made if missing), where every later command and stage
    finds it: a stage that trains (train, grid) does so once ``require_same_sweep`` has passed."""
    import yaml

    from ps_ray.store.atomic import write_text

    layout = sweep_layout(spec)
    layout.root.mkdir(parents=True, exist_ok=True)
    write_text(layout.spec_file, yaml.safe_dump(spec.to_dict(), sort_keys=True))


# how to read the experiment, below its sweep's description
READING = (
    "Runs nest under their stage (train, grid, zero_shot, few_shot, report). A training run's "
    "step is its env steps: read its curves with the x axis on Step. A stitched pair's run holds "
    "its success beside its controls (robot_source, task_source, chance, task_blind, oracle) and "
    "names its two sources' runs."
)


def connect(spec: SweepSpec) -> tuple[str, str]:
    """Join (or start) Ray and open the sweep's MLflow experiment: (tracking URI, experiment id).

    The driver creates the store and experiment once, before any trial could race for it."""
    from ps_ray.rllib.ray_start import cluster_address, init_ray

    with _quiet(spec):  # Ray's start-up messages
        init_ray(cluster_address() or "local")
    return open_tracking(spec)


def open_tracking(spec: SweepSpec) -> tuple[str, str]:
    """The sweep's MLflow experiment, without Ray: (tracking URI, experiment id); MLflow's
    start-up messages go to the sweep's driver log."""
    from ps_ray.store.tracking import default_tracking_uri, ensure_experiment

    where = sweep_layout(spec)
    with _quiet(spec):
        tracking_uri = spec.tracking_uri or default_tracking_uri(where.root)
        note = f"{spec.description}\n\n{READING}" if spec.description else READING
        return tracking_uri, ensure_experiment(tracking_uri, spec.name, where.artifacts, note)


def _quiet(spec: SweepSpec):
    from ps_ray.store.layout import LOG_FOLDER
    from ps_ray.store.terminal import others_to

    return others_to(sweep_layout(spec).root / LOG_FOLDER / "driver.log")


class StageError(RuntimeError):
    """Trials of a stage failed; the message names how many and the first error."""


class StageInterrupted(StageError):
    """A stage was stopped (Ctrl-C) before all its trials finished and none
    failed: what finished is kept, and a resume runs the rest."""


def raise_on_errors(outcomes, what: str) -> None:
    """StageError if any trial failed; StageInterrupted if none failed but some did not finish
    (``outcomes``: :func:`ps_ray.store.attempts.outcomes` of a stage's trials)."""
    from ps_ray.store.attempts import UNFINISHED

    unfinished = [r for r in outcomes if r.error]
    failed = [r for r in unfinished if r.error != UNFINISHED]
    if failed:
        raise StageError(f"{len(failed)} of {len(outcomes)} {what} failed: {failed[0].error}")
    if unfinished:
        done, total = len(outcomes) - len(unfinished), len(outcomes)
        raise StageInterrupted(f"interrupted: {done} of {total} {what} finished, {len(unfinished)} not")
