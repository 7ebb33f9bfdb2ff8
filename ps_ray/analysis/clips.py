"""Rollout clips for the report: the same stitched pairs, from the same start state, under every
method, beside the two source policies each was built from; small GIFs rendered headless."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ps_ray.plan.catalogue import trained
from ps_ray.plan.zero_shot import evaluated_pairs
from ps_ray.specs import reset_seeds
from ps_ray.specs.names import short_name
from ps_ray.specs.sweep import SweepSpec
from ps_ray.stitching.pair_table import pairs_from_table
from ps_ray.stitching.pairs import StitchedPair
from ps_ray.store.layout import sweep_layout

CLIP_SIZE = (240, 180)  # pixels; every second step, so a clip is about 26 frames
START_SEED = reset_seeds.fixed("clips")  # the env reset every clip starts from


ROLES = ("stitched", "task source", "robot source")


@dataclass(frozen=True)
class Clip:
    method: str
    role: str  # one of ROLES
    env: str  # robot and task it ran in
    path: Path
    success: bool
    distance: float  # final distance (m) from the goal


def _clip(policy_file_or_nets, robot, task, path: Path, method: str, role: str) -> Clip:
    from ps_ray.envs import make
    from ps_ray.envs.render import rollout, save_gif
    from ps_ray.nets.policy import GreedyPolicy

    actor = policy_file_or_nets.actor if hasattr(policy_file_or_nets, "actor") else None
    policy = GreedyPolicy(actor) if actor is not None else GreedyPolicy.from_file(policy_file_or_nets)
    env = make(robot, task, render_mode="rgb_array", render_size=CLIP_SIZE)
    try:
        frames, success, distance = rollout(env, policy, seed=START_SEED, every=2)
        fps = env.metadata["render_fps"] / 2
    finally:
        env.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    save_gif(frames, path, fps=fps)
    return Clip(method, role, f"{short_name(robot)}, {short_name(task)}", path, success, distance)


def stitched_clips(spec: SweepSpec, out_dir: Path, pairs_per_method: int = 2) -> list[tuple[str, list[Clip]]]:
    """Rows of clips: per chosen pair (the first ``pairs_per_method`` that every method has, at the
    first seed), each method's stitched policy in the target env, then its two sources in their
    own envs. The pairs and their sources' files and envs are the zero-shot table's records
    (:func:`ps_ray.plan.zero_shot.evaluated_pairs`). Returns (pair label, clips) rows; empty when
    the sweep has no stitchable pairs."""
    from ps_ray.stitching.stitch import stitch_policies

    methods = list(spec.zero_shot.methods) or list(spec.methods)
    found: dict[str, dict[str, StitchedPair]] = {}
    table = pairs_from_table(sweep_layout(spec).zero_shot_table)
    for pair in evaluated_pairs(spec, table, lambda: trained(spec), methods):
        if pair.seed == spec.seeds[0]:
            found.setdefault(pair.label, {})[pair.method] = pair
    labels = [label for label, by_method in found.items() if set(methods) <= set(by_method)]
    rows = []
    for number, label in enumerate(labels[:pairs_per_method]):
        clips = []
        for method in methods:
            pair = found[label][method]
            nets, _ = stitch_policies(pair.task_from_path, pair.robot_from_path)
            stem = f"pair{number}_{method}"
            clips.append(_clip(nets, pair.robot, pair.task, out_dir / f"{stem}.gif", method, "stitched"))
            sources = (
                ("task source", pair.task_from_path, pair.task_from_robot, pair.task),
                ("robot source", pair.robot_from_path, pair.robot_from_robot, pair.robot_from_task),
            )
            for role, path, robot, task in sources:
                clips.append(
                    _clip(path, robot, task, out_dir / f"{stem}_{role.split()[0]}.gif", method, role)
                )
        rows.append((label, clips))
    return rows
