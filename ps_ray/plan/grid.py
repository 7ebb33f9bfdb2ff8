"""The grid stage's trials: each co-trained grid of the sweep, with the anchor set of each task."""

from __future__ import annotations

from ps_ray.plan.train import anchor_file
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.trial import GridTrial


def plan(spec: SweepSpec) -> list[GridTrial]:
    """One trial per grid (:meth:`ps_ray.specs.grid.GridSettings.grids`); a PS grid's tasks read
    the sweep's anchor sets, the same files its sources alone read."""
    return [
        GridTrial(
            grid,
            tuple(
                anchor_file(spec, grid.cell_spec(next(c for c in grid.cells if c[1] == t)))
                for t in grid.tasks
            ),
        )
        for grid in spec.grid.grids(spec)
    ]
