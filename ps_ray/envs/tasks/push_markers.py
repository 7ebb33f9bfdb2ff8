"""Push to a marker: one object and several goal markers on the table; the task names the marker
the object must end at. The manipulation member of the transfer family (the markers' pattern,
docs/transfer.md): two tasks see the same kind of scene and differ only in which marker they mean,
so a source of one task pushes to the wrong marker on the other, and no input gives the target away.

Goals are said in the named marker's frame, as the marker family says them:

- ``task_state``: the object's state (position, Euler angles, linear and angular velocity: 12),
  then every marker's position (3 per marker), in a fixed order of colours; with ``marker_state:
  from_object``, the object's position minus each marker's instead (what each task of the scene
  reads as its achieved goal, so the critic compares two inputs, as plain push's does, and still
  no input names the target);
- ``achieved_goal``: the object's position minus the named marker's;
- ``desired_goal``: the offset from the named marker at which the object must end: zero in every
  real episode, so a hindsight goal is "push to the named marker plus this offset".

``goal_frame: world`` says both goals in the world frame instead (the desired goal the named
marker's position, the achieved goal the object's), as plain push says them: a diagnostic of what
the marker frame costs a learner, not a member of the family (the target is then an input).

The outcome of an episode (outcome matching, the wrong-target rate, touching) is where the object
is, read from the env (``RobotTaskEnv.object_position``), never from the achieved goal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ps_ray.errors import UserError

from .markers import MARKER_COLOURS, MarkerScene
from .push import Push, PushOptions

GOAL_FRAMES = ("marker", "world")
MARKER_STATES = ("position", "from_object")


@dataclass(frozen=True)
class PushMarkerOptions(PushOptions):
    markers: int = 2  # how many goal markers the table holds (their positions are task state)
    target: int = 0  # the marker the object must end at (0 red, 1 blue, 2 green, 3 yellow)
    min_separation: float = 0.1  # markers at least this far apart (twice the success distance) ...
    # ... this far (horizontally) from the workspace centre's vertical line, about which the mounts
    # of ps_ray.envs.robots turn (another mount's mirror image misses by twice this) ...
    min_radius: float = 0.06
    # ... and this far from the object's start, so that every episode needs a push
    min_push: float = 0.08
    # "world": a diagnostic only (the goal the named marker's world position, the achieved goal the
    # object's): the target is then an input any source reads, so the family cannot use it
    goal_frame: str = "marker"
    # how the task state says the markers: "position" (each marker's world position) or "from_object"
    # (the object's position minus each marker's: each task's achieved goal, for every task alike)
    marker_state: str = "position"

    def __post_init__(self) -> None:
        if self.goal_frame not in GOAL_FRAMES:
            frames = ", ".join(GOAL_FRAMES)
            raise UserError(f"bad goal_frame {self.goal_frame!r}; valid goal frames: {frames}")
        if self.marker_state not in MARKER_STATES:
            raise UserError(
                f"bad marker_state {self.marker_state!r}; valid marker states: {', '.join(MARKER_STATES)}"
            )
        if not isinstance(self.markers, int) or not 1 <= self.markers <= len(MARKER_COLOURS):
            raise UserError(f"bad markers {self.markers!r}; valid markers: 1..{len(MARKER_COLOURS)}")
        if not isinstance(self.target, int) or not 0 <= self.target < self.markers:
            raise UserError(f"bad target {self.target!r}; valid targets: 0..{self.markers - 1}")


class PushMarkers(MarkerScene, Push):
    """Push the object to the named marker; the other markers mean the same to another task."""

    Options = PushMarkerOptions
    options: PushMarkerOptions

    def __init__(self, sim, options: PushMarkerOptions) -> None:
        self.positions = np.zeros((options.markers, 3))
        super().__init__(sim, options)

    @classmethod
    def state_width(cls, options) -> int:
        return cls.state_dim + 3 * options.markers

    @classmethod
    def candidate_count(cls, options) -> int:
        return options.markers

    def _build(self) -> None:
        super()._build()
        self._build_markers(self.sim)

    def _reset(self, rng: np.random.Generator) -> None:
        super()._reset(rng)  # the object, on the env's RNG (its goal draw is replaced below)
        o = self.options
        start = self.sim.base_state(self.object)[:3]
        where = (
            f", {o.min_radius} m off the centre and {o.min_push} m from the object within goal_xy_range "
            f"{o.goal_xy_range}"
        )
        away = lambda point: np.linalg.norm(point[:2] - start[:2]) >= o.min_push  # noqa: E731
        self._place_markers(self.sim, rng, *self.target_region(), where, clear=away)
        if o.goal_frame == "world":
            self.goal = self.positions[o.target].copy()

    @property
    def offset(self) -> np.ndarray:
        if self.options.goal_frame == "world":
            return self.goal - self.positions[self.options.target]
        return self.goal

    @classmethod
    def hindsight_marker(cls, options) -> tuple[slice, float] | None:
        if options.goal_frame == "world":
            return None
        return cls.marker_columns(options.target), -1.0 if options.marker_state == "from_object" else 1.0

    def _set_own(self, state: np.ndarray) -> None:
        """The object where the task state's first 12 numbers put it (pose and velocities)."""
        self.sim.set_base_state(self.object, state)

    def _marker_positions(self, own: np.ndarray, columns: np.ndarray) -> np.ndarray:
        if self.options.marker_state == "from_object":
            return own[:3] - columns
        return columns.copy()

    def observe(self, ee_position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        state, position = super().observe(ee_position)
        markers = position - self.positions if self.options.marker_state == "from_object" else self.positions
        task_state = np.concatenate([state, markers.reshape(-1)])
        if self.options.goal_frame == "world":
            return task_state, position
        return task_state, position - self.positions[self.options.target]
