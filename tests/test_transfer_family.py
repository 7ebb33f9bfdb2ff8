"""The transfer family (docs/transfer.md): tasks that differ only in which marker they mean, and a
mount that changes how the arm moves. A scripted reacher shows what each control must fail."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

from ps_ray.envs import make
from ps_ray.envs.goals import task_input
from ps_ray.envs.robots import EE_LINK, N_ARM


def reach_for(env, target: np.ndarray, solver=None) -> np.ndarray:
    """One action toward ``target`` by inverse kinematics solved on ``solver``'s arm (default: the
    env's own): a reacher solved on another mount is a policy that learned its moves there."""
    robot = env.robot
    arm = (solver or env).robot
    state = robot.state()[:N_ARM]
    for k, joint in enumerate(arm.free):  # the solver's arm in this arm's joint angles
        p.resetJointState(arm.body, arm.joints[k], float(state[joint]), physicsClientId=arm.sim.client)
    q = p.calculateInverseKinematics(
        arm.body, EE_LINK, list(map(float, target)), maxNumIterations=50, physicsClientId=arm.sim.client
    )
    action = np.zeros(env.action_space.shape)
    for k, joint in enumerate(robot.free):
        action[joint] = (q[k] - state[joint]) / 0.05
    return np.clip(action, -1, 1)


def run(robot, task, pick_target, episodes: int = 12, solver_robot=None) -> float:
    env = make(robot, task)
    solver = None if solver_robot is None else make(solver_robot, task)
    wins = []
    for seed in range(episodes):
        obs, _ = env.reset(seed=seed)
        for _ in range(50):
            obs, _, _, _, info = env.step(reach_for(env, pick_target(obs), solver))
        wins.append(info["is_success"])
    env.close()
    return float(np.mean(wins))


RED = lambda obs: obs["task_state"][0:3]  # noqa: E731  (the red marker, whatever the task)


@pytest.mark.parametrize("robot", ["panda", "panda_far"])
def test_a_scripted_red_reacher_solves_reach_red_and_fails_reach_blue(robot):
    assert run(robot, "reach_red", RED) == 1.0
    assert run(robot, "reach_blue", RED) == 0.0


def test_a_reacher_that_moves_like_one_mount_fails_on_the_other():
    """Joint moves learned at the paper's mount put the far-mounted arm at the mirror image of the
    marker through the workspace centre, at least 2 x min_radius away: every episode fails."""
    assert run("panda_far", "reach_red", RED, solver_robot="panda") == 0.0
    assert run("panda", "reach_red", RED, solver_robot="panda") == 1.0  # at its own mount it reaches


def test_markers_are_the_task_state_and_the_goal_is_an_offset_from_the_named_one():
    for name, target in (("reach_red", 0), ("reach_blue", 1)):
        env = make("panda", name)
        obs, info = env.reset(seed=5)
        markers = obs["task_state"].reshape(2, 3)
        assert np.linalg.norm(markers[0] - markers[1]) >= 0.1
        assert np.all(np.hypot(markers[:, 0], markers[:, 1]) >= 0.03)
        np.testing.assert_array_equal(obs["desired_goal"], np.zeros(3))
        np.testing.assert_allclose(obs["achieved_goal"], env.robot.ee_position() - markers[target], atol=1e-6)
        assert task_input(obs).shape == (9,) and not info["touching"]


def test_both_tasks_see_the_same_scenes():
    red, _ = make("panda", "reach_red").reset(seed=11)
    blue, _ = make("panda", "reach_blue").reset(seed=11)
    np.testing.assert_array_equal(red["task_state"], blue["task_state"])
    assert not np.allclose(red["achieved_goal"], blue["achieved_goal"])


def test_a_relabelled_goal_is_the_named_marker_plus_an_offset_and_rewards_agree():
    """Hindsight: a later achieved goal as the desired one means 'reach the marker plus that
    offset', and compute_reward on stored goals equals the reward the env gives for it."""
    env = make("panda", "reach_red")
    obs, _ = env.reset(seed=2)
    actions = np.random.default_rng(0).uniform(-1, 1, (50, 7))
    achieved = []
    for action in actions:
        obs, reward, *_ = env.step(action)
        achieved.append(obs["achieved_goal"])
    achieved = np.array(achieved)
    relabelled = np.repeat(achieved[-1:], 50, axis=0)
    rewards = env.compute_reward(achieved, relabelled, None)
    assert rewards[-1] == 0.0 and rewards[0] == -1.0
    # the env itself, asked for that offset, agrees at the last step
    env.reset(seed=2)
    env.task.goal = achieved[-1].astype(np.float64)
    for action in actions:
        obs, reward, *_ = env.step(action)
    assert reward == 0.0


def test_mounts_turn_the_base_about_the_workspace_centre():
    far = make("panda_far", "reach_red")
    near = make("panda", "reach_red")
    far.reset(seed=0)
    near.reset(seed=0)
    ee_far, ee_near = far.robot.ee_position(), near.robot.ee_position()
    np.testing.assert_allclose(ee_far[:2], -ee_near[:2], atol=1e-6)  # the same angles, mirrored
    assert ee_far[2] == pytest.approx(ee_near[2])
    with pytest.raises(ValueError, match="bad mount 'left'"):
        make({"name": "panda", "mount": "left"}, "reach")
