"""Every stage's plan in one shape: ``PLANS[stage](spec, catalogue) -> list[record]``, on the
catalogue of what was trained (a stage's runner) or of what the spec implies (the cost model,
``--check``). The train and grid stages make the catalogue and read none; few-shot starts from
the zero-shot plan's same-seed pairs (its runner takes them from the zero-shot table, which
holds the same pairs with the files they were scored with)."""

from __future__ import annotations

from collections.abc import Callable

from ps_ray.plan import few_shot, grid, train, zero_shot
from ps_ray.specs.sweep import SweepSpec
from ps_ray.stitching.zoo import ModuleZoo


def _few_shot(spec: SweepSpec, zoo: ModuleZoo) -> list:
    pairs = zero_shot.alone_pairs(spec, zoo, list(spec.few_shot.methods) or None)
    return few_shot.plan(spec, zoo, pairs)


PLANS: dict[str, Callable[[SweepSpec, ModuleZoo], list]] = {
    "train": lambda spec, zoo: train.plan(spec),
    "grid": lambda spec, zoo: grid.plan(spec),
    "zero_shot": lambda spec, zoo: zero_shot.plan(spec, zoo),
    "few_shot": _few_shot,
}
