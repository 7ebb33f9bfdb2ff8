"""Trials that failed because their node went away (a spot instance taken back, a node that died),
told apart from trials that failed on their own. :func:`ps_ray.pipeline.trials.run_trials`
launches the first kind again, so a preemption does not use up the sweep's ``max_failures``
(docs/cluster.md, "Spot capacity and preemption"). No Ray here: the messages are plain text."""

from __future__ import annotations

import re
from collections.abc import Sequence

PREEMPTION_RETRIES = 3  # rounds of relaunching node-lost trials after a stage's Tune run

# What Ray says when a trial's node goes away (Ray 2.60: ray/exceptions.py and the GCS's
# node-death messages), lower-cased. A worker process that dies on a live node (OOM kill,
# segfault: "its worker process has died") is the trial's own failure, not listed here.
NODE_LOST = (
    "because its node has died",  # ActorDiedError, the GCS marked the node dead
    "the actor's node was preempted",  # ... with the node's death reason
    "the actor's node was terminated",
    "actor died by preemption",
    "the node it was running on is dead",  # NodeDiedError, a task on a dead node
    "the actor is temporarily unavailable",  # ActorUnavailableError: what a killed node gave here
    "the task's local raylet died",  # LocalRayletDiedError
    "has been marked dead because the detector has missed too many heartbeats",
)

_FAILURE = re.compile(r"^Failure # \d+ \(occurred at [^)\n]*\)$", re.MULTILINE)


def failures(error_txt: str) -> list[str]:
    """The failures a Tune trial's ``error.txt`` lists (Tune appends one per failure, each after
    a ``Failure # N (occurred at ...)`` line), oldest first."""
    parts = _FAILURE.split(error_txt)
    return [p.strip() for p in parts[1:] if p.strip()]


def node_lost(message: str) -> bool:
    """Whether one failure's message says its node went away."""
    text = message.lower()
    return any(sign in text for sign in NODE_LOST)


def preempted(messages: Sequence[str]) -> bool:
    """Whether a failed trial failed only because its node went away: at least one failure, and
    every one of them a lost node. One failure of its own and it counts as the trial's."""
    return bool(messages) and all(node_lost(m) for m in messages)
