"""The train stage's anchor sets: one per (task-input width, k), pooled over that width's source
tasks, made by the driver between the anchors' plain sources and the training trials (the grid
stage makes its own the same way). Where each goes: :func:`ps_ray.plan.train.anchor_file`."""

from __future__ import annotations

from functools import partial
from pathlib import Path

from ps_ray.plan.train import anchor_file
from ps_ray.specs import reset_seeds
from ps_ray.specs.modes import AnchorPolicy
from ps_ray.specs.sweep import SweepSpec, anchor_sources, task_input_dim


def prepare_sweep_anchors(
    spec: SweepSpec, plain_policies: dict[str, Path] | None = None
) -> dict[tuple[int, int], str]:
    """One anchor set per (task-input width, k), pooled over that width's source tasks, each
    written once (an existing file is kept); returns their paths.

    States come from `spec.anchors.file`, from greedy rollouts of the trained plain policies
    (policy: plain: ``plain_policies``, by source label) or from random-action rollouts (policy: random).
    """
    from ps_ray.data.anchor_file import anchors_from_file, save_anchor_set
    from ps_ray.data.anchors import make_anchor_set
    from ps_ray.data.collect import collect_task_states
    from ps_ray.envs import make
    from ps_ray.nets.policy import GreedyPolicy

    ps = [t for t in spec.trials() if t.resolved.uses_anchors]
    sources = anchor_sources(spec) if ps else []
    paths: dict[tuple[int, int], str] = {}
    for t in ps:
        paths.setdefault((task_input_dim(t.task), t.interface_dim), anchor_file(spec, t))
    for (dim, k), name in sorted(paths.items()):
        path = Path(name)
        if path.exists():
            continue
        if spec.anchors.file:
            anchor_set = anchors_from_file(spec.anchors.file, k, seed=spec.anchors.seed)
        else:
            states = {}
            for source in (s for s in sources if task_input_dim(s.task) == dim):
                policy = None
                if spec.anchors.policy == AnchorPolicy.PLAIN:
                    policy = GreedyPolicy.from_file(plain_policies[source.label()])
                states[source.task.text] = collect_task_states(
                    lambda source=source: make(source.robot, source.task),
                    episodes=spec.anchors.episodes,
                    steps=spec.anchors.steps,
                    policy=policy,
                    seed=reset_seeds.fixed("anchors", spec.anchors.seed),
                    goals=spec.anchors.goals,
                )
            anchor_set = make_anchor_set(
                states,
                k,
                seed=spec.anchors.seed,
                extra_provenance={
                    "policy": spec.anchors.policy,
                    "goals": spec.anchors.goals,
                    "robot": spec.anchors.robot.spelling,
                    "steps": list(spec.anchors.steps),
                    "episodes": spec.anchors.episodes,
                    "checkpoints": {s: str(p) for s, p in (plain_policies or {}).items()},
                },
            )
        path.parent.mkdir(parents=True, exist_ok=True)
        save_anchor_set(path, anchor_set)
    return paths


def missing_anchor_sets(spec: SweepSpec) -> bool:
    """Whether an anchor set the sweep's trials read is not written yet."""
    paths = [Path(p) for p in map(partial(anchor_file, spec), spec.trials()) if p is not None]
    return any(not p.exists() for p in paths)
