"""A stage's MLflow run: the parent of the stage's runs, open while the stage runs and closed
with its summary metrics (:func:`open_stage`)."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from ps_ray.store.mlflow_values import _chunks, finite_float, metric_name
from ps_ray.store.tracking import (
    MAX_METRICS_PER_CALL,
    PARENT_TAG,
    STAGE_RUN_TAG,
    STAGE_TAG,
    _client,
    _first_line,
    code_tags,
)

log = logging.getLogger(__name__)


class StageRun:
    """The MLflow run of one stage of a sweep, the parent of the stage's runs: made when the
    stage first starts, found again (by :data:`STAGE_RUN_TAG`) and set RUNNING on a resume, and
    ended by :func:`open_stage` when the stage ends, with the summary metrics :meth:`record`
    gave it. Its duration is the stage's: from its first start to its last end."""

    def __init__(self, tracking_uri: str, experiment_id: str, sweep: str, stage: str) -> None:
        self.client = _client(tracking_uri)
        self.sweep, self.stage = sweep, stage
        self.metrics: dict[str, float] = {}
        self.status: str | None = None
        found = _find(self.client, experiment_id, stage)
        if found:
            self.run_id = found[0].info.run_id
            if found[0].info.status != "RUNNING":
                self.client.update_run(self.run_id, status="RUNNING")
        else:
            run_tags = {"ps_ray.sweep": sweep, STAGE_RUN_TAG: stage, **code_tags()}
            self.run_id = self.client.create_run(experiment_id, run_name=stage, tags=run_tags).info.run_id

    @property
    def tags(self) -> dict[str, str]:
        """The tags every run of the stage carries: the sweep, the stage, the source, and this
        run as its parent."""
        return {"ps_ray.sweep": self.sweep, STAGE_TAG: self.stage, **code_tags(), PARENT_TAG: self.run_id}

    def record(self, metrics: Mapping[str, Any], status: str = "FINISHED") -> None:
        """The stage's summary metrics and how it ended, written when it closes."""
        self.metrics.update({metric_name(k): v for k, v in metrics.items() if finite_float(v) is not None})
        self.status = status

    def close(self, status: str) -> None:
        _end(self.client, self.run_id, self.metrics, status)


def _end(client, run_id: str, metrics: Mapping[str, Any], status: str) -> None:
    """Write a stage run's summary metrics and end it now with ``status``."""
    from mlflow.entities import Metric

    stamp = int(time.time() * 1000)
    rows = [Metric(k, float(v), stamp, 0) for k, v in metrics.items()]
    for chunk in _chunks(rows, MAX_METRICS_PER_CALL):
        client.log_batch(run_id, metrics=chunk)
    client.set_terminated(run_id, status=status, end_time=stamp)


def _find(client, experiment_id: str, stage: str) -> list:
    """The stage's run (the oldest, if a race ever made two), as a list of at most one."""
    from mlflow.entities import ViewType

    return client.search_runs(
        [experiment_id],
        filter_string=f"tags.`{STAGE_RUN_TAG}` = '{stage}'",
        run_view_type=ViewType.ACTIVE_ONLY,
        order_by=["attributes.start_time ASC"],
        max_results=1,
    )


def close_left_open(tracking_uri: str, experiment_id: str, stage: str, metrics: Mapping[str, Any]) -> bool:
    """A stage run a kill left open (RUNNING, or KILLED) whose stage, resumed, had nothing left to
    run: closed FINISHED with its summary. False where there is none, or it is closed already."""
    client = _client(tracking_uri)
    found = _find(client, experiment_id, stage)
    if not found or found[0].info.status == "FINISHED":
        return False
    summary = {metric_name(k): v for k, v in metrics.items() if finite_float(v) is not None}
    _end(client, found[0].info.run_id, summary, "FINISHED")
    return True


@contextmanager
def open_stage(tracking_uri: str, experiment_id: str, sweep: str, stage: str) -> Iterator[StageRun]:
    """The stage's run, open while the block runs: closed as :meth:`StageRun.record` said (else
    FINISHED), or KILLED on Ctrl-C and FAILED on an error that came before any record."""
    run = StageRun(tracking_uri, experiment_id, sweep, stage)
    try:
        yield run
    except KeyboardInterrupt:
        _closing(run, run.status or "KILLED")
        raise
    except BaseException:
        _closing(run, run.status or "FAILED")
        raise
    _closing(run, run.status or "FINISHED")


def _closing(run: StageRun, status: str) -> None:
    try:
        run.close(status)
    except Exception as e:  # noqa: BLE001 - bookkeeping must not hide the stage's own outcome
        log.warning("MLflow: could not close the %s stage's run: %s", run.stage, _first_line(e))
