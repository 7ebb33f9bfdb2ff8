"""MLflow tracking: one run per trial key, batched metrics. No Ray here: a report is built and
logged without loading it; the driver-side Tune callback is in :mod:`ps_ray.pipeline.tune_tracking`.

Only the process that calls these functions touches the MLflow store; in a sweep that is the
Tune driver, never the trial workers. The store is a sqlite file
(``default_tracking_uri``); ``ensure_experiment`` creates it and the experiment once, before any
other process could race to create the same fresh database.

A run is found again by its tag ``ps_ray.trial_key``, not by an in-memory map: a trial resumed
after a driver restart, or a second ``TrialTracker`` with the same key, continues the same run.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import subprocess
import tempfile
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ps_ray.errors import UserError
from ps_ray.store.mlflow_values import _chunks, finite_float, flatten_params, metric_name, same_param

if TYPE_CHECKING:
    from mlflow import MlflowClient
    from mlflow.entities import Metric

log = logging.getLogger(__name__)

TRIAL_KEY_TAG = "ps_ray.trial_key"
STAGE_TAG = "ps_ray.stage"
# A stage's runs are the children of one run per stage (MLflow's own nesting tag), so the UI lists
# the stages, each unfolding into its trials; the stage run is found again by its own tag.
PARENT_TAG, STAGE_RUN_TAG = "mlflow.parentRunId", "ps_ray.stage_run"
# a stitched policy's run names its sources' trial keys and MLflow runs, and its anchor set
TASK_SOURCE_TAG, ROBOT_SOURCE_TAG = "ps_ray.task_module", "ps_ray.robot_module"
TASK_SOURCE_RUN_TAG, ROBOT_SOURCE_RUN_TAG = "ps_ray.task_module_run", "ps_ray.robot_module_run"
ANCHOR_HASH_TAG = "ps_ray.anchor_hash"
GIT_COMMIT_TAG = "mlflow.source.git.commit"  # MLflow's own source tags, which its UI shows
EXPERIMENT_KIND = {"mlflow.experimentKind": "custom_model_development"}  # the UI opens on the runs
MAX_METRICS_PER_CALL = 1000  # mlflow.utils.validation.MAX_METRICS_PER_BATCH
MAX_PARAMS_TAGS_PER_CALL = 100  # mlflow.utils.validation.MAX_PARAMS_TAGS_PER_BATCH
MAX_TAG_CHARS = 8000  # mlflow.utils.validation.MAX_TAG_VAL_LENGTH
TERMINAL_STATUSES = ("FINISHED", "FAILED", "KILLED")


# ---------------------------------------------------------------------------------- store


def default_tracking_uri(root: str | Path) -> str:
    """The sqlite store of a project root: ``sqlite:////abs/root/mlflow.db``."""
    from ps_ray.store.layout import SweepLayout

    return f"sqlite:///{SweepLayout(Path(root).expanduser().resolve()).mlflow_db}"


# The stores MLflow 3 writes to: its server, and databases through SQLAlchemy (file stores are
# frozen in MLflow 3 and refused).
TRACKING_SCHEMES = ("http", "https", "databricks", "sqlite", "postgresql", "mysql", "mssql")


def check_tracking_uri(uri: str) -> None:
    """A tracking URI MLflow can write to, checked before anything is made; else one line."""
    scheme = uri.split(":", 1)[0].split("+", 1)[0].lower() if ":" in uri else ""
    if scheme not in TRACKING_SCHEMES:
        raise UserError(
            f"tracking_uri {uri!r}: not an MLflow tracking store; valid: http(s)://HOST:PORT (a "
            f"tracking server), sqlite:///PATH, postgresql://..., mysql://..., mssql://..., databricks"
        )


def _client(tracking_uri: str) -> MlflowClient:
    from mlflow import MlflowClient

    return MlflowClient(tracking_uri=tracking_uri)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0]


STORE_RETRY_S = 20.0
# the stores' lock files, one per store path, in one folder per user of the temp folder (not
# beside the store: a shared file system may not honour flock); kept, as removing one races its users
LOCK_DIR = Path(tempfile.gettempdir()) / f"ps_ray-locks-{os.getuid()}"


