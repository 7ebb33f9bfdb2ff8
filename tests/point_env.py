"""A trivial goal-conditioned point-mass env with the same observation layout as the robot envs,
for tests: it needs no physics engine, so learning tests of the SAC + HER machinery run in seconds.

Trained as any gymnasium env of that layout is, by its id (``ps-ray train --env`` :data:`POINT_ENV`):
gymnasium imports this module from the id and makes the env registered here."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from ps_ray.envs.goals import SUCCESS_DISTANCE, goal_reward


class PointGoalEnv(gym.Env):
    """Move a point in the plane onto a goal. robot_state = position, task_state is empty."""

    metadata = {"render_modes": []}

    def __init__(self, max_episode_steps: int = 20, step_size: float = 0.1, goal_range: float = 0.5):
        self.max_episode_steps, self.step_size = max_episode_steps, step_size
        self.goal_range = goal_range
        box = lambda n, lim: gym.spaces.Box(-lim, lim, (n,), np.float32)  # noqa: E731
        self.observation_space = gym.spaces.Dict(
            robot_state=box(2, 1.0),
            task_state=box(0, 1.0),
            achieved_goal=box(2, 1.0),
            desired_goal=box(2, 1.0),
        )
        self.action_space = box(2, 1.0)
        self._pos = np.zeros(2, np.float32)
        self._goal = np.zeros(2, np.float32)
        self._t = 0

    def _obs(self) -> dict[str, np.ndarray]:
        return {
            "robot_state": self._pos.copy(),
            "task_state": np.zeros(0, np.float32),
            "achieved_goal": self._pos.copy(),
            "desired_goal": self._goal.copy(),
        }

    def _info(self, initially: bool = False) -> dict:
        success = bool(np.linalg.norm(self._pos - self._goal) < SUCCESS_DISTANCE)
        return {"is_success": success, "touching": False, "contact": False, "initially_successful": initially}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._t = 0
        self._pos = np.zeros(2, np.float32)
        self._goal = self.np_random.uniform(-self.goal_range, self.goal_range, 2).astype(np.float32)
        self._initially = self._info()["is_success"]
        return self._obs(), self._info(self._initially)

    def step(self, action):
        action = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
        self._pos = np.clip(self._pos + self.step_size * action, -1.0, 1.0).astype(np.float32)
        self._t += 1
        obs = self._obs()
        reward = float(self.compute_reward(obs["achieved_goal"], obs["desired_goal"], None))
        return obs, reward, False, self._t >= self.max_episode_steps, self._info(self._initially)

    def compute_reward(self, achieved_goal, desired_goal, info):
        return goal_reward(achieved_goal, desired_goal)


POINT_ENV = "tests.point_env:PointGoal-v0"  # the module gymnasium imports, then the id it registers
if "PointGoal-v0" not in gym.registry:
    gym.register("PointGoal-v0", entry_point=PointGoalEnv)
