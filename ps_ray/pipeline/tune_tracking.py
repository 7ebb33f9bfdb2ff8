"""The driver-side Tune callback that logs every trial to MLflow (:mod:`ps_ray.store.tracking`):
one run per trial key, metrics in batches, artifacts and status at the end."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ray.tune import Callback

from ps_ray.store.tracking import (
    GIT_COMMIT_TAG,
    PARENT_TAG,
    TrialTracker,
    _client,
    _first_line,
    git_commit,
)

if TYPE_CHECKING:
    from mlflow import MlflowClient
    from ray.tune.experiment import Trial

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------- Tune


@dataclass(frozen=True)
class MemberRun:
    """A source trained inside a trial (a population's member): its own MLflow run, nested under
    the trial's, logging the trial's per-member columns (``eval_<prefix>success`` as
    ``eval_success``); ``files``: its files in the trial's checkpoint, logged as artifacts."""

    key: str
    name: str
    params: Mapping[str, Any]
    prefix: str  # "c00_"
    files: tuple[str, ...] = ()  # its policy file first
    model: tuple[Any, Any] | None = None  # (robot, task): its policy file logged as a model


MEMBER_COLUMNS = ("train_", "eval_", "final_")  # a member's own figures carry its prefix after these
SHARED_COLUMNS = ("env_steps", "updates")  # every member's, as the trial's


def member_metric(key: str, prefix: str) -> str | None:
    """The trial's column a member's metric ``key`` is read from (None: the member has none)."""
    if key in SHARED_COLUMNS:
        return key
    for head in MEMBER_COLUMNS:
        if key.startswith(head):
            return head + prefix + key[len(head) :]
    return None


def lookup(result: Mapping[str, Any], key: str) -> Any:
    """``result[key]``, or the nested value for ``a/b`` keys (``result["a"]["b"]``); None if absent."""
    if key in result:
        return result[key]
    head, sep, tail = key.partition("/")
    if sep and isinstance(result.get(head), Mapping):
        return lookup(result[head], tail)
    return None


class MLflowTuneCallback(Callback):
    """Driver-side: only the driver process touches the store. Results → batched metrics of the trial's run.

    Each result contributes the whitelisted ``metric_keys`` (nested ``a/b`` keys are looked up in
    the nested result dict, logged under the same name) at step ``result[step_key]`` (default
    ``training_iteration``; e.g. ``num_env_steps_sampled_lifetime`` for env-step curves). A
    trial's metrics are written every ``flush_every`` results or ``flush_secs`` seconds, after
    each checkpoint, and on completion/error/recovery/experiment end. Trackers are keyed by
    ``key_fn(trial)`` and find their run by tag, so a trial restored after a driver restart
    continues the SAME run, named ``name_fn(trial)`` (default: the key as a reader writes it).
    Errors while writing metrics, artifacts or status are logged as warnings, never raised into
    Tune: a sweep does not die for its bookkeeping (unflushed metrics are retried at the next
    flush). Finding or creating a trial's run does raise (e.g. its key's run has other params).
    ``model_fn(trial)``: a finished trial's (policy file, robot, task, title), logged as the run's
    MLflow model (:mod:`ps_ray.pipeline.policy_models`), or None.
    """

    def __init__(
        self,
        tracking_uri: str,
        experiment_id: str,
        *,
        metric_keys: Sequence[str],
        params_fn: Callable[[Trial], Mapping[str, Any]],
        key_fn: Callable[[Trial], str],
        name_fn: Callable[[Trial], str] | None = None,
        tags: Mapping[str, str] | None = None,
        tags_fn: Callable[[Trial, MlflowClient], Mapping[str, str]] | None = None,
        flush_every: int = 20,
        artifacts_fn: Callable[[Trial], list[Path]] | None = None,
        model_fn: Callable[[Trial], tuple[Path, Any, Any, str] | None] | None = None,
        step_key: str = "training_iteration",
        flush_secs: float = 60.0,
        once_per_step: bool = False,
        members_fn: Callable[[Trial], Sequence[MemberRun]] | None = None,
    ) -> None:
        if flush_every < 1:
            raise ValueError(f"flush_every must be >= 1, got {flush_every}")
        self.tracking_uri = tracking_uri
        self.experiment_id = experiment_id
        self.metric_keys = tuple(metric_keys)
        self.params_fn = params_fn
        self.key_fn = key_fn
        self.name_fn = name_fn
        self.tags = dict(tags or {})
        self.tags_fn = tags_fn
        if GIT_COMMIT_TAG not in self.tags and (commit := git_commit()):
            self.tags[GIT_COMMIT_TAG] = commit
        self.flush_every = flush_every
        self.flush_secs = flush_secs
        self.artifacts_fn = artifacts_fn
        self.model_fn = model_fn
        self.step_key = step_key
        self.once_per_step = once_per_step
        self.members_fn = members_fn
        self._members: dict[str, list[tuple[MemberRun, TrialTracker]]] = {}  # trial key -> its members'
        self._trackers: dict[str, TrialTracker] = {}
        self._results: dict[str, int] = {}
        self._last_flush: dict[str, float] = {}
        self._client_cache: MlflowClient | None = None

    # Tuner.restore unpickles the callback from the experiment state: keep no store handles there.
    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.update(_trackers={}, _members={}, _results={}, _last_flush={}, _client_cache=None)
        return state

    @property
    def _client(self) -> MlflowClient:
        if self._client_cache is None:
            self._client_cache = _client(self.tracking_uri)
        return self._client_cache

    def tracker(self, trial: Trial) -> TrialTracker:
        """The trial's tracker, creating (or finding again) its run on first use."""
        key = self.key_fn(trial)
        if key not in self._trackers:
            tags = {**self.tags, "ps_ray.tune_trial_id": trial.trial_id}
            if self.tags_fn is not None:
                tags.update(self.tags_fn(trial, self._client))
            self._trackers[key] = TrialTracker(
                self.tracking_uri,
                self.experiment_id,
                key,
                params=self.params_fn(trial),
                tags=tags,
                client=self._client,
                once_per_step=self.once_per_step,
                name=self.name_fn(trial) if self.name_fn else None,
            )
            self._results[key] = 0
            self._last_flush[key] = time.monotonic()
            self._members[key] = [
                (m, self._member_tracker(m, self._trackers[key], trial)) for m in self._member_runs(trial)
            ]
        return self._trackers[key]

    def _member_runs(self, trial: Trial) -> Sequence[MemberRun]:
        return self.members_fn(trial) if self.members_fn is not None else ()

    def _member_tracker(self, member: MemberRun, parent: TrialTracker, trial: Trial) -> TrialTracker:
        tags = {**self.tags, "ps_ray.tune_trial_id": trial.trial_id, PARENT_TAG: parent.run_id}
        return TrialTracker(
            self.tracking_uri,
            self.experiment_id,
            member.key,
            params=member.params,
            tags=tags,
            client=self._client,
            once_per_step=self.once_per_step,
            name=member.name,
        )

    def run_id(self, trial: Trial) -> str:
        return self.tracker(trial).run_id

    def on_trial_start(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        self.tracker(trial)

    def on_trial_result(
        self, iteration: int, trials: list[Trial], trial: Trial, result: dict, **info: Any
    ) -> None:
        tracker = self.tracker(trial)
        step = lookup(result, self.step_key)
        stamp = result.get("timestamp")
        tracker.log_metrics(
            {k: lookup(result, k) for k in self.metric_keys},
            step=int(step) if step is not None else self._results[tracker.trial_key],
            timestamp_ms=int(stamp * 1000) if stamp else None,
        )
        key = tracker.trial_key
        for member, member_tracker in self._members[key]:
            columns = {k: c for k in self.metric_keys if (c := member_metric(k, member.prefix)) is not None}
            if all(lookup(result, c) is None for c in columns.values() if c not in SHARED_COLUMNS):
                continue  # none of its own figures: it has stopped (its final ones come last)
            # a member's final figures are those of the step it stopped at
            stopped = lookup(result, f"final_{member.prefix}env_steps")
            member_tracker.log_metrics(
                {k: lookup(result, c) for k, c in columns.items()},
                step=int(stopped) if stopped is not None else int(step) if step is not None else 0,
                timestamp_ms=int(stamp * 1000) if stamp else None,
            )
        self._results[key] += 1
        due = time.monotonic() - self._last_flush[key] >= self.flush_secs
        if self._results[key] % self.flush_every == 0 or due:
            self._flush(tracker)

    def on_checkpoint(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        """What a checkpoint holds is in the store: a driver killed after it loses no metric that
        the resumed trial does not report again (it re-reports only the steps after it)."""
        key = self.key_fn(trial)
        if key in self._trackers:
            self._flush(self._trackers[key])

    def on_trial_recover(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        key = self.key_fn(trial)
        if key in self._trackers:
            self._flush(self._trackers[key])

    def on_trial_complete(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        tracker = self.tracker(trial)
        if self.artifacts_fn is not None:
            for path in self.artifacts_fn(trial):
                self._guard(f"log artifact {path}", tracker.log_artifact, path)
        model = self.model_fn(trial) if self.model_fn is not None else None
        if model is not None:  # (policy file, robot, task, the run's title)
            from ps_ray.pipeline.policy_models import log_policy_model

            self._guard(
                "log the policy as a model", log_policy_model, self.tracking_uri, tracker.run_id, *model
            )
        folder = Path(trial.checkpoint.path) if trial.checkpoint is not None else None
        for member, member_tracker in self._members.get(tracker.trial_key, ()):
            for name in member.files if folder is not None else ():
                if (folder / name).exists():
                    self._guard(f"log artifact {name}", member_tracker.log_artifact, folder / name)
            if member.model is not None and folder is not None and (folder / member.files[0]).exists():
                from ps_ray.pipeline.policy_models import log_policy_model

                policy = folder / member.files[0]
                args = (self.tracking_uri, member_tracker.run_id, policy, *member.model, member.name)
                self._guard("log the policy as a model", log_policy_model, *args)
        self._close(trial, "FINISHED")

    def on_trial_error(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        self._close(trial, "FAILED")

    def on_experiment_end(self, trials: list[Trial], **info: Any) -> None:
        """Trials still open (interrupted) are flushed and marked KILLED; a resume reopens them."""
        for key in list(self._trackers):
            for _, member_tracker in self._members.pop(key, ()):
                self._guard(f"close run of {member_tracker.trial_key}", member_tracker.close, "KILLED")
            self._guard(f"close run of {key}", self._trackers.pop(key).close, "KILLED")

    def _flush(self, tracker: TrialTracker) -> None:
        for _, member_tracker in self._members.get(tracker.trial_key, ()):
            self._guard(f"flush metrics of {member_tracker.trial_key}", member_tracker.flush)
        self._guard(f"flush metrics of {tracker.trial_key}", tracker.flush)
        self._last_flush[tracker.trial_key] = time.monotonic()

    def _close(self, trial: Trial, status: str) -> None:
        tracker = self.tracker(trial)
        del self._trackers[tracker.trial_key]
        for _, member_tracker in self._members.pop(tracker.trial_key, ()):
            self._guard(f"close run of {member_tracker.trial_key}", member_tracker.close, status)
        self._guard(f"close run of {tracker.trial_key}", tracker.close, status)

    @staticmethod
    def _guard(what: str, fn: Callable[..., None], *args: Any) -> None:
        try:
            fn(*args)
        except Exception as e:  # noqa: BLE001 - tracking must not end a sweep
            log.warning("MLflow: could not %s: %s", what, _first_line(e))


# when the work of a row began and ended (epoch seconds): its run's start and end (Tune's own
# timestamp has whole seconds)
ROW_STARTED, ROW_ENDED = "row_started", "row_ended"


def _ms(seconds: Any) -> int | None:
    return int(seconds * 1000) if isinstance(seconds, (int, float)) and seconds > 0 else None


class RowRunsCallback(Callback):
    """Driver-side: one MLflow run per result row that names ``row_key``, for trials that report
    one row per item (a batch of stitched pairs): the item's run is created (or found again, on a
    retried batch), its ``metric_keys`` logged at step 0 and the run closed FINISHED at once, its
    times those of the row's work (``ROW_STARTED`` and ``ROW_ENDED`` in the row).
    ``params_fn(name)``, ``tags_fn(name, client)`` and ``name_fn(name)`` (its run name) describe
    the item, the files of the folder a row names under ``artifacts_key`` are its artifacts;
    writing metrics, artifacts and status never raises into Tune, finding or creating the run does
    (as in MLflowTuneCallback)."""

    def __init__(
        self,
        tracking_uri: str,
        experiment_id: str,
        *,
        row_key: str,
        metric_keys: Sequence[str],
        params_fn: Callable[[str], Mapping[str, Any]],
        tags: Mapping[str, str],
        tags_fn: Callable[[str, MlflowClient], Mapping[str, str]] | None = None,
        name_fn: Callable[[str], str] | None = None,
        artifacts_key: str | None = None,
    ) -> None:
        self.tracking_uri = tracking_uri
        self.experiment_id = experiment_id
        self.row_key = row_key
        self.artifacts_key = artifacts_key
        self.metric_keys = tuple(metric_keys)
        self.params_fn = params_fn
        self.tags = dict(tags)
        self.tags_fn = tags_fn
        self.name_fn = name_fn
        self._client_cache: MlflowClient | None = None

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_client_cache": None}

    def on_trial_result(
        self, iteration: int, trials: list[Trial], trial: Trial, result: dict, **info: Any
    ) -> None:
        name = result.get(self.row_key)
        if not isinstance(name, str):
            return
        if self._client_cache is None:
            self._client_cache = _client(self.tracking_uri)
        tags = {**self.tags, "ps_ray.tune_trial_id": trial.trial_id}
        if self.tags_fn is not None:
            tags.update(self.tags_fn(name, self._client_cache))
        tracker = TrialTracker(
            self.tracking_uri,
            self.experiment_id,
            name,
            params=self.params_fn(name),
            tags=tags,
            client=self._client_cache,
            once_per_step=True,  # a retried batch reports its pairs again: logged once
            name=self.name_fn(name) if self.name_fn else None,
            start_ms=_ms(result.get(ROW_STARTED)),  # the run lasts as long as its item's work
        )
        stamp = result.get("timestamp")
        tracker.log_metrics(
            {k: lookup(result, k) for k in self.metric_keys},
            step=0,
            timestamp_ms=int(stamp * 1000) if stamp else None,
        )
        given = result.get(self.artifacts_key) if self.artifacts_key else None
        folder = Path(given) if isinstance(given, str) and given else None
        for path in sorted(folder.iterdir()) if folder is not None and folder.is_dir() else ():
            if not path.name.startswith("."):  # a writer killed mid-write left its temp file
                MLflowTuneCallback._guard(f"log artifact {path}", tracker.log_artifact, path)
        end = _ms(result.get(ROW_ENDED)) or _ms(stamp)
        MLflowTuneCallback._guard(f"close run of {name}", tracker.close, "FINISHED", end)