@contextmanager
def _one_maker(db: Path | None) -> Iterator[None]:
    """One ps_ray process of this machine at a time opens a sqlite store here: two that made a new
    store at once could both run MLflow's table migrations, and a migration cut across by the
    other's left the store unusable for good (``table _alembic_tmp_experiments already exists``).
    The lock file lives in :data:`LOCK_DIR`, keyed by the store's path, never beside the store."""
    if db is None:
        yield
        return
    key = hashlib.sha256(str(db.expanduser().resolve()).encode()).hexdigest()[:16]
    LOCK_DIR.mkdir(exist_ok=True)
    with open(LOCK_DIR / f"mlflow-{key}.lock", "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)  # released when the file closes, or the process dies
        yield


NOTE_TAG = "mlflow.note.content"  # an experiment's description in MLflow's UI
DEFAULT_EXPERIMENT = "0"  # MLflow makes it, empty, in every new store


def ensure_experiment(
    tracking_uri: str, name: str, artifact_root: str | Path, description: str | None = None
) -> str:
    """Create (if needed) the store and the experiment ``name`` with its artifacts under
    ``artifact_root`` and its ``description``; returns the experiment id. Idempotent; call it from
    the driver only. A sqlite store's empty Default experiment (its artifacts in a folder that
    never exists) is deleted, so the UI lists the sweep alone."""
    artifact_location = Path(artifact_root).expanduser().resolve().as_uri()
    db = Path(tracking_uri.removeprefix("sqlite:///")) if tracking_uri.startswith("sqlite:///") else None
    # A new sqlite store that another process (`mlflow ui`, a second driver, a script reading runs)
    # opens at the same moment gets its tables made twice: the loser retries, while the file
    # exists, until the winner has made them (at most STORE_RETRY_S).
    deadline = time.monotonic() + STORE_RETRY_S
    while True:
        try:
            if db is not None:
                db.parent.mkdir(parents=True, exist_ok=True)
            with _one_maker(db):  # the store's tables are made on the first call, not by the client
                client = _client(tracking_uri)
                experiment = client.get_experiment_by_name(name)
                if db is not None:
                    _drop_empty_default(client)
                if experiment is None:
                    tags = {**EXPERIMENT_KIND, **({NOTE_TAG: description} if description else {})}
                    return client.create_experiment(name, artifact_location=artifact_location, tags=tags)
            wanted = {**EXPERIMENT_KIND, **({NOTE_TAG: description} if description else {})}
            for key, value in wanted.items():  # an experiment made before the tag existed
                if experiment.tags.get(key) != value:
                    client.set_experiment_tag(experiment.experiment_id, key, value)
            break
        except Exception as e:  # noqa: BLE001 - any failure here means the URI is unusable
            making = db is not None and db.exists() and "not a database" not in str(e)
            if making and time.monotonic() < deadline:
                time.sleep(0.5)
                continue
            raise UserError(f"cannot use MLflow tracking URI {tracking_uri!r}: {_first_line(e)}") from e
    if experiment.artifact_location != artifact_location:
        raise UserError(
            f"MLflow experiment {name!r} in {tracking_uri} keeps artifacts in "
            f"{experiment.artifact_location}, not {artifact_location}"
        )
    if experiment.lifecycle_stage == "deleted":
        client.restore_experiment(experiment.experiment_id)
    return experiment.experiment_id


def _drop_empty_default(client: MlflowClient) -> None:
    """Delete the store's Default experiment while it holds no run (MLflow does not make it again)."""
    default = next((e for e in client.search_experiments() if e.experiment_id == DEFAULT_EXPERIMENT), None)
    if default is not None and not client.search_runs([DEFAULT_EXPERIMENT], max_results=1):
        client.delete_experiment(DEFAULT_EXPERIMENT)


def runs_page(tracking_uri: str, name: str, ui: str = "http://127.0.0.1:5000") -> str | None:
    """The MLflow UI's page of an experiment's runs (``mlflow ui``'s default address). The 3.x UI
    opens an experiment on its GenAI overview unless the page asks for the model-training view
    (``workflowType=machine_learning``); the experiment's own kind tag does not decide it. None
    when the store cannot be read."""
    try:
        experiment = _client(tracking_uri).get_experiment_by_name(name)
    except Exception:  # noqa: BLE001 - a hint printed at the end; never fail a finished run on it
        return None
    return (
        None
        if experiment is None
        else f"{ui}/#/experiments/{experiment.experiment_id}?workflowType=machine_learning"
    )


def code_tags() -> dict[str, str]:
    """MLflow's source tags of a ps_ray run: the command and the commit of the source tree."""
    commit = git_commit()
    tags = {"mlflow.source.name": "ps-ray", "mlflow.source.type": "JOB"}
    return {**tags, GIT_COMMIT_TAG: commit} if commit else tags


def git_commit(cwd: str | Path | None = None) -> str | None:
    """``git rev-parse HEAD`` of ``cwd`` (default: the ps_ray source tree), or None."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=cwd or Path(__file__).parent,
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


# ---------------------------------------------------------------------------------- tracker


class TrialTracker:
    """One MLflow run per trial key; a resumed trial continues its run instead of creating a second.

    The run is looked up by the tag ``ps_ray.trial_key`` in the experiment (the oldest one if a
    race ever made two). A found run is set back to RUNNING and its tags updated; its params must
    agree with ``params`` (MLflow params are immutable), otherwise ValueError names the first
    difference. Metrics are buffered until :meth:`flush` (or 1000 are pending).
    """

    def __init__(
        self,
        tracking_uri: str,
        experiment_id: str,
        trial_key: str,
        *,
        params: Mapping[str, Any],
        tags: Mapping[str, str],
        client: MlflowClient | None = None,
        once_per_step: bool = False,
        name: str | None = None,
        start_ms: int | None = None,
    ) -> None:
        if not trial_key:
            raise ValueError("trial_key must be a non-empty string")
        self.tracking_uri = tracking_uri
        self.experiment_id = experiment_id
        self.trial_key = trial_key
        self.client = client or _client(tracking_uri)
        self._pending: list[Metric] = []
        # once_per_step: per metric, the last step in the run. A trial restarted after a kill
        # re-reports steps it had logged; the first record of a step stays, none is logged twice.
        self.once_per_step = once_per_step
        self._last_step: dict[str, int] = {}
        all_tags = {k: str(v)[:MAX_TAG_CHARS] for k, v in tags.items() if v is not None}
        all_tags[TRIAL_KEY_TAG] = trial_key
        flat = flatten_params(params)
        self.name = self._name(name)
        run = self._find_run()
        if run is None:
            self.run_id = self._create_run(all_tags, start_ms)
            self.resumed = False
        else:
            self.run_id = run.info.run_id
            self.resumed = True
            if run.info.run_name != self.name:  # a run named before the current scheme
                self.client.update_run(self.run_id, name=self.name)
            for key in run.data.metrics if once_per_step else ():
                steps = [m.step for m in self.client.get_metric_history(self.run_id, key)]
                self._last_step[key] = max(steps, default=-1)
            self._check_params(run.data.params, flat)
            flat = {k: v for k, v in flat.items() if k not in run.data.params}
            if run.info.status != "RUNNING":
                self.client.update_run(self.run_id, status="RUNNING")
        self._log_params_tags(flat, all_tags)

    def _find_run(self):
        return find_run(self.client, self.experiment_id, self.trial_key)

    def _name(self, name: str | None) -> str:
        """``name`` (a record's title, :mod:`ps_ray.specs.titles`), or the key as a reader would
        write it (``reach q1``, not JSON); the key itself, exact, is the ``ps_ray.trial_key`` tag."""
        from ps_ray.specs.names import readable
        from ps_ray.specs.titles import MAX_TITLE

        return (name or readable(self.trial_key))[:MAX_TITLE]

    def _create_run(self, tags: Mapping[str, str], start_ms: int | None) -> str:
        run = self.client.create_run(self.experiment_id, start_time=start_ms, run_name=self.name, tags=tags)
        return run.info.run_id

    def _check_params(self, logged: Mapping[str, str], wanted: Mapping[str, str]) -> None:
        for key, value in wanted.items():
            if key in logged and not same_param(logged[key], value):
                raise UserError(
                    f"trial {self.trial_key!r} already has run {self.run_id} with param "
                    f"{key}={logged[key]!r}, not {value!r}; use another trial key"
                )

    def _log_params_tags(self, params: Mapping[str, str], tags: Mapping[str, str]) -> None:
        from mlflow.entities import Param, RunTag

        param_list = [Param(k, v) for k, v in params.items()]
        tag_list = [RunTag(k, v) for k, v in tags.items()]
        for chunk in _chunks(param_list, MAX_PARAMS_TAGS_PER_CALL):
            self.client.log_batch(self.run_id, params=chunk)
        for chunk in _chunks(tag_list, MAX_PARAMS_TAGS_PER_CALL):
            self.client.log_batch(self.run_id, tags=chunk)

    @property
    def pending(self) -> int:
        """Metrics buffered and not yet written."""
        return len(self._pending)

    def log_metrics(self, metrics: Mapping[str, Any], step: int, *, timestamp_ms: int | None = None) -> None:
        """Buffer ``metrics`` at ``step``; None, NaN, infinities and non-numbers are dropped, and so
        is, with ``once_per_step``, a step at or before one the run holds for that metric. Names
        take the characters MLflow allows (:func:`metric_name`)."""
        from mlflow.entities import Metric

        stamp = int(time.time() * 1000) if timestamp_ms is None else timestamp_ms
        for key, value in metrics.items():
            number = finite_float(value)
            if number is None or (self.once_per_step and int(step) <= self._last_step.get(key, -1)):
                continue
            self._pending.append(Metric(metric_name(key), number, stamp, int(step)))
            self._last_step[key] = int(step)
        if len(self._pending) >= MAX_METRICS_PER_CALL:
            self.flush()

    def flush(self) -> None:
        """Write buffered metrics, at most 1000 per ``log_batch`` call; a failed call keeps the rest."""
        while self._pending:
            chunk = self._pending[:MAX_METRICS_PER_CALL]
            self.client.log_batch(self.run_id, metrics=chunk)
            del self._pending[: len(chunk)]

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        """A file goes to ``artifact_path/<name>``; a directory to ``artifact_path/<dirname>/...``."""
        path = Path(path)
        if path.is_dir():
            target = f"{artifact_path}/{path.name}" if artifact_path else path.name
            self.client.log_artifacts(self.run_id, str(path), artifact_path=target)
        elif path.is_file():
            self.client.log_artifact(self.run_id, str(path), artifact_path=artifact_path)
        else:
            raise FileNotFoundError(f"no artifact to log at {path}")

    def log_dict(self, data: dict, artifact_file: str) -> None:
        """``data`` as a JSON (or YAML, by suffix) artifact, e.g. the resolved config."""
        self.client.log_dict(self.run_id, data, artifact_file)

    def close(self, status: str = "FINISHED", end_ms: int | None = None) -> None:
        """Flush and mark the run ``status`` (FINISHED, FAILED or KILLED), ended at ``end_ms``
        (default: now)."""
        if status not in TERMINAL_STATUSES:
            raise ValueError(f"status must be one of {', '.join(TERMINAL_STATUSES)}, got {status!r}")
        self.flush()
        self.client.set_terminated(self.run_id, status=status, end_time=end_ms)


def find_run(client: MlflowClient, experiment_id: str, trial_key: str):
    """The run of a trial key in an experiment (the oldest, if a race ever made two), or None."""
    from mlflow.entities import ViewType

    runs = client.search_runs(
        [experiment_id],
        filter_string=_tag_filter(trial_key),
        run_view_type=ViewType.ACTIVE_ONLY,
        order_by=["attributes.start_time ASC"],
        max_results=10,
    )
    return runs[0] if runs else None


def source_tags(client: MlflowClient, experiment_id: str, task_from: str, robot_from: str, policy) -> dict:
    """Tags linking a stitched policy's run to the training runs of its two sources (by their
    trial keys; a co-trained cell's, to its grid's run) and naming its anchor set (from
    ``policy``, a stitched or source policy file); its description links the two runs by name."""
    from ps_ray.specs.grid import grid_run_of
    from ps_ray.store.signature import read_signature

    tags = {TASK_SOURCE_TAG: task_from, ROBOT_SOURCE_TAG: robot_from}
    links = []
    for key, tag, half in (
        (task_from, TASK_SOURCE_RUN_TAG, "task module"),
        (robot_from, ROBOT_SOURCE_RUN_TAG, "robot module"),
    ):
        run = find_run(client, experiment_id, grid_run_of(key) or key)  # a co-trained cell: its grid's
        if run is not None:
            tags[tag] = run.info.run_id
            page = f"#/experiments/{experiment_id}/runs/{run.info.run_id}"
            links.append(f"the {half} of [{run.info.run_name}]({page})")
    if links:
        tags[NOTE_TAG] = "Stitched from " + " and ".join(links) + "."
    anchor_hash = read_signature(policy)[0].anchor_hash
    if anchor_hash:
        tags[ANCHOR_HASH_TAG] = anchor_hash
    return tags


def _tag_filter(trial_key: str) -> str:
    if "'" not in trial_key:
        return f"tags.`{TRIAL_KEY_TAG}` = '{trial_key}'"
    if '"' not in trial_key:
        return f'tags.`{TRIAL_KEY_TAG}` = "{trial_key}"'
    raise ValueError(f"trial key {trial_key!r} holds both quote characters; MLflow cannot search it")


# ---------------------------------------------------------------------------------- specs
