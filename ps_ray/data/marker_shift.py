"""Hindsight that moves the named marker rather than the goal (train setting ``hindsight: marker``).

A task whose goals are said in a marker's frame (the transfer family) has one real goal, the zero
offset; plain 'future' relabelling gives every relabelled transition another one, so a learner can
tell real transitions (which almost never succeed on a push task) from relabelled ones by the goal
alone, and learns that the real goal is hopeless. Moving the marker instead keeps the real goal in
every transition: relabelled and real inputs then look alike, as a world-frame goal's do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MarkerShift:
    """Hindsight by moving the named marker, for a task whose goals are said in a marker's frame:
    a relabelled transition keeps its real goal and sees the scene in which the named marker stood
    where the episode's later outcome puts that goal (the marker's task-state columns and the
    achieved goal shifted by the difference of the two goals). Its reward is the reward of the
    relabelled goal, as in plain 'future' relabelling; what changes is what the learner reads: a
    real goal (zero offset) in every transition, so that it cannot tell relabelled transitions from
    real ones by the goal alone (:meth:`ps_ray.envs.tasks.markers.MarkerScene.hindsight_marker`).

    ``sign`` is how the columns move with the marker: +1 for its position, -1 for the object's
    position minus it."""

    key: str  # the observation key that holds the marker's columns (the task state)
    columns: slice
    sign: float

    def move(
        self, out: dict[str, np.ndarray], side: str, rows: np.ndarray, shift: np.ndarray, achieved: str
    ) -> None:
        """Move the marker by ``shift`` (the relabelled goal minus the real one) in ``rows`` of
        ``out[side/...]``; the achieved goal, said from the marker, moves the other way."""
        state = out[f"{side}/{self.key}"]
        state[rows, self.columns] += (self.sign * shift).astype(state.dtype)
        out[f"{side}/{achieved}"][rows] -= shift.astype(state.dtype)
