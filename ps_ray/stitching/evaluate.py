"""Batched zero-shot evaluation: a deterministic policy on fixed evaluation episodes.

Protocol (docs/authors_code.md §6): ``repeats`` x ``episodes`` episodes; episode j of repeat r is reset with
seed ``seed + r * episodes + j``, so every policy evaluated with the same seed sees exactly the same
episodes (goals, object starts). ``num_envs`` envs run in lockstep, one batched forward per step.
Per repeat:

- success: ``is_success`` after the last step, averaged over all episodes;
- touching (the authors' measure): the end effector within 0.05 m of the object in any state the
  policy acts on (checked before each action, as the authors do: the reset state and the states
  after steps 1..49), averaged over the episodes that did *not* start successful;
- contact: PyBullet robot-object contact at any step, same denominator as touching;
- wrong target (scenes that hold several candidate targets, the marker family): the end effector
  ended within the success distance of a target the task does not name, averaged over all
  episodes; NaN where the scene holds one target.

Reported: mean and (population) std over the repeats, the per-repeat values and speed. Reach has
no object, so its touching and contact are 0.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ps_ray.envs import make, task_input
from ps_ray.envs.goals import SUCCESS_DISTANCE
from ps_ray.errors import UserError
from ps_ray.nets.modular import Actor
from ps_ray.nets.obs import dims_from_spaces
from ps_ray.nets.policy import GreedyPolicy
from ps_ray.nets.sac import SACNets
from ps_ray.specs.dims import NetDims
from ps_ray.specs.names import EnvPart
from ps_ray.store.signature import Signature

Obs = dict[str, np.ndarray]
ActionFn = Callable[[Obs], np.ndarray]  # batched Dict obs (leading axis) -> actions (B, A)
PolicyLike = str | Path | tuple[SACNets, Signature] | SACNets | Actor | ActionFn


@dataclass(frozen=True)
class EpisodeRecord:
    repeat: int
    seed: int
    success: bool
    touched: bool
    contact: bool
    initially_successful: bool
    goal: tuple[float, ...]  # desired goal at reset
    start: tuple[float, ...]  # achieved goal at reset (in the named marker's frame for the marker families)
    task_input: tuple[float, ...]  # the task module's input at reset (task state, then goal)
    end_effector: tuple[float, ...]  # the end effector's final position (world frame)
    # the outcome's final distance (the object's, else the end effector's) to each candidate target
    # (env.candidate_targets(); empty where the scene holds one), and whether it ended within the
    # success distance of another one
    candidate_distances: tuple[float, ...] = ()
    wrong_target: bool = False
    object_end: tuple[float, ...] = ()  # where the object ended (world frame); () for tasks without one


def outcome_point(record: Mapping[str, Any]) -> tuple[float, ...]:
    """What an episode (an :class:`EpisodeRecord` as a dict) did, as a point: where the object
    ended, or, in a task without one (reach, the markers), where the end effector ended."""
    return tuple(record.get("object_end") or ()) or tuple(record["end_effector"])


# -- the policy -----------------------------------------------------------------------------------
def as_action_fn(policy: PolicyLike, fast: bool = True) -> tuple[ActionFn, NetDims | None]:
    """A batched action function and the dims it expects (None for a bare callable)."""
    if isinstance(policy, (str, Path)):
        from ps_ray.stitching.stitch import load_source

        policy = load_source(policy)
    if isinstance(policy, tuple):
        policy = policy[0]
    if isinstance(policy, SACNets):
        policy = policy.actor
    if isinstance(policy, nn.Module):
        fn = GreedyPolicy(policy, fast)
        return fn, fn.dims
    if callable(policy):
        return policy, None
    raise UserError(
        f"cannot evaluate a {type(policy).__name__}: give a policy file, SACNets, "
        f"an Actor or a batched action function"
    )


# -- envs ------------------------------------------------------------------------------------------
class EnvPool:
    """Envs kept between evaluations in one process: building one (loading the robot's URDF) costs
    more than a short evaluation's steps. Every episode starts with ``reset(seed)``, which sets
    the whole scene again, so an env lent twice gives the same episodes as a new one (tested).
    The envs of the ``targets`` most recently used (robot, task) are kept; others are closed. An
    env holds about 90 MB (a PyBullet client and the robot's meshes), so one target (a zero-shot
    pair's stitch and controls share it) keeps what one evaluation needs anyway (docs/cost.md)."""

    def __init__(self, targets: int = 1) -> None:
        if targets < 0:
            raise ValueError(f"an env pool keeps the envs of 0 or more targets, not {targets}")
        self.targets = targets
        self._free: dict[tuple[str, str], list] = {}

    @contextmanager
    def lend(self, robot: EnvPart, task: EnvPart, count: int) -> Iterator[list]:
        key = (robot.text, task.text)
        free = self._free.pop(key, [])
        envs = free[:count]
        try:
            while len(envs) < count:
                envs.append(make(robot, task))
        except BaseException:
            for env in envs + free[count:]:
                env.close()
            raise
        try:
            yield envs
        except BaseException:  # an env stopped mid-episode by an error is not lent again
            for env in envs + free[count:]:
                env.close()
            raise
        # the most recent target last; envs a nested lend of the same target returned are kept
        self._free[key] = self._free.pop(key, []) + envs + free[count:]
        while len(self._free) > self.targets:
            for env in self._free.pop(next(iter(self._free))):
                env.close()


_ENVS = EnvPool()


# -- aggregation ----------------------------------------------------------------------------------
def _rate(flags: Sequence[bool]) -> float:
    return float(np.mean(flags)) if len(flags) else math.nan


def _mean_std(values: Sequence[float]) -> tuple[float, float]:
    finite = [v for v in values if not math.isnan(v)]
    if not finite:
        return math.nan, math.nan
    return float(np.mean(finite)), float(np.std(finite))


def summarize(records: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """Per-repeat success / touching / contact and their mean and std over repeats."""
    repeats = sorted({r.repeat for r in records})
    out: dict[str, Any] = {
        "success_per_repeat": [],
        "touching_per_repeat": [],
        "contact_per_repeat": [],
        "initially_successful_per_repeat": [],
        "wrong_target_per_repeat": [],
    }
    for rep in repeats:
        rows = [r for r in records if r.repeat == rep]
        eligible = [r for r in rows if not r.initially_successful]
        out["success_per_repeat"].append(_rate([r.success for r in rows]))
        out["touching_per_repeat"].append(_rate([r.touched for r in eligible]))
        out["contact_per_repeat"].append(_rate([r.contact for r in eligible]))
        out["initially_successful_per_repeat"].append(len(rows) - len(eligible))
        several = [r for r in rows if len(r.candidate_distances) > 1]
        out["wrong_target_per_repeat"].append(_rate([r.wrong_target for r in several]))
    for name in ("success", "touching", "contact", "wrong_target"):
        out[f"{name}_mean"], out[f"{name}_std"] = _mean_std(out[f"{name}_per_repeat"])
    return out


# -- rollouts -------------------------------------------------------------------------------------
@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Small batched forwards gain nothing from intra-op threads, and lose a lot when the CPUs
    are busy (spinning workers), so evaluation runs torch on one thread."""
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def _stack(obs: Sequence[Obs]) -> Obs:
    return {k: np.stack([o[k] for o in obs]) for k in obs[0]}


def _run_batch(
    envs: Sequence,
    seeds: Sequence[int],
    act: ActionFn,
    repeat_of: Callable[[int], int],
    scenes: Sequence[np.ndarray | None],
) -> list[EpisodeRecord]:
    """One episode per env, in lockstep: one batched forward per step; an env with a scene (a task
    input) is reset to it. A scripted policy (the chance control, :mod:`ps_ray.stitching.chance`)
    is told the reset envs and seeds first."""
    resets = [
        env.reset(seed=s, options=None if scene is None else {"task_input": scene})
        for env, s, scene in zip(envs, seeds, scenes)
    ]
    if hasattr(act, "begin"):
        act.begin(envs, seeds)
    obs = [o for o, _ in resets]
    touched = [info["touching"] for _, info in resets]
    contact = [info["contact"] for _, info in resets]
    success = [info["is_success"] for _, info in resets]
    steps = envs[0].max_episode_steps
    for t in range(steps):
        actions = act(_stack(obs))
        for i, env in enumerate(envs):
            obs[i], _, _, _, info = env.step(actions[i])
            if t < steps - 1:  # touching is checked before each action, as the authors do
                touched[i] |= info["touching"]
            contact[i] |= info["contact"]
            success[i] = info["is_success"]  # success after the last step counts
    ends = [_candidate_ends(env) for env in envs]
    return [
        EpisodeRecord(
            repeat_of(s),
            s,
            bool(success[i]),
            bool(touched[i]),
            bool(contact[i]),
            bool(info["initially_successful"]),
            tuple(map(float, o["desired_goal"])),
            tuple(map(float, o["achieved_goal"])),
            tuple(map(float, task_input(o))),
            tuple(map(float, envs[i].ee_position)),
            *ends[i],
            tuple(map(float, envs[i].object_position)) if envs[i].task.has_object else (),
        )
        for i, (s, (o, info)) in enumerate(zip(seeds, resets))
    ]


def _candidate_ends(env) -> tuple[tuple[float, ...], bool]:
    """The outcome's distance (the object's, or the end effector's without one:
    ``env.outcome_position``) to each of the scene's candidate targets, and whether it is within
    the success distance of one the task does not name (``(), False``: one target)."""
    candidates = env.candidate_targets()
    if candidates is None:
        return (), False
    distances = np.linalg.norm(candidates - env.outcome_position, axis=-1)
    others = np.delete(distances, env.named_candidate)
    return tuple(map(float, distances)), bool((others < SUCCESS_DISTANCE).any())


def check_dims(dims: NetDims, env) -> None:
    """ValueError naming each dim where the policy and the env disagree."""
    env_dims = dims_from_spaces(env.observation_space, env.action_space)
    wrong = [
        f"{f} {getattr(dims, f)} vs env {getattr(env_dims, f)}"
        for f in ("task_dim", "robot_dim", "action_dim")
        if getattr(dims, f) != getattr(env_dims, f)
    ]
    if wrong:
        raise UserError("policy does not fit the env: " + "; ".join(wrong))


def evaluate(
    policy: PolicyLike,
    robot: str | Mapping = "panda",
    task: str | Mapping = "reach",
    *,
    episodes: int = 200,
    repeats: int = 5,
    seed: int = 0,
    num_envs: int = 8,
    verbose: bool = False,
    fast: bool = True,
    scenes: np.ndarray | None = None,
) -> dict[str, Any]:
    """Zero-shot evaluation of a deterministic policy (see the module docstring).

    Returns success/touching/contact mean, std and per-repeat values, ``initially_successful``
    per repeat, ``records`` (one :class:`EpisodeRecord` dict per episode), ``episodes_digest``
    (:func:`episodes_digest`), ``episodes_per_s`` and
    ``env_steps_per_s`` of the rollout loop (env construction excluded) and ``wall_s`` (all of it).
    ``fast``: see :class:`BatchedGreedy`. ``scenes``: task inputs (episodes x repeats rows), each
    episode reset to its row (the marker family; :mod:`ps_ray.stitching.outcomes`).
    """
    for name, value in (("episodes", episodes), ("repeats", repeats), ("num_envs", num_envs)):
        if not isinstance(value, int) or value < 1:
            raise UserError(f"{name} must be a positive integer, got {value!r}")
    robot, task = EnvPart(robot), EnvPart(task)
    act, dims = as_action_fn(policy, fast)
    seeds = [seed + r * episodes + j for r in range(repeats) for j in range(episodes)]
    if scenes is not None and len(scenes) != len(seeds):
        raise UserError(f"{len(scenes)} scenes for {len(seeds)} episodes; give one per episode")
    scene_of = [None] * len(seeds) if scenes is None else list(np.asarray(scenes, float))
    repeat_of = lambda s: (s - seed) // episodes  # noqa: E731
    started = time.perf_counter()
    label = f"{task.short}/{robot.short}"
    with _ENVS.lend(robot, task, min(num_envs, len(seeds))) as envs:
        if dims is not None:
            check_dims(dims, envs[0])
        records: list[EpisodeRecord] = []
        loop_start = time.perf_counter()
        with torch_threads(1):
            for first in range(0, len(seeds), len(envs)):
                chunk = seeds[first : first + len(envs)]
                done_before = len(records)
                records += _run_batch(
                    envs[: len(chunk)], chunk, act, repeat_of, scene_of[first : first + len(envs)]
                )
                if verbose:
                    _progress(records, done_before, episodes, repeats, loop_start, label)
        loop_s = time.perf_counter() - loop_start
        steps = envs[0].max_episode_steps
    return {
        "robot": robot.short,
        "task": task.short,
        "episodes": episodes,
        "repeats": repeats,
        "seed": seed,
        "num_envs": len(envs),
        **summarize(records),
        "episodes_per_s": len(records) / loop_s,
        "env_steps_per_s": len(records) * steps / loop_s,
        "wall_s": time.perf_counter() - started,
        "records": [asdict(r) for r in records],
        "episodes_digest": episodes_digest(records),
    }


def episodes_digest(records: Sequence[EpisodeRecord]) -> str:
    """A short hash of the episodes as they were reset (seed, goal, start): two evaluations with
    equal digests scored their policies on the same episodes."""
    text = repr([(r.seed, r.goal, r.start) for r in records])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _progress(
    records: list[EpisodeRecord], done_before: int, episodes: int, repeats: int, loop_start: float, label: str
) -> None:
    """One line per finished repeat."""
    for rep in range(done_before // episodes, len(records) // episodes):
        rows = summarize([r for r in records if r.repeat == rep])
        rate = len(records) / (time.perf_counter() - loop_start)
        print(
            f"[evaluate {label}] repeat {rep + 1}/{repeats}: success "
            f"{rows['success_mean']:.3f}, touching {rows['touching_mean']:.3f} "
            f"({len(records)}/{episodes * repeats} episodes, {rate:.1f} episodes/s)",
            flush=True,
        )


def format_result(result: Mapping[str, Any], title: str = "") -> str:
    """A small table: mean +- std and per-repeat values of each rate."""
    lines = [title] if title else []
    lines.append(
        f"target env: robot {result['robot']}, task {result['task']}; "
        f"{result['repeats']} x {result['episodes']} episodes from seed {result['seed']}; "
        f"{result['episodes_per_s']:.1f} episodes/s"
    )
    lines.append(f"{'':<10}{'mean':>8}{'std':>8}   per repeat")
    for name in ("success", "touching", "contact", "wrong_target"):
        if all(math.isnan(v) for v in result[f"{name}_per_repeat"]):
            continue
        per = " ".join(f"{v:.3f}" for v in result[f"{name}_per_repeat"])
        lines.append(f"{name:<10}{result[name + '_mean']:>8.3f}{result[name + '_std']:>8.3f}   {per}")
    n_init = sum(result["initially_successful_per_repeat"])
    lines.append(f"(touching and contact exclude the {n_init} episodes that started successful)")
    return "\n".join(lines)
