"""GridEnv: the trained cells of a robot x task grid stepped side by side, one env per cell.

Co-training (Devin et al. 2017; docs/transfer.md "Co-trained grids") updates shared task and robot
modules on every cell at once, so one env runner collects one episode of every cell per episode:
the observation is a Dict of the cells' own Dict observations (keys :func:`cell_key`), the action
the cells' actions side by side. Each cell keeps its own physics, seed, reward and info; the
grid's reward is their sum (the learner never reads it: hindsight replay recomputes each cell's).
All cells truncate after the same ``max_episode_steps``.

A population of sources (:mod:`ps_ray.rllib.population_sac`) steps its members the same way, but
each member resets as its own source would: ``seed_offsets`` gives each cell's offset from the
env's reset seed (``seed + offset``: the member's own reset-seed block), instead of the grid's
``seed * n + i``. A member that stops is frozen (:meth:`GridEnv.freeze`): its env is neither
stepped nor reset again, so its CPU goes to the members still training.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .core import make


def cell_key(index: int) -> str:
    """The observation and info key of the grid's ``index``-th trained cell (sorts in order)."""
    return f"c{index:02d}"


def make_cell(config: Mapping[str, Any]) -> gym.Env:
    """A cell's env: ``{"robot": ..., "task": ..., **options}``, or a gymnasium env ``{"id": ...}``
    (a population of sources of one registered env, as ``ps-ray train --env`` trains one)."""
    if "id" in config:
        return gym.make(config["id"])
    return make(**dict(config))


class GridEnv(gym.Env):
    """``cells``: the env configs of the trained cells (:func:`make_cell`);
    ``seed_offsets``: each cell's reset seed is the env's plus its offset (None: a grid's)."""

    def __init__(self, cells: Sequence[Mapping[str, Any]], seed_offsets: Sequence[int] | None = None) -> None:
        if not cells:
            raise ValueError("a grid env needs at least one cell")
        if seed_offsets is not None and len(seed_offsets) != len(cells):
            raise ValueError(f"{len(seed_offsets)} seed offsets for {len(cells)} cells")
        self.seed_offsets = None if seed_offsets is None else [int(o) for o in seed_offsets]
        self.envs: list[gym.Env] = [make_cell(cell) for cell in cells]
        self.keys = [cell_key(i) for i in range(len(self.envs))]
        self.observation_space = spaces.Dict({k: e.observation_space for k, e in zip(self.keys, self.envs)})
        self.action_dims = [e.action_space.shape[0] for e in self.envs]
        self.action_space = spaces.Box(-1.0, 1.0, shape=(sum(self.action_dims),), dtype=np.float32)
        self.max_episode_steps = self.envs[0].unwrapped.max_episode_steps
        self._cuts = np.cumsum(self.action_dims)[:-1]
        self.frozen: frozenset[int] = frozenset()
        self._latest: list[tuple[Any, dict]] = []  # each cell's latest (observation, info)

    def freeze(self, indices: Sequence[int]) -> None:
        """Step and reset these cells no more (a population's stopped members): each repeats its
        latest observation and info, with no reward, and the episode ends when the live cells'
        do. The live cells step exactly as they would beside them (each cell has its own physics)."""
        frozen = frozenset(int(i) for i in indices)
        if len(frozen) >= len(self.envs) or not frozen <= set(range(len(self.envs))):
            raise ValueError(f"cells {sorted(frozen)} cannot be frozen in a grid of {len(self.envs)}")
        self.frozen = frozen

    def split_actions(self, actions: np.ndarray) -> list[np.ndarray]:
        """The grid's actions (any batch shape) as each cell's, in cell order."""
        return np.split(np.asarray(actions), self._cuts, axis=-1)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._latest = [
            self._latest[i]
            if i in self.frozen and self._latest
            else env.reset(seed=self.cell_seed(seed, i), options=options)
            for i, env in enumerate(self.envs)
        ]
        return {k: r[0] for k, r in zip(self.keys, self._latest)}, {
            k: r[1] for k, r in zip(self.keys, self._latest)
        }

    def cell_seed(self, seed: int | None, index: int) -> int | None:
        """The reset seed of cell ``index`` when the env is reset with ``seed``."""
        if seed is None:
            return None
        if self.seed_offsets is None:
            return seed * len(self.envs) + index
        return seed + self.seed_offsets[index]

    def step(self, action: np.ndarray):
        actions = self.split_actions(action)
        live = {i: self.envs[i].step(actions[i]) for i in range(len(self.envs)) if i not in self.frozen}
        for i, r in live.items():
            self._latest[i] = (r[0], r[4])
        obs = {k: r[0] for k, r in zip(self.keys, self._latest)}
        infos = {k: r[1] for k, r in zip(self.keys, self._latest)}
        reward = float(sum(r[1] for r in live.values()))
        results = live.values()
        return obs, reward, all(r[2] for r in results), all(r[3] for r in results), infos

    def close(self) -> None:
        for env in self.envs:
            env.close()
