"""RobotTaskEnv: one robot variant x one task variant as a goal-conditioned gymnasium env."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ps_ray.errors import UserError

from .camera import Camera
from .goals import GOAL_DIM, SUCCESS_DISTANCE, goal_distance, goal_reward
from .robots import ROBOT_STATE_DIM, Panda, RobotSpec, action_dim, resolve_robot
from .sim import Sim
from .tasks import TaskSpec, resolve_task

EPISODE_STEPS = 50
TOUCH_DISTANCE = 0.05  # the authors' "touching": end effector within 5 cm of the object centre
Obs = dict[str, np.ndarray]

OBS_BOUND = 100.0  # finite (gymnasium warns on infinite bounds), far beyond any physical value


def effective_gripper(robot: str | Mapping | RobotSpec, task: str | Mapping | TaskSpec) -> bool:
    """Whether ``robot`` has a working gripper in ``task`` (a robot's None: the task's default)."""
    spec = resolve_robot(robot)
    return resolve_task(task).family.default_gripper if spec.gripper is None else spec.gripper


def env_widths(robot: str | Mapping | RobotSpec, task: str | Mapping | TaskSpec) -> tuple[int, int, int]:
    """(task input, robot state, action) widths of ``make(robot, task)``, without building it."""
    return resolve_task(task).input_dim, ROBOT_STATE_DIM, action_dim(effective_gripper(robot, task))


def _box(dim: int) -> spaces.Box:
    return spaces.Box(-OBS_BOUND, OBS_BOUND, shape=(dim,), dtype=np.float32)


class RobotTaskEnv(gym.Env[Obs, np.ndarray]):
    """Goal-conditioned Panda env with the robot/task observation split of Policy Stitching.

    Observation (float32): ``robot_state`` (8: arm joint angles + finger width), ``task_state``
    (12 for object tasks: position, Euler angles, linear and angular velocity; 0 for reach),
    ``achieved_goal`` (3) and ``desired_goal`` (3). The end effector's pose is not observed.
    Reward: 0 within 0.05 m of the goal, else -1. Episodes truncate after ``max_episode_steps``
    and never terminate.

    ``info`` (also from ``reset``): ``is_success`` (distance < 0.05), ``touching`` (end effector
    within 0.05 m of the object centre), ``contact`` (PyBullet contact points between robot and
    object at the end of the step), ``initially_successful`` (success at reset). Reach has no
    object: ``touching`` and ``contact`` are False.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(
        self,
        robot: str | RobotSpec | Mapping = "panda",
        task: str | Mapping | TaskSpec = "reach",
        *,
        render_mode: str | None = None,
        max_episode_steps: int = EPISODE_STEPS,
        render_size: tuple[int, int] = (Camera.width, Camera.height),
        **task_options: Any,
    ) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise UserError(f"unknown render_mode {render_mode!r}; valid render_modes: None, rgb_array")
        self.robot_spec = resolve_robot(robot)
        self.task_spec = resolve_task(task, **task_options)
        gripper = effective_gripper(self.robot_spec, self.task_spec)
        self.render_mode = render_mode
        self.max_episode_steps = max_episode_steps
        self.sim = Sim()
        self.robot = Panda(self.sim, self.robot_spec, gripper)
        self.task = self.task_spec.family(self.sim, self.task_spec.options)
        self.camera = Camera(width=render_size[0], height=render_size[1])
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.robot.action_dim,), dtype=np.float32)
        self.observation_space = spaces.Dict(
            {
                "robot_state": _box(ROBOT_STATE_DIM),
                "task_state": _box(self.task_spec.input_dim - GOAL_DIM),
                "achieved_goal": _box(GOAL_DIM),
                "desired_goal": _box(GOAL_DIM),
            }
        )
        self._steps = 0
        self._initially_successful = False

    # -- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Obs, dict]:
        super().reset(seed=seed)
        unknown = sorted(set(options or {}) - {"task_input"})
        if unknown:
            raise UserError(f"unknown reset options {unknown}; valid reset options: task_input")
        self.robot.reset()
        self.task.reset(self.np_random, (options or {}).get("task_input"))
        self.sim.detect_collisions()
        self._steps = 0
        obs, distance = self._observe()
        self._initially_successful = bool(distance < SUCCESS_DISTANCE)
        return obs, self._info(obs, distance)

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict]:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != self.action_space.shape:
            raise ValueError(f"bad action shape {action.shape}; valid shape: {self.action_space.shape}")
        self.robot.set_action(action)
        self.sim.step()
        self._steps += 1
        obs, distance = self._observe()
        reward = float(distance <= SUCCESS_DISTANCE) - 1.0
        return obs, reward, False, self._steps >= self.max_episode_steps, self._info(obs, distance)

    def compute_reward(
        self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None
    ) -> np.ndarray:
        """Vectorised over leading batch axes; equals the rewards returned by :meth:`step`."""
        return goal_reward(achieved_goal, desired_goal)

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self.camera.frame(self.sim.client)

    def close(self) -> None:
        self.sim.close()

    # -- for scripted policies (chance and the task-blind floor, ps_ray.stitching.chance) ---------
    def target_region(self) -> tuple[np.ndarray, np.ndarray]:
        """The box (world frame, low and high corners) the task draws its targets from."""
        return self.task.target_region()

    def candidate_targets(self) -> np.ndarray | None:
        """The targets the scene holds for every task of its family (None: one task per scene);
        the named one is row :attr:`named_candidate` (the task-blind floor and the wrong-target
        rate, ps_ray.stitching.chance and ps_ray.stitching.evaluate)."""
        return self.task.candidate_targets()

    @property
    def named_candidate(self) -> int:
        return self.task.named_candidate

    def action_toward(self, point: np.ndarray) -> np.ndarray:
        """An action that moves the end effector toward a world point (inverse kinematics)."""
        return self.robot.action_toward(point)

    @property
    def object_position(self) -> np.ndarray | None:
        """The task's object's position (world frame) at the last observation; None without one.
        What touching, the outcome point and the wrong-target rate read (the achieved goal is
        the object's position only where the goal is said in the world frame)."""
        return None if self._object is None else self._object.copy()

    @property
    def outcome_position(self) -> np.ndarray:
        """Where an episode's work shows: the object, or the end effector in a task without one."""
        return self.ee_position if self._object is None else self.object_position

    @property
    def ee_position(self) -> np.ndarray:
        """The end effector's position (world frame) at the last observation: where a policy
        went, read without the task's target (outcome matching, ps_ray.stitching.outcomes)."""
        return self._ee.copy()

    # -- internals ----------------------------------------------------------------------------
    def _observe(self) -> tuple[Obs, np.float32]:
        self._ee = self.robot.ee_position()
        task_state, achieved = self.task.observe(self._ee)
        self._object = self.task.object_position()
        obs = {
            "robot_state": self.robot.state().astype(np.float32),
            "task_state": task_state.astype(np.float32),
            "achieved_goal": achieved.astype(np.float32),
            "desired_goal": self.task.goal.astype(np.float32),
        }
        # Reward and success use the float32 goals, as compute_reward on stored obs does: same values.
        return obs, goal_distance(obs["achieved_goal"], obs["desired_goal"])

    def _info(self, obs: Obs, distance: np.float32) -> dict[str, bool]:
        obj = self.task.object
        return {
            "is_success": bool(distance < SUCCESS_DISTANCE),
            "touching": obj is not None and math.dist(self._ee, self._object) <= TOUCH_DISTANCE,
            "contact": obj is not None and self.sim.in_contact(self.robot.body, obj),
            "initially_successful": self._initially_successful,
        }


def make(
    robot: str | RobotSpec | Mapping = "panda",
    task: str | Mapping | TaskSpec = "reach",
    **kwargs: Any,
) -> RobotTaskEnv:
    """``make("panda_l3", "push")``, ``make({"base": "panda", "locked_joints": [1]}, "reach")``,
    ``make("panda", {"name": "push", "object_friction": 0.3})``, ``make(task="reach", goal_region="q2")``.

    Keyword arguments are ``render_mode``, ``render_size`` (width, height), ``max_episode_steps``
    or task options.
    """
    return RobotTaskEnv(robot, task, **kwargs)
