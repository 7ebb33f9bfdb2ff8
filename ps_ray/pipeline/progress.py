"""What a Tune stage shows on the terminal: one compact live view, one summary line.

Tune's own tables and Ray's routine warnings go to ``<stage folder>/logs/<stage>.log`` instead
(``--verbose`` or ``PS_RAY_VERBOSE=1`` puts them back on the terminal). On a TTY the view is a
tqdm bar; without one (CI, ``ray job`` logs) it is a plain line every ``PLAIN_EVERY_S`` seconds,
with no control codes.
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from ray.tune import Callback
from tqdm import tqdm

from ps_ray.store.attempts import FINISHED, START_STEPS, STOPPED_FILE, identity
from ps_ray.store.terminal import others_to

PLAIN_EVERY_S = 30.0
EARLIEST_ETA = 0.02  # share of a stage's work done before its ETA is shown


class StageProgress(Callback):
    """Trials done / running / failed / pending, env steps, elapsed and ETA, best greedy success.

    Counts are read from the trials' own states at every event, so a restored stage (whose
    callbacks come back from Tune's experiment state) counts the trials finished before the
    restart too. A trial Tune ended without its finished mark was interrupted (Ctrl-C). The ETA
    counts work, not trials: a trial with a budget (``budgets``: units of ``work``, env steps by
    default, by the identity of its ``key`` value) is done by the share of its budget run, so a few
    long trials give a steady estimate. The output stream is looked up when printing, never stored
    (it is not picklable)."""

    def __init__(
        self,
        stage: str,
        total: int = 0,
        key: str = "",
        budgets: dict[str, int] | None = None,
        work: str = "env_steps",
    ) -> None:
        self.stage, self.total = stage, total  # Tune makes a grid search's trials lazily: count them all
        self.key, self.budgets, self.work = key, budgets or {}, work
        self.started = time.time()
        self.best: float | None = None
        self.last_plain = self.last_step = 0.0
        self.counts: dict[str, int] = {}
        self.env_steps = 0
        # trial id -> (share of its work done at its first result, now, share it ends at: 1, or
        # less for a trial that failed or a scheduler stopped); None: started, no result yet
        self.shares: dict[str, tuple[float, float, float] | None] = {}
        self.unmeasured = 0  # trials Tune made with all their work left
        self._bar = None

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_bar": None}

    # -- Tune hooks ----------------------------------------------------------------------------
    def on_trial_start(self, iteration, trials, trial, **info) -> None:
        self.shares.setdefault(trial.trial_id, None)  # a start seen: its work is this run's
        self._update(trials)

    def on_trial_result(self, iteration, trials, trial, result: dict[str, Any], **info) -> None:
        for key in ("eval_success", "final_success", "success_mean"):
            value = result.get(key)
            if value is not None and value == value:
                self.best = value if self.best is None else max(self.best, value)
        self._update(trials)

    def on_step_end(self, iteration, trials, **info) -> None:
        """Between events too (a trial may report once in many minutes): the bar's clock once a
        second, a plain line every ``PLAIN_EVERY_S``."""
        now = time.time()
        if self.counts and now - self.last_step >= 1.0:
            self.last_step = now
            self._show()

    def on_trial_complete(self, iteration, trials, trial, **info) -> None:
        self._update(trials, force=all(t.status in ("TERMINATED", "ERROR") for t in trials))

    def on_trial_error(self, iteration, trials, trial, **info) -> None:
        self._update(trials, force=True)

    def on_experiment_end(self, trials, **info) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        else:
            self._update(trials, force=True)

    # -- view ----------------------------------------------------------------------------------
    def _update(self, trials, force: bool = False) -> None:
        ended = [t for t in trials if t.status == "TERMINATED"]
        interrupted = sum(_interrupted(t) for t in ended)
        stopped = sum(_stopped(t) for t in ended)
        self.counts = {
            "total": max(self.total, len(trials)),
            "made": len(trials),
            "done": len(ended) - interrupted - stopped,
            "stopped": stopped,  # by a search's scheduler (ps_ray.pipeline.search)
            "interrupted": interrupted,
            "running": sum(t.status == "RUNNING" for t in trials),
            "failed": sum(t.status == "ERROR" for t in trials),
        }
        self.env_steps = sum(int((t.last_result or {}).get("env_steps") or 0) for t in trials)
        self.unmeasured = 0
        for trial in trials:
            measured, seen = self._share(trial), self.shares.get(trial.trial_id)
            if measured is None:  # waiting, or started without a result yet
                if seen is None:  # all its work left
                    self.unmeasured += 1
                    if trial.status == "RUNNING":
                        self.shares.setdefault(trial.trial_id, None)
                else:  # a failed trial Tune retries: its share so far stands, the rest is left again
                    self.shares[trial.trial_id] = (*seen[:2], 1.0)
                continue
            share, ends_early = measured
            if seen is None:  # first result: it may carry steps a checkpoint restored
                first = self._restored(trial, share)
            else:
                first, share = seen[0], max(share, seen[1])  # a retry from a checkpoint redoes steps
            self.shares[trial.trial_id] = (first, share, share if ends_early else 1.0)
        self._show(force)

    def _budget(self, trial) -> int | None:
        return self.budgets.get(identity((trial.config or {}).get(self.key)))

    def _restored(self, trial, share: float) -> float:
        """The share of a trial's work it brought from a checkpoint, at its first result seen: as
        its rows say, else that result's share (a trial that ended before any result was seen
        ran all of its work here)."""
        start = (trial.last_result or {}).get(START_STEPS)
        budget = self._budget(trial)
        if start is not None and budget and self.work == "env_steps":
            return min(int(start) / budget, share)
        over = trial.status in ("TERMINATED", "ERROR")
        return 0.0 if over and trial.trial_id in self.shares else share

    def _share(self, trial) -> tuple[float, bool] | None:
        """The share of a trial's work done (its env steps over its budget), and whether its run
        ends there: a failure or a search's scheduler ended it, and the rest is never done (a
        finished or interrupted trial's run ends at 1: a resume does the rest). A trial without
        a budget counts whole once ended. None while it waits, and before its first result (a
        resumed trial starts from its checkpoint's steps)."""
        ended = trial.status in ("TERMINATED", "ERROR")
        early = trial.status == "ERROR" or (trial.status == "TERMINATED" and _stopped(trial))
        budget = self._budget(trial)
        steps = (trial.last_result or {}).get(self.work)
        if ended and (not budget or not (early or _interrupted(trial))):
            return 1.0, False  # finished, or ended without a budget to measure it by
        if not ended and trial.status != "RUNNING":
            return None
        if not budget:
            return 0.0, False
        if steps is None:
            return (0.0, early) if ended else None
        return min(int(steps) / budget, 1.0), early

    def status(self) -> str:
        c = self.counts
        finished = sum(c.get(k, 0) for k in ("done", "failed", "stopped", "interrupted"))
        pending = max(c.get("total", 0) - finished - c.get("running", 0), 0)
        elapsed = time.time() - self.started
        measured = [share for share in self.shares.values() if share is not None]
        not_made = max(c.get("total", 0) - c.get("made", 0), 0)  # Tune makes a grid's trials lazily
        eta = eta_s(elapsed, measured, not_made + self.unmeasured)
        best = "–" if self.best is None else f"{self.best:.2f}"
        steps = f"  env steps {self.env_steps:,}" if self.env_steps else ""
        stopped = f"{c['stopped']} stopped early, " if c.get("stopped") else ""
        interrupted = f"{c['interrupted']} interrupted, " if c.get("interrupted") else ""
        return (
            f"{c.get('done', 0)} done, {stopped}{interrupted}{c.get('running', 0)} running, "
            f"{c.get('failed', 0)} failed, {pending} pending{steps}  best success {best}  elapsed "
            f"{_clock(elapsed)}  ETA {'–' if eta is None else _clock(eta)}"
        )

    def _show(self, force: bool = False) -> None:
        stream = view_stream()
        if stream.isatty():
            if self._bar is None:
                self._bar = tqdm(
                    total=self.counts["total"],
                    desc=self.stage,
                    unit="trial",
                    file=stream,
                    leave=False,
                    dynamic_ncols=True,
                )
            self._bar.n = sum(self.counts[k] for k in ("done", "failed", "stopped", "interrupted"))
            self._bar.set_postfix_str(self.status(), refresh=True)
            return
        now = time.time()
        if force or now - self.last_plain >= PLAIN_EVERY_S:
            self.last_plain = now
            print(f"  {self.stage}: {self.status()}", file=stream, flush=True)


_VIEW_STREAM: list[IO[str]] = []  # the terminal while quiet_tune redirects stdout


def view_stream() -> IO[str]:
    return _VIEW_STREAM[-1] if _VIEW_STREAM else sys.stdout


def _stopped(trial) -> bool:
    return (Path(trial.path) / STOPPED_FILE).is_file()


def _interrupted(trial) -> bool:
    """An ended trial that neither finished its work nor was stopped by a search's scheduler."""
    return not (trial.last_result or {}).get(FINISHED) and not _stopped(trial)


def eta_s(elapsed_s: float, shares: list[tuple[float, float, float]], pending: int) -> float | None:
    """Seconds left at the pace so far: ``shares`` holds each trial seen, as the share of its work
    done when first seen, now, and where it ends (1, or less for a trial ended early); ``pending``
    trials not measured yet have all theirs left. None until ``EARLIEST_ETA`` of the work is done:
    the first results follow the trials' start-up, and a pace read from them is off by hours."""
    done = sum(now - first for first, now, _ in shares)
    left = sum(end - now for _, now, end in shares) + pending
    return elapsed_s * left / done if done > 0 and done >= EARLIEST_ETA * (done + left) else None


def _clock(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


@contextlib.contextmanager
def quiet_tune(log_path: Path) -> Iterator[IO[str]]:
    """Send Tune's printed tables and the noisy loggers' messages to ``log_path`` for the block
    (:func:`ps_ray.store.terminal.others_to`); yields the real stdout, for the live view."""
    with others_to(log_path) as real_stdout:
        _VIEW_STREAM.append(real_stdout)
        try:
            yield real_stdout
        finally:
            _VIEW_STREAM.pop()
