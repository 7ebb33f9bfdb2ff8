"""Freed C-heap memory back to the operating system between the trials of a reused Tune worker.

Tune's reused worker (``reuse_actors``) runs each trial in a new thread, and glibc serves each
thread from its own arena, which keeps the pages its trial freed: a training worker's memory grew
by about 0.3 GB per trial (6.2 GB after 20 reach sources of ``sweeps/transfer_rows.yaml``; 8
threaded runs in one process: 0.8 -> 3.1 GB). ``malloc_trim`` after each trial keeps it flat
(0.55 GB after each of the 8; docs/cost.md, "Memory")."""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import gc


def release_freed_memory() -> bool:
    """Collect the garbage (a finished run's envs and nets sit in reference cycles), then give the
    C heap's free pages back to the OS (glibc's ``malloc_trim``); False where the C library has
    none (macOS, musl)."""
    gc.collect()
    try:
        trim = ctypes.CDLL(ctypes.util.find_library("c")).malloc_trim
    except (OSError, AttributeError, TypeError):
        return False
    trim(0)
    return True


def releasing(trainable):
    """``trainable``, then :func:`release_freed_memory`, whatever way the trial ends."""

    @functools.wraps(trainable)
    def trial(config):
        try:
            return trainable(config)
        finally:
            release_freed_memory()

    return trial
