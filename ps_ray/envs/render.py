"""Headless rollouts to pictures: a PNG of one frame and/or an animated GIF."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .core import RobotTaskEnv, make
from .goals import goal_distance

Policy = Callable[[dict[str, np.ndarray]], np.ndarray]


def rollout(
    env: RobotTaskEnv,
    policy: Policy | None = None,
    seed: int | None = 0,
    steps: int | None = None,
    every: int = 1,
) -> tuple[list[np.ndarray], bool, float]:
    """Run one episode (``policy(obs) -> action``; random actions if None); returns RGB frames,
    the initial one, one every ``every`` steps and the last, whether the last step succeeded, and
    the final distance (m) between the achieved and the desired goal. ``env`` needs
    ``render_mode="rgb_array"``."""
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    frames, success = [env.render()], False
    for t in range(steps or env.max_episode_steps):
        action = env.action_space.sample() if policy is None else policy(obs)
        obs, _, terminated, truncated, info = env.step(action)
        success = bool(info["is_success"])
        if (t + 1) % every == 0:
            frames.append(env.render())
        if terminated or truncated:
            break
    if (t + 1) % every:
        frames.append(env.render())
    distance = float(goal_distance(obs["achieved_goal"], obs["desired_goal"]))
    return frames, success, distance


def save_png(frame: np.ndarray, path: str | Path) -> Path:
    from PIL import Image  # Pillow comes with matplotlib

    Image.fromarray(frame).save(path)
    return Path(path)


def save_gif(frames: list[np.ndarray], path: str | Path, fps: float = 25.0) -> Path:
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)
    return Path(path)


def record(
    robot: str | Mapping = "panda",
    task: str | Mapping = "reach",
    policy: Policy | None = None,
    *,
    seed: int | None = 0,
    png: str | Path | None = None,
    gif: str | Path | None = None,
    every: int = 1,
    **options: Any,
) -> list[np.ndarray]:
    """Roll out ``policy`` in a fresh env and write the last frame to ``png`` and all to ``gif``
    (without a ``gif``, only the first and last frames are rendered)."""
    env = make(robot, task, render_mode="rgb_array", **options)
    try:
        every = every if gif is not None else env.max_episode_steps
        frames, _, _ = rollout(env, policy, seed=seed, every=every)
    finally:
        env.close()
    if png is not None:
        save_png(frames[-1], png)
    if gif is not None:
        save_gif(frames, gif, fps=env.metadata["render_fps"] / every)
    return frames
