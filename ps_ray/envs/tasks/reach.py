"""Reach: move the end effector to a goal in a box, or in a disc-shaped region (latent analysis)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ps_ray.errors import choice_error

from ..sim import Sim
from .base import Task, TaskOptions

# The paper's four target regions (Fig. 1B): one disc per quadrant in front of the robot,
# q1 = (+x, +y), q2 = (-x, +y), q3 = (-x, -y), q4 = (+x, -y) as in the usual quadrant numbering.
GOAL_REGIONS: dict[str, dict] = {
    name: {"center": (sx * 0.1, sy * 0.1, 0.15), "radius": 0.05}
    for name, (sx, sy) in {"q1": (1, 1), "q2": (-1, 1), "q3": (-1, -1), "q4": (1, -1)}.items()
}
# Two overlapping halves (+x and -x), for stitching between goal sets that share a middle strip.
GOAL_REGIONS.update(
    {name: {"center": (sx * 0.05, 0.0, 0.15), "radius": 0.1} for name, sx in {"east": 1, "west": -1}.items()}
)
_REGION_CHOICES = ("None", *GOAL_REGIONS, "{'center': [x, y, z], 'radius': r}")


def resolve_region(region: str | Mapping | None) -> tuple[np.ndarray, float] | None:
    """``(center, radius)`` of a horizontal disc, or None for the default goal box."""
    if region is None:
        return None
    if isinstance(region, str):
        if region not in GOAL_REGIONS:
            raise choice_error("goal_region", region, _REGION_CHOICES)
        region = GOAL_REGIONS[region]
    if isinstance(region, Mapping) and set(region) == {"center", "radius"}:
        center = np.asarray(region["center"], dtype=float)
        radius = float(region["radius"])
        if center.shape == (3,) and radius >= 0:
            return center, radius
    raise choice_error("goal_region", region, _REGION_CHOICES)


@dataclass(frozen=True)
class ReachOptions(TaskOptions):
    goal_low: tuple[float, float, float] = (-0.15, -0.15, 0.0)
    goal_high: tuple[float, float, float] = (0.15, 0.15, 0.3)
    goal_region: str | Mapping | None = None  # None (box above), "q1".."q4", or {"center", "radius"}

    def __post_init__(self) -> None:
        resolve_region(self.goal_region)  # fail at construction on a bad region


class Reach(Task):
    """Achieved goal: the end-effector position; no task state."""

    Options = ReachOptions
    state_dim = 0
    options: ReachOptions

    def __init__(self, sim: Sim, options: ReachOptions) -> None:
        super().__init__(sim, options)
        self._region = resolve_region(options.goal_region)

    def target_region(self) -> tuple[np.ndarray, np.ndarray]:
        if self._region is None:
            return np.asarray(self.options.goal_low, float), np.asarray(self.options.goal_high, float)
        center, radius = self._region  # the disc's bounding box
        return center - (radius, radius, 0.0), center + (radius, radius, 0.0)

    def _reset(self, rng: np.random.Generator) -> None:
        o = self.options
        if self._region is None:
            self.goal = rng.uniform(o.goal_low, o.goal_high)
        else:  # uniform over the disc
            center, radius = self._region
            r, theta = radius * np.sqrt(rng.uniform()), rng.uniform(0.0, 2 * np.pi)
            self.goal = center + (r * np.cos(theta), r * np.sin(theta), 0.0)

    def observe(self, ee_position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(0), ee_position
