"""The two catalogues a plan runs on: what a sweep trained (its zoo, read from its folder), and
what its spec implies it will train (every source, anchor policy and grid cell, each with the
signature its policy file will carry), for pricing before anything ran."""

from __future__ import annotations

from pathlib import Path

from ps_ray.plan import grid, train
from ps_ray.specs.sweep import SweepSpec
from ps_ray.stitching.rule import expected_signature
from ps_ray.stitching.zoo import ModuleZoo, ZooEntry, key_of
from ps_ray.store.layout import sweep_layout

PLANNED = Path("<planned>")  # where a planned module's file stands: a name, never read


def trained(spec: SweepSpec) -> ModuleZoo:
    """The sweep's trained modules (its train, anchor-policy and grid stages' checkpoints)."""
    return ModuleZoo.from_sweep(sweep_layout(spec).root)


def planned(spec: SweepSpec) -> ModuleZoo:
    """The modules the spec's stages train: every training trial's and anchor policy's (the train
    stage), and the cells of every grid (the grid stage), as the zoo will hold them once trained
    (same keys, stages and signatures; files under :data:`PLANNED`). A spec that trains nothing
    (stitching stages run on a trained folder) stands for the sources its trials name."""
    entries = []

    def add(data: dict, stage: str, held_out: str = "") -> None:
        key = key_of(data, held_out)
        entries.append(ZooEntry(key, PLANNED / str(key), expected_signature(data), data, stage))

    trains = "train" in spec.stages
    for trial in train.plan(spec) if trains or "grid" not in spec.stages else ():
        for source in trial.sources:  # a population's members are sources
            add(source.spec.to_dict(), "train")
    for trial in train.plain_sources(spec) if trains else ():
        add(trial.spec.to_dict(), "plain_source")
    for trial in grid.plan(spec) if "grid" in spec.stages else ():
        for cell in trial.grid.cells:
            add(trial.grid.cell_spec(cell).to_dict(), "grid", trial.grid.held_out_text)
    return ModuleZoo(entries)
