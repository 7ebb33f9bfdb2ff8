"""The stitching matrix of a sweep: one record per stitched pair, with its sources, target env
and controls (the zero-shot trials' configs, few-shot's starts and the report's clips read these)."""

from __future__ import annotations

from typing import Any

from ps_ray.specs.sweep import SweepSpec, seed_pairs
from ps_ray.store.layout import sweep_dir


def pairs(
    spec: SweepSpec, methods: list[str] | None = None, translate: bool = False, pairing: str = "same_seed"
) -> list[dict[str, Any]]:
    """One trial config per stitched pair of the sweep's trained policies (``pairing``: see
    :func:`seed_pairs`), with the zoo keys and files of its controls
    (:func:`ps_ray.stitching.stitch.controls`); with ``translate``, also one per latent
    translation that ``spec.zero_shot.translate`` names for the method (its method shown as
    ``<method>+<translation>``)."""
    from ps_ray.stitching.stitch import combos, controls
    from ps_ray.stitching.zoo import ModuleZoo

    zoo = ModuleZoo.from_sweep(sweep_dir(spec))
    out = []
    for method in methods or spec.methods:
        kinds = ("", *spec.zero_shot.translations(method)) if translate else ("",)
        for kind_of_pair, seed, robot_seed in seed_pairs(spec.seeds, pairing):
            for combo in combos(zoo, method, seed, robot_seed=robot_seed):
                seeds = str(seed) if kind_of_pair == "same_seed" else f"{seed}x{robot_seed}"
                for kind in kinds:
                    name = f"{method}+{kind}" if kind else method
                    out.append(
                        {
                            "key": f"zero_shot/{name}/{combo.label}/{seeds}",
                            "method": name,
                            "translation": kind,
                            "pairing": kind_of_pair,
                            "seed": seed,
                            "robot_seed": robot_seed,
                            "label": combo.label,
                            "task_from": str(combo.task_from.key),
                            "robot_from": str(combo.robot_from.key),
                            "task_from_path": str(combo.task_from.path),
                            "robot_from_path": str(combo.robot_from.path),
                            "fit_tasks": [combo.task_from.spec["task"], combo.robot_from.spec["task"]],
                            "robot": combo.robot,
                            "task": combo.task,
                            "controls": {
                                role: {"source": str(entry.key), "path": str(entry.path)}
                                for role, entry in controls(zoo, combo).items()
                            },
                        }
                    )
    return out
