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

from ps_ray.store.attempts import STOPPED_FILE
from ps_ray.store.terminal import others_to

PLAIN_EVERY_S = 30.0


class StageProgress(Callback):
    """Trials done / running / failed / pending, env steps, elapsed and ETA, best greedy success.

    Counts are read from the trials' own states at every event, so a restored stage (whose
    callbacks come back from Tune's experiment state) counts the trials finished before the
    restart too. The output stream is looked up when printing, never stored (it is not picklable)."""

    def __init__(self, stage: str, total: int = 0) -> None:
        self.stage, self.total = stage, total  # Tune makes a grid search's trials lazily: count them all
        self.started = time.time()
        self.best: float | None = None
        self.last_plain = 0.0
        self.counts: dict[str, int] = {}
        self.env_steps = 0
        self._bar = None

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_bar": None}

    # -- Tune hooks ----------------------------------------------------------------------------
    def on_trial_start(self, iteration, trials, trial, **info) -> None:
        self._update(trials)

    def on_trial_result(self, iteration, trials, trial, result: dict[str, Any], **info) -> None:
        for key in ("eval_success", "final_success", "success_mean"):
            value = result.get(key)
            if value is not None and value == value:
                self.best = value if self.best is None else max(self.best, value)
        self._update(trials)

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
        states = [t.status for t in trials]
        stopped = sum(t.status == "TERMINATED" and (Path(t.path) / STOPPED_FILE).is_file() for t in trials)
        self.counts = {
            "total": max(self.total, len(trials)),
            "done": states.count("TERMINATED") - stopped,
            "stopped": stopped,  # by a search's scheduler (ps_ray.pipeline.search)
            "running": states.count("RUNNING"),
            "failed": states.count("ERROR"),
        }
        self.env_steps = sum(int((t.last_result or {}).get("env_steps") or 0) for t in trials)
        self._show(force)

    def status(self) -> str:
        c = self.counts
        finished = c.get("done", 0) + c.get("failed", 0) + c.get("stopped", 0)
        pending = max(c.get("total", 0) - finished - c.get("running", 0), 0)
        elapsed = time.time() - self.started
        remaining = c.get("total", 0) - finished
        eta = elapsed / finished * remaining if finished else None
        best = "–" if self.best is None else f"{self.best:.2f}"
        steps = f"  env steps {self.env_steps:,}" if self.env_steps else ""
        stopped = f"{c['stopped']} stopped early, " if c.get("stopped") else ""
        return (
            f"{c.get('done', 0)} done, {stopped}{c.get('running', 0)} running, {c.get('failed', 0)} "
            f"failed, {pending} pending{steps}  best success {best}  elapsed "
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
            self._bar.n = self.counts["done"] + self.counts["failed"] + self.counts["stopped"]
            self._bar.set_postfix_str(self.status(), refresh=True)
            return
        now = time.time()
        if force or now - self.last_plain >= PLAIN_EVERY_S:
            self.last_plain = now
            print(f"  {self.stage}: {self.status()}", file=stream, flush=True)


_VIEW_STREAM: list[IO[str]] = []  # the terminal while quiet_tune redirects stdout


def view_stream() -> IO[str]:
    return _VIEW_STREAM[-1] if _VIEW_STREAM else sys.stdout


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
