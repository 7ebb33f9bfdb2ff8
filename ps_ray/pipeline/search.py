"""A search's Tune scheduler (:mod:`ps_ray.specs.search`): Tune's ASHA over env steps on the
greedy success curve, which leaves a plain-JSON mark beside each trial it stops, so a resumed
search counts that trial as done (:data:`ps_ray.store.attempts.STOPPED_FILE`) and never runs it
again. A resumed search's scheduler first hears the earlier trials' curves, so its rungs cut
where the killed one's would have."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

from ray.tune.schedulers import ASHAScheduler, TrialScheduler

from ps_ray.specs.modes import Scheduler
from ps_ray.specs.search import SearchSpec
from ps_ray.store.atomic import write_text
from ps_ray.store.attempts import FINISHED, STOPPED_FILE, merged_rows, outcomes

TIME_ATTR = "env_steps"


class MarkingASHA(ASHAScheduler):
    """ASHA that skips rows without the metric (a checkpoint between evaluations) and marks a
    trial it stops before its end."""

    def on_trial_result(self, tune_controller, trial, result: dict) -> str:
        if result.get(self._metric) is None:
            return TrialScheduler.CONTINUE
        decision = super().on_trial_result(tune_controller, trial, result)
        if decision == TrialScheduler.STOP and not result.get(FINISHED):
            mark = {TIME_ATTR: result[TIME_ATTR], self._metric: result[self._metric]}
            write_text(Path(trial.path) / STOPPED_FILE, json.dumps(mark))
        return decision

    def on_trial_complete(self, tune_controller, trial, result: dict) -> None:
        if result.get(self._metric) is None:  # a last row without an evaluation (the final one's)
            self._trial_info.pop(trial.trial_id, None)
            return
        super().on_trial_complete(tune_controller, trial, result)


def search_scheduler(
    search: SearchSpec, max_env_steps: int, stage_dir: Path, trials: list
) -> MarkingASHA | None:
    """The scheduler of a search's training stage (None: no scheduler), told the curves of the
    ``trials`` (Tune configs) that earlier runs of the stage finished or stopped."""
    if search.scheduler == Scheduler.NONE:
        return None
    scheduler = MarkingASHA(
        time_attr=TIME_ATTR,
        metric=search.metric,
        mode="max",
        max_t=max_env_steps,
        grace_period=min(search.grace_env_steps, max_env_steps),
        reduction_factor=search.reduction_factor,
    )
    (bracket,) = scheduler._brackets  # one bracket: ASHA's default (Tune's own bookkeeping object)
    done = [o for o in outcomes(stage_dir, "trial", trials) if o.error is None]
    for index, outcome in enumerate(done):
        earlier = SimpleNamespace(trial_id=f"earlier-{index}")
        for row in merged_rows(outcome.attempts):
            if row.get(search.metric) is not None and row.get(TIME_ATTR) is not None:
                bracket.on_result(earlier, row[TIME_ATTR], float(row[search.metric]))
    return scheduler
