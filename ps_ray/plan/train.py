"""The training stages' trials: the plain policies the anchors are drawn from, and the sweep's
sources (one per drawn setting of a search)."""

from __future__ import annotations

import json

from ps_ray.envs.core import env_widths
from ps_ray.specs.modes import AnchorPolicy
from ps_ray.specs.population import shared_settings
from ps_ray.specs.sweep import SweepSpec, anchor_sources, task_input_dim
from ps_ray.specs.train import TrainSpec
from ps_ray.specs.trial import PopulationTrial, TrainTrial
from ps_ray.store.layout import sweep_layout


def anchor_file(spec: SweepSpec, trial: TrainSpec) -> str | None:
    """The one place that decides where a PS trial of this sweep (train, grid, few-shot scratch)
    gets its anchors: the sweep's anchor set for the trial's task-input width and K. None for
    methods without anchors. (A stitched start carries its anchors in its policy file.)"""
    if not trial.resolved.uses_anchors:
        return None
    return str(sweep_layout(spec).anchor_set(task_input_dim(trial.task), trial.interface_dim))


def plain_sources(spec: SweepSpec) -> list[TrainTrial]:
    """The plain policies whose greedy rollouts give the anchor states (anchors.policy plain,
    without an anchor file); none otherwise."""
    if spec.anchors.policy != AnchorPolicy.PLAIN or spec.anchors.file:
        return []
    return [TrainTrial(source) for source in anchor_sources(spec)]


def plan(spec: SweepSpec) -> list[TrainTrial | PopulationTrial]:
    """The train stage's trials: each source with its anchor set; a search's, each named by its
    drawn setting (run ``<trial key>/searchNN``). With ``population`` K above 1, the sources in
    trials of up to K that share everything but robot, task and seed (and their widths), in
    the sweep's order; a source left over alone is a trial of its own."""
    sources = [
        TrainTrial(t, anchor_file(spec, t), key=f"{t.label()}/{name}" if name else "", label=name)
        for name, t in spec.named_trials()
    ]
    if spec.population == 1:
        return sources
    groups: dict[str, list[TrainTrial]] = {}
    for source in sources:
        shape = json.dumps([shared_settings(source.spec), _widths(source.spec)], sort_keys=True)
        groups.setdefault(shape, []).append(source)
    k = spec.population
    chunks = [group[i : i + k] for group in groups.values() for i in range(0, len(group), k)]
    return [PopulationTrial(tuple(c)) if len(c) > 1 else c[0] for c in chunks]  # one left over: alone


def _widths(spec: TrainSpec) -> tuple[int, int, int] | None:
    return None if spec.env is not None else env_widths(spec.robot, spec.task)
