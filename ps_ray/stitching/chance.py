"""The controls with no task knowledge: chance, and the task-blind floor, on a pair's episodes.

A stitched pair's unstitched sources can fail at zero by construction (the robot source reaches the
wrong marker every time), so a stitched policy above them is not yet a policy that knows the task.
Chance is the level any purposeful mover of the target robot reaches without knowing what the task
means (docs/controls.md, "Chance"). Two such policies are scored on the pair's own evaluation
episodes, and the higher is the control:

- ``random_point``: each episode, drive the end effector (inverse kinematics on the target robot)
  to one point drawn uniformly from the task's target region (``env.target_region()``: the box
  every target is drawn from; on the marker family the marker box, which reaches the named marker
  about 8% of the time);
- ``random_actions``: uniform random actions.

Chance is a floor for moving purposefully; the **task-blind floor** is the floor for a transfer
claim: the best policy that lacks only the knowledge being transferred (docs/controls.md, "The
task-blind floor"). It can do every task that shares the target's scene on the target robot but
is not told which one: it drives the end effector to one of the scene's candidate targets
(``env.candidate_targets()``: on the marker family every marker) chosen uniformly. Its success is
taken in expectation over that choice, not from one draw: each episode is run once per candidate
(:class:`DriveTo`), and the floor is the mean over candidates (``task_blind``), per episode and so
over episodes, with no draw noise. On the two-marker family it is half of what driving to the
named marker reaches (about 0.5). Its wrong-target rate is the same mean. Where the family's
tasks do not share a scene (one candidate) it is absent (NaN); where an object must be moved to
the candidate (the push family) driving the hand there does no task, and the floor is the mean
over candidates of the oracle trained on each candidate's task (:func:`oracle_floor`; NaN where
the sweep trained none).

Chance draws from the episode's seed alone, and the floor draws nothing, so both are
deterministic and every pair with the same target env and episodes gets the same figure. No
torch, no Ray.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

_STREAM = 0x5EED_C4A7  # keeps these draws apart from the env's own use of the episode seed


class RandomPoint:
    """Each episode: one target point ~ U(target region); every step moves toward it."""

    def begin(self, envs: Sequence, seeds: Sequence[int]) -> None:
        """Called by :func:`ps_ray.stitching.evaluate.evaluate` once the batch's envs are reset."""
        self.envs = list(envs)
        self.points = [self.point(env, seed) for env, seed in zip(envs, seeds)]

    def point(self, env, seed: int) -> np.ndarray:
        """The episode's target point, drawn from its seed."""
        low, high = env.target_region()
        return np.random.default_rng([_STREAM, seed]).uniform(low, high)

    def __call__(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        return np.stack([env.action_toward(point) for env, point in zip(self.envs, self.points)])


class RandomActions:
    """Uniform random actions in [-1, 1], drawn from the episode's seed."""

    def begin(self, envs: Sequence, seeds: Sequence[int]) -> None:
        self.rngs = [np.random.default_rng([_STREAM, 1, seed]) for seed in seeds]
        self.dim = envs[0].action_space.shape[0]

    def __call__(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        return np.stack([rng.uniform(-1.0, 1.0, self.dim) for rng in self.rngs])


class DriveTo(RandomPoint):
    """Each episode: the scene's candidate target ``index`` (``env.candidate_targets()``, whatever
    the task names); every step moves toward it. One term of the task-blind floor."""

    def __init__(self, index: int) -> None:
        self.index = index

    def point(self, env, seed: int) -> np.ndarray:
        candidates = env.candidate_targets()
        if candidates is None:
            raise ValueError(f"{env.task_spec.name}: one target per scene, no task-blind floor")
        return candidates[self.index]


def candidate_count(task) -> int:
    """How many candidate targets the target env's scene holds (1: no task-blind floor)."""
    from ps_ray.envs.tasks import resolve_task
    from ps_ray.specs.names import EnvPart

    return resolve_task(EnvPart(task)).candidate_count


def task_blind(robot, task, settings: Mapping[str, Any]) -> dict[str, Any]:
    """The task-blind floor in expectation on the episodes ``settings`` name: each episode driven
    to every candidate target in turn (:class:`DriveTo`), ``task_blind_success`` and
    ``task_blind_wrong_target`` the means over candidates, ``task_blind_per_candidate`` each
    candidate's success, ``task_blind_per_episode`` the floor of each episode (the mean over
    candidates of reaching the named target from it) and the episodes' digest."""
    from ps_ray.stitching.evaluate import evaluate

    return _mean_over_candidates(
        [evaluate(DriveTo(i), robot, task, **settings) for i in range(candidate_count(task))]
    )


def _mean_over_candidates(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The floor in expectation from one evaluation per candidate, on the same episodes."""
    if len({run["episodes_digest"] for run in runs}) != 1:  # a bug, never bad input
        raise RuntimeError("the task-blind floor's candidates ran on other episodes")
    per_episode = np.mean([[r["success"] for r in run["records"]] for run in runs], axis=0)
    return {
        "task_blind_success": float(np.mean([run["success_mean"] for run in runs])),
        "task_blind_wrong_target": float(np.mean([run["wrong_target_mean"] for run in runs])),
        "task_blind_per_candidate": [run["success_mean"] for run in runs],
        "task_blind_per_episode": per_episode.tolist(),
        "episodes_digest": runs[0]["episodes_digest"],
    }


def oracle_floor(robot, task, settings: Mapping[str, Any], oracles: Sequence[Any]) -> dict[str, Any]:
    """The task-blind floor in expectation where no script does the scene's tasks (the push
    family): ``oracles[c]`` is a policy trained on the scene's candidate task ``c`` on the target
    robot (:func:`scene_oracles`), run as it is on the target's episodes, so each does task ``c``
    as well as it can whatever the target names; the floor is the mean over candidates, per
    episode and so over episodes (as :func:`task_blind`'s, whose keys it returns)."""
    from ps_ray.stitching.evaluate import evaluate

    if len(oracles) != candidate_count(task):  # a bug, never bad input
        raise RuntimeError(f"{len(oracles)} oracles for {candidate_count(task)} candidate targets")
    return _mean_over_candidates([evaluate(policy, robot, task, **settings) for policy in oracles])


def scene_oracles(zoo, robot, task, seed: int) -> dict[str, list[str]]:
    """Per method and interface width (``<method>/i<dim>``), the policy files the sweep trained
    alone at ``seed`` on the target robot for every candidate task of the target's scene, in
    candidate order (the same family and options, another ``target``); a method and width missing
    any candidate is left out."""
    import dataclasses

    from ps_ray.envs.tasks import resolve_task
    from ps_ray.specs.names import EnvPart

    spec, robot = resolve_task(EnvPart(task)), EnvPart(robot)
    wanted = [dataclasses.replace(spec.options, target=c) for c in range(spec.candidate_count)]
    found: dict[str, dict[int, str]] = {}
    for entry in zoo.select(seed=seed):
        if entry.stage != "train" or EnvPart(entry.key.robot) != robot:
            continue
        other = resolve_task(EnvPart(entry.key.task))
        if other.family is spec.family and other.options in wanted:
            kind = f"{entry.key.method}/i{entry.key.interface_dim}"
            found.setdefault(kind, {})[wanted.index(other.options)] = str(entry.path)
    complete = {m: files for m, files in found.items() if len(files) == len(wanted)}
    return {m: [files[c] for c in range(len(wanted))] for m, files in complete.items()}


POLICIES: dict[str, Callable[[], Any]] = {"random_point": RandomPoint, "random_actions": RandomActions}
CHANCE_POLICIES = tuple(POLICIES)


def has_floor(task) -> bool:
    """Whether the target's scene holds several candidate targets (a task-blind floor exists)."""
    return candidate_count(task) > 1


def scripted_floor(task) -> bool:
    """Whether :func:`task_blind` measures the floor: several candidates, and the hand's place is
    the task's outcome (the markers), so driving the hand to a candidate does that candidate's
    task. Where an object must be moved there (the push family) no script does each task as well
    as its oracle, and the floor is the mean of the scene's tasks' oracles instead
    (:func:`oracle_floor`)."""
    from ps_ray.envs.tasks import resolve_task
    from ps_ray.specs.names import EnvPart

    return has_floor(task) and not resolve_task(EnvPart(task)).has_object


def chance(
    robot, task, settings: Mapping[str, Any], oracles: Mapping[str, Sequence[Any]] | None = None
) -> dict[str, Any]:
    """Each chance policy's success on the episodes ``settings`` (``evaluate``'s episodes, repeats,
    seed) name, ``chance_success`` (the higher), ``chance_policy`` (which), the task-blind floor's
    success and wrong-target rate (``task_blind_success``, ``task_blind_wrong_target``; NaN where
    the scene holds one target; the floor in expectation: :func:`task_blind` where a script does
    the tasks, else the best method's :func:`oracle_floor` of ``oracles`` (method -> the scene's
    oracles, :func:`scene_oracles`), named in ``task_blind_policy``; NaN without them) and the
    episodes' digest (:func:`ps_ray.stitching.evaluate.episodes_digest`), to check a pair ran on
    the same ones."""
    from ps_ray.stitching.evaluate import evaluate

    out: dict[str, Any] = {}
    for name in CHANCE_POLICIES:
        result = evaluate(POLICIES[name](), robot, task, **settings)
        out[f"{name}_success"] = result["success_mean"]
        out["episodes_digest"] = result["episodes_digest"]
    best = max(CHANCE_POLICIES, key=lambda name: out[f"{name}_success"])
    out.update(chance_success=out[f"{best}_success"], chance_policy=best)
    out.update(task_blind_success=np.nan, task_blind_wrong_target=np.nan, task_blind_policy="")
    floors = {}
    if scripted_floor(task):
        floors["drive_to"] = task_blind(robot, task, settings)
    elif has_floor(task):
        floors = {f"{m} oracles": oracle_floor(robot, task, settings, o) for m, o in (oracles or {}).items()}
    if floors:
        best = max(floors, key=lambda name: floors[name]["task_blind_success"])
        if floors[best]["episodes_digest"] != out["episodes_digest"]:  # a bug, never bad input
            raise RuntimeError("the task-blind floor ran on other episodes than chance")
        out["task_blind_success"] = floors[best]["task_blind_success"]
        out["task_blind_wrong_target"] = floors[best]["task_blind_wrong_target"]
        out["task_blind_policy"] = best
    return out
