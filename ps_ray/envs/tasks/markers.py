"""Markers: several coloured markers in the scene; the task names the one to reach.

A task family that needs transfer (docs/transfer.md): two tasks of the family see the same kind of
scene and differ only in which marker they mean, so a policy of one task run on the other reaches
the wrong marker, and what to do lives in the task state's meaning, not in an input that any
policy could read.

Goals are expressed in the named marker's frame, so that the target point is never an input:

- ``task_state``: every marker's position (3 per marker), in a fixed order of colours;
- ``achieved_goal``: the end effector's position minus the named marker's;
- ``desired_goal``: the offset from the named marker to reach: zero in every real episode.

A hindsight goal relabelled from a later achieved goal is then "reach the named marker plus this
offset", still said in the task's own terms, and ``compute_reward`` (the distance of the two goals)
agrees with the env's reward for it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as p

from ps_ray.errors import UserError

from ..sim import Sim
from .base import Task, TaskOptions

MARKER_RADIUS = 0.02
MARKER_COLOURS = (
    (0.9, 0.1, 0.1, 1.0),  # red
    (0.1, 0.2, 0.9, 1.0),  # blue
    (0.1, 0.8, 0.1, 1.0),  # green
    (0.9, 0.8, 0.1, 1.0),  # yellow
)


@dataclass(frozen=True)
class MarkerOptions(TaskOptions):
    markers: int = 2  # how many markers the scene holds (their positions are the task state)
    target: int = 0  # the index of the marker to reach (0 red, 1 blue, 2 green, 3 yellow)
    marker_low: tuple[float, float, float] = (-0.1, -0.1, 0.1)  # markers ~ U[low, high] ...
    marker_high: tuple[float, float, float] = (0.1, 0.1, 0.2)
    min_separation: float = 0.1  # ... at least this far apart (twice the success distance) ...
    # ... and this far (horizontally) from the vertical line through the workspace centre, about
    # which the mounts of ps_ray.envs.robots turn: another mount's mirror image misses by 2x this
    min_radius: float = 0.03

    def __post_init__(self) -> None:
        if not isinstance(self.markers, int) or not 1 <= self.markers <= len(MARKER_COLOURS):
            raise UserError(f"bad markers {self.markers!r}; valid markers: 1..{len(MARKER_COLOURS)}")
        if not isinstance(self.target, int) or not 0 <= self.target < self.markers:
            raise UserError(f"bad target {self.target!r}; valid targets: 0..{self.markers - 1}")


class MarkerScene:
    """What the transfer family's scenes share: coloured markers, one named by the task
    (``options.markers`` and ``options.target``), placed anew each episode; every marker plus the
    desired offset is a candidate target, the named one the target."""

    options: MarkerOptions
    positions: np.ndarray
    goal: np.ndarray
    state_dim: int
    sim: Sim

    def _build_markers(self, sim: Sim) -> None:
        self._bodies = [
            sim.add_shape(p.GEOM_SPHERE, (MARKER_RADIUS,), (0.0, 0.0, -1.0), rgba=rgba, ghost=True)
            for rgba in MARKER_COLOURS[: self.options.markers]
        ]

    @property
    def offset(self) -> np.ndarray:
        """The desired offset from the named marker (the goal itself, said in that marker's frame)."""
        return self.goal

    @property
    def target_position(self) -> np.ndarray:
        """Where the outcome must end: the named marker plus the desired offset."""
        return self.positions[self.options.target] + self.offset

    def candidate_targets(self) -> np.ndarray:
        """Every marker plus the desired offset: where each task of the family would end here."""
        return self.positions + self.offset

    @property
    def named_candidate(self) -> int:
        return self.options.target

    @classmethod
    def marker_columns(cls, index: int) -> slice:
        """Where marker ``index``'s position stands in the task state (after the family's own
        ``state_dim`` numbers: none for the markers, the object's 12 for the push family)."""
        first = cls.state_dim + 3 * index
        return slice(first, first + 3)

    @classmethod
    def hindsight_marker(cls, options) -> tuple[slice, float] | None:
        """The named marker's task-state columns and how they move with it (+1: its position),
        for hindsight that moves the marker rather than the goal (``ps_ray.data.marker_shift.MarkerShift``);
        None where the goals are not said in its frame."""
        return cls.marker_columns(options.target), 1.0

    def _settable(self, task_input: np.ndarray) -> np.ndarray:
        width = self.state_dim + 3 * self.options.markers + 3
        if task_input.shape != (width,) or not np.isfinite(task_input).all():
            raise UserError(
                f"a task input of this scene is {width} finite numbers, got {task_input.tolist()}"
            )
        return task_input

    def _set(self, task_input: np.ndarray) -> None:
        """The scene a task input says: the family's own part (:meth:`_set_own`), every marker at
        the task state's positions, the desired offset from the goal part."""
        head, width = self.state_dim, self.state_dim + 3 * self.options.markers
        self._set_own(task_input[:head])
        self.positions = self._marker_positions(task_input[:head], task_input[head:width].reshape(-1, 3))
        for body, position in zip(self._bodies, self.positions):
            self.sim.move(body, position)
        self.goal = task_input[width:].copy()

    def _set_own(self, state: np.ndarray) -> None:
        """Set the family's own part of the task state (the markers have none)."""

    def _marker_positions(self, own: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """The markers' world positions from their task-state columns (rows; the family's own part
        of the task state beside them): the columns themselves here."""
        return columns.copy()

    def _place_markers(self, sim: Sim, rng: np.random.Generator, low, high, where: str, clear=None) -> None:
        """Markers drawn uniformly in the box ``low``..``high`` by rejection sampling on the env's
        RNG (deterministic), ``min_separation`` apart, ``min_radius`` off the mounts' axis and
        where ``clear(point)`` allows; the desired offset zero."""
        o = self.options
        placed: list[np.ndarray] = []
        for _ in range(10_000):
            if len(placed) == o.markers:
                break
            candidate = rng.uniform(low, high)
            apart = all(np.linalg.norm(candidate - q) >= o.min_separation for q in placed)
            if apart and np.hypot(*candidate[:2]) >= o.min_radius and (clear is None or clear(candidate)):
                placed.append(candidate)
        else:
            raise UserError(f"cannot place {o.markers} markers {o.min_separation} m apart{where}")
        self.positions = np.asarray(placed)
        for body, position in zip(self._bodies, self.positions):
            sim.move(body, position)
        self.goal = np.zeros(3)


class Markers(MarkerScene, Task):
    """Reach the named marker; the other markers are the same kind of input with another meaning."""

    Options = MarkerOptions
    options: MarkerOptions

    def __init__(self, sim: Sim, options: MarkerOptions) -> None:
        self.positions = np.zeros((options.markers, 3))
        super().__init__(sim, options)

    @classmethod
    def state_width(cls, options: TaskOptions) -> int:
        return 3 * options.markers  # type: ignore[attr-defined]

    @classmethod
    def candidate_count(cls, options: TaskOptions) -> int:
        return options.markers  # type: ignore[attr-defined]

    def _build(self) -> None:
        self._build_markers(self.sim)

    def target_region(self) -> tuple[np.ndarray, np.ndarray]:
        """The marker box: every marker, the named one too, is drawn in it."""
        return np.asarray(self.options.marker_low, float), np.asarray(self.options.marker_high, float)

    def _reset(self, rng: np.random.Generator) -> None:
        o = self.options
        where = (
            f" and {o.min_radius} m off the centre within marker_low {o.marker_low} .. marker_high "
            f"{o.marker_high}"
        )
        self._place_markers(self.sim, rng, o.marker_low, o.marker_high, where)

    def observe(self, ee_position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.positions.reshape(-1), ee_position - self.positions[self.options.target]
