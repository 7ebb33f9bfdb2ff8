"""Task states for anchors: roll out episodes and record the task module's input
(``task_state`` then ``desired_goal``) at given time steps (docs/authors_code.md §4, step 1 of the
authors' anchor recipe; selection is :mod:`ps_ray.data.anchors`).

The desired goal in a recorded state is the episode's own (``goals="real"``, the authors'), or a
later achieved goal of the same episode (``goals="relabelled"``), drawn as hindsight relabelling's
'future' strategy draws it: the task module of a goal-conditioned policy learns mostly from
relabelled goals, and with ``"real"`` anchors never show one. On the marker family every real
desired goal is the zero offset (docs/transfer.md).

No torch and no Ray: numpy and gymnasium-style env objects only.
"""

from __future__ import annotations

import logging
import operator
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from ps_ray.errors import UserError, choice_error
from ps_ray.specs.modes import AnchorGoals
from ps_ray.specs.names import ANCHOR_GOALS

log = logging.getLogger(__name__)

Policy = Callable[[dict[str, np.ndarray]], Any]


def _task_input(obs: Mapping[str, Any]) -> np.ndarray:
    """The task input (:func:`ps_ray.envs.goals.task_input`) of one observation, flat float32."""
    from ps_ray.envs.goals import TASK_KEYS, task_input  # lazily: the envs package loads PyBullet

    return task_input({key: np.asarray(obs[key], np.float32).reshape(-1) for key in TASK_KEYS})


def _check_steps(steps: Sequence[int]) -> list[int]:
    try:
        out = [operator.index(s) for s in steps]
    except TypeError:
        raise UserError(f"steps must be integers, got {list(steps)}") from None
    if not out or min(out) < 0:
        raise UserError(f"steps must be one or more non-negative integers, got {out}")
    if len(set(out)) != len(out):
        raise UserError(f"steps must be distinct, got {out}")
    return sorted(out)


def _act(env: Any, obs: Mapping[str, Any], policy: Policy | None) -> np.ndarray:
    if policy is None:
        return env.action_space.sample()
    action = np.asarray(policy({key: np.asarray(val)[None] for key, val in obs.items()}))
    if action.ndim != 2 or action.shape[0] != 1:
        shape = action.shape
        raise ValueError(
            f"policy must return actions of shape (1, A) for a batch of one observation, got shape {shape}"
        )
    return action[0]


def collect_task_states(
    make_env: Callable[[], Any],
    *,
    episodes: int,
    steps: Sequence[int] = range(5, 10),
    policy: Policy | None = None,
    seed: int = 0,
    goals: str = "real",
) -> np.ndarray:
    """Roll out ``episodes`` episodes and record the task input at the given time steps.

    Episode ``i`` starts with ``env.reset(seed=seed + i)``; with ``policy=None`` its actions
    are uniform random from ``env.action_space`` seeded with ``seed + i``, so each episode is
    reproducible on its own. ``policy`` gets the observation batched to a leading dimension of
    1 (``{key: array[None]}``) and returns actions of shape ``(1, A)``.

    Step ``t`` is the observation before the ``t``-th action (``t = 0``: the reset
    observation), as in the authors' loop. With ``goals="real"`` each episode stops after the
    last recorded step; with ``"relabelled"`` it runs to its end, and step ``t``'s desired goal
    becomes the achieved goal of a step drawn uniformly from ``t+1`` to the last (generator
    seeded with ``seed + i``). An episode that ends before the last recorded step is an error.

    Returns an ``(episodes * len(steps), task_dim)`` float32 array, episode-major, steps in
    ascending order within an episode.
    """
    if int(episodes) != episodes or episodes < 1:
        raise UserError(f"episodes must be a positive integer, got {episodes!r}")
    if goals not in ANCHOR_GOALS:
        raise choice_error("goals", goals, ANCHOR_GOALS, "goals")
    episodes, wanted = int(episodes), _check_steps(steps)
    last, relabel = wanted[-1], goals == AnchorGoals.RELABELLED
    report_every = max(1, episodes // 10) if episodes >= 100 else 0

    rows: list[np.ndarray] = []
    env = make_env()
    try:
        for ep in range(episodes):
            obs, _ = env.reset(seed=seed + ep)
            if policy is None:
                env.action_space.seed(seed + ep)
            recorded, achieved, t = [], [np.asarray(obs["achieved_goal"], np.float32)], 0
            while True:
                if t in wanted:
                    recorded.append(_task_input(obs))
                if t == last and not relabel:
                    break
                obs, _, terminated, truncated, _ = env.step(_act(env, obs, policy))
                t += 1
                achieved.append(np.asarray(obs["achieved_goal"], np.float32))
                if (terminated or truncated) and t <= last:
                    raise ValueError(
                        f"episode {ep} ended after {t} steps, before the last recorded step {last}"
                    )
                if terminated or truncated:
                    break
            if relabel:
                rng = np.random.default_rng(seed + ep)
                for row, step in zip(recorded, wanted):
                    goal = achieved[rng.integers(step + 1, t + 1)]
                    row[-goal.size :] = goal
            rows += recorded
            if report_every and (ep + 1) % report_every == 0:
                log.info("collect_task_states: %d/%d episodes", ep + 1, episodes)
    finally:
        close = getattr(env, "close", None)
        if close is not None:
            close()
    return np.ascontiguousarray(np.stack(rows).astype(np.float32, copy=False))
