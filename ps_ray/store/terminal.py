"""What reaches the terminal: ps_ray's own lines. Ray's and MLflow's routine messages (the token
notice, "You are running ... on the new API stack", Ray's own deprecation notices, MLflow's
database set-up) go to a log file instead; ``--verbose`` or ``PS_RAY_VERBOSE=1`` leaves them on
the terminal. No Ray import here."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import IO

VERBOSE_ENV = "PS_RAY_VERBOSE"
NOISY_LOGGERS = ("ray", "ray.tune", "ray.rllib", "mlflow", "alembic")


def verbose() -> bool:
    return os.environ.get(VERBOSE_ENV, "") not in ("", "0")


@contextlib.contextmanager
def others_to(log_path: Path) -> Iterator[IO[str]]:
    """For the block, send Python's stdout and stderr, the noisy libraries' log handlers and the
    process's file descriptor 2 (where Ray's core writes) to ``log_path``; yields the real stdout
    for ps_ray's own lines. With :func:`verbose`, changes nothing."""
    real_stdout = sys.stdout
    if verbose():
        yield real_stdout
        return
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "a", buffering=1) as log:
        handlers = list(  # each once: a handler on two loggers must get its own stream back
            dict.fromkeys(
                h
                for name in NOISY_LOGGERS
                for h in logging.getLogger(name).handlers
                if isinstance(h, logging.StreamHandler)
            )
        )
        streams = [h.setStream(log) for h in handlers]
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        saved = _redirect_fd2(log)
        try:
            with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
                yield real_stdout
        finally:
            _restore_fd2(saved)
            for handler, stream in zip(handlers, streams):
                handler.setStream(stream)


def _redirect_fd2(log: IO[str]) -> int | None:
    try:
        saved = os.dup(2)
        os.dup2(log.fileno(), 2)
    except OSError:  # no fd 2 (closed) or a log without one
        return None
    return saved


def _restore_fd2(saved: int | None) -> None:
    if saved is not None:
        os.dup2(saved, 2)
        os.close(saved)
