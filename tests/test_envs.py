"""Behaviour of ps_ray.envs in real PyBullet: locking, friction, contacts, rewards, determinism."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

from ps_ray.envs import GOAL_REGIONS, goal_reward, make, task_input
from ps_ray.envs.robots import ARM_STEP, EE_LINK
from ps_ray.envs.tasks.rocks import rock_boxes

DOWN = p.getQuaternionFromEuler([np.pi, 0.0, 0.0])


def ik_action(env, obs, target) -> np.ndarray:
    """Joint-delta action moving the end effector towards ``target`` (gripper pointing down)."""
    robot = env.unwrapped.robot
    ik = p.calculateInverseKinematics(
        robot.body,
        EE_LINK,
        list(map(float, target)),
        DOWN,
        maxNumIterations=100,
        physicsClientId=robot.sim.client,
    )
    action = np.zeros(env.action_space.shape, np.float32)
    action[robot.free] = np.clip(
        (np.array(ik[: len(robot.free)]) - obs["robot_state"][robot.free]) / ARM_STEP, -1, 1
    )
    return action


def scripted_push(env, seed: int, height: float = 0.02, speed: float = 0.01, stop: int = 50):
    """Come down 10 cm behind the object, sweep through it along +x at ``speed`` m/step, and lift
    the hand away from step ``stop`` on.

    Returns the object's start position, the actions and the per-step infos.
    """
    obs, _ = env.reset(seed=seed)
    start = env.object_position  # the achieved goal is the object only where goals are in the world frame
    actions, infos = [], []
    for t in range(50):
        if t < 12 or t >= stop:
            offset = (-0.10, 0, 0.06)
        else:
            offset = (-0.10 + speed * max(t - 18, 0), 0, height)
        actions.append(ik_action(env, obs, start + offset))
        obs, _, _, _, info = env.step(actions[-1])
        infos.append(info)
    return start, obs, np.array(actions), infos


def rollout(env, seed: int, actions: np.ndarray, render: bool = False) -> dict[str, np.ndarray]:
    """Everything an episode returns, stacked."""
    obs, info = env.reset(seed=seed)
    steps = [(obs, 0.0, info)]
    for action in actions:
        obs, reward, _, _, info = env.step(action)
        steps.append((obs, reward, info))
        if render:
            env.render()
    out = {k: np.stack([s[0][k] for s in steps]) for k in obs}
    out["reward"] = np.array([s[1] for s in steps])
    out.update({k: np.array([s[2][k] for s in steps]) for k in info})
    return out


def link_rotation(env, link: int) -> np.ndarray:
    cid, body = env.sim.client, env.robot.body
    if link < 0:
        quat = p.getBasePositionAndOrientation(body, physicsClientId=cid)[1]
    else:
        quat = p.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=cid)[5]
    return np.array(p.getMatrixFromQuaternion(quat)).reshape(3, 3)


def joint_rotation(env, joint: int) -> np.ndarray:
    """Rotation of arm joint ``joint``'s child link relative to its parent, from the link poses."""
    return link_rotation(env, joint - 1).T @ link_rotation(env, joint)


# -- robots ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("robot", ["panda_l3", "panda_l5", {"base": "panda", "locked_joints": [1]}])
def test_locked_joint_stays_put_while_others_move(robot):
    env = make(robot, "push")
    (lock,) = env.robot_spec.locked_joints
    free = [j for j in range(7) if j != lock]
    obs0, _ = env.reset(seed=0)
    reference = joint_rotation(env, lock)
    env.action_space.seed(0)
    drift, moved = 0.0, np.zeros(7)
    for episode in range(3):
        env.reset(seed=episode)
        for _ in range(50):
            obs, *_ = env.step(env.action_space.sample())
            relative = reference.T @ joint_rotation(env, lock)
            drift = max(drift, np.arccos(np.clip((np.trace(relative) - 1) / 2, -1, 1)))
            moved = np.maximum(moved, np.abs(obs["robot_state"][:7] - obs0["robot_state"][:7]))
    assert drift <= 1e-3
    assert moved[lock] == 0.0  # reported at its lock angle
    assert np.all(moved[free] > 0.05)
    env.close()


def test_lock_at_nonzero_angle_keeps_kinematics():
    """Locking joint 1 at its neutral 0.41 rad folds the rotation into the URDF joint origin."""
    free, locked = make("panda", "reach"), make({"locked_joints": [1, 3]}, "reach")
    free.reset(seed=0)
    obs, _ = locked.reset(seed=0)
    np.testing.assert_allclose(locked.robot.ee_position(), free.robot.ee_position(), atol=1e-9)
    np.testing.assert_allclose(obs["robot_state"][[1, 3]], [0.41, -1.85], atol=1e-7)


def test_gripper_defaults_and_overrides():
    assert make("panda", "push").action_space.shape == (7,)
    assert make("panda", "reach").action_space.shape == (7,)
    pick = make("panda_l5", "pick_cube")
    assert pick.action_space.shape == (8,)
    push_gripper = make({"name": "panda_l3", "gripper": True}, "push")
    assert push_gripper.action_space.shape == (8,)
    assert push_gripper.robot_spec.locked_joints == (2,)
    obs, _ = pick.reset(seed=0)
    for _ in range(5):
        obs, *_ = pick.step(np.array([0, 0, 0, 0, 0, 0, 0, 1], np.float32))
    assert obs["robot_state"][7] > 0.05  # fingers opened
    blocked = make({"gripper": False}, "pick_cube")
    obs, _ = blocked.reset(seed=0)
    assert blocked.action_space.shape == (7,) and obs["robot_state"][7] == 0.0


# -- tasks ----------------------------------------------------------------------------------------
def test_slippery_object_slides_further():
    moved = {}
    for task in ("push", "push_slippery"):
        env = make("panda", task)
        start, obs, _, infos = scripted_push(env, seed=0, speed=0.02, stop=28)  # a strike, then away
        assert any(i["touching"] for i in infos)
        moved[task] = obs["achieved_goal"][0] - start[0]
    assert moved["push"] > 0.03  # the arm did hit the cube
    assert moved["push_slippery"] > 2 * moved["push"], moved


def test_custom_friction_option():
    env = make("panda", {"name": "push", "object_friction": 0.3})
    env.reset(seed=0)
    assert p.getDynamicsInfo(env.task.object, -1, physicsClientId=env.sim.client)[1] == pytest.approx(0.3)


@pytest.mark.parametrize("task", ["push", "push_rocks", "pick_cube", "push_red"])
def test_touching_and_contact_fire_only_near_the_object(task):
    env = make("panda", task)
    _, _, _, infos = scripted_push(env, seed=0)
    touching = np.array([i["touching"] for i in infos])
    contact = np.array([i["contact"] for i in infos])
    assert not touching[:12].any() and not contact[:12].any()  # hovering 10 cm away
    assert touching.any() and contact.any()
    assert np.all(touching[contact])  # every real contact is within the 5 cm touching radius


def test_success_when_object_on_goal():
    env = make("panda", "push")
    obs, info = env.reset(seed=0)
    assert not info["is_success"] and not info["initially_successful"] and not info["touching"]
    p.resetBasePositionAndOrientation(
        env.task.object, env.task.goal.tolist(), (0, 0, 0, 1), physicsClientId=env.sim.client
    )
    obs, reward, terminated, truncated, info = env.step(np.zeros(7, np.float32))
    assert info["is_success"] and reward == 0.0 and not terminated and not truncated
    assert not info["initially_successful"]


def test_initially_successful():
    env = make("panda", "push", goal_xy_range=0.0, object_xy_range=0.0)
    _, info = env.reset(seed=0)
    assert info["initially_successful"] and info["is_success"]
    _, _, _, _, info = env.step(np.zeros(7, np.float32))
    assert info["initially_successful"]


def test_reach_reports_no_object():
    env = make("panda", "reach")
    obs, info = env.reset(seed=0)
    assert obs["task_state"].shape == (0,) and not info["touching"] and not info["contact"]
    np.testing.assert_allclose(obs["achieved_goal"], env.robot.ee_position(), atol=1e-6)


@pytest.mark.parametrize("region", list(GOAL_REGIONS))
def test_reach_goal_regions(region):
    env = make("panda", "reach", goal_region=region)
    center, radius = np.array(GOAL_REGIONS[region]["center"]), GOAL_REGIONS[region]["radius"]
    goals = np.array([env.reset(seed=s)[0]["desired_goal"] for s in range(30)])
    assert np.all(np.linalg.norm(goals[:, :2] - center[:2], axis=1) <= radius + 1e-6)
    np.testing.assert_allclose(goals[:, 2], center[2], atol=1e-6)
    assert np.ptp(goals[:, 0]) > radius / 2  # spread over the disc


def test_reach_custom_disc_and_default_box():
    env = make("panda", {"name": "reach", "goal_region": {"center": [0.0, 0.1, 0.05], "radius": 0.02}})
    goal = env.reset(seed=1)[0]["desired_goal"]
    assert np.linalg.norm(goal[:2] - (0.0, 0.1)) <= 0.02 + 1e-6
    box = np.array([make("panda", "reach").reset(seed=s)[0]["desired_goal"] for s in range(20)])
    assert np.all(np.abs(box[:, :2]) <= 0.15) and np.all((box[:, 2] >= 0) & (box[:, 2] <= 0.3))


def test_pick_goals_and_stick():
    env = make("panda", "pick_stick")
    goals = np.array([env.reset(seed=s)[0]["desired_goal"] for s in range(40)])
    assert np.all(np.abs(goals[:, :2]) <= 0.15) and np.all(
        (goals[:, 2] >= 0.02) & (goals[:, 2] <= 0.22 + 1e-6)
    )
    assert 0 < np.mean(goals[:, 2] == np.float32(0.02)) < 0.7  # some goals on the table
    shape = p.getCollisionShapeData(env.task.object, -1, physicsClientId=env.sim.client)[0][3]
    np.testing.assert_allclose(shape, (0.30, 0.04, 0.04))


def test_rocks_are_fixed_and_in_range():
    boxes = rock_boxes()
    assert boxes.shape == (169, 6)
    assert boxes[:, 0].min() >= -0.43 and boxes[:, 0].max() <= 0.23
    assert boxes[:, 1].min() >= -0.33 and boxes[:, 1].max() <= 0.33
    assert np.all((2 * boxes[:, 5] >= 0.006) & (2 * boxes[:, 5] <= 0.010))
    np.testing.assert_allclose(boxes[:, 3:5], 0.007)
    env = make("panda", "push_rocks")
    obs, _ = env.reset(seed=0)
    assert obs["achieved_goal"][2] >= 0.02  # the cube rests on the bumps, not inside them


# -- rewards, observation helpers -----------------------------------------------------------------
def test_compute_reward_matches_step_rewards():
    env = make("panda", "push")
    env.action_space.seed(0)
    obs, _ = env.reset(seed=0)
    achieved, desired, rewards = [], [], []
    for t in range(50):
        if t == 25:  # put the cube on the goal, so both reward values occur
            p.resetBasePositionAndOrientation(
                env.task.object, env.task.goal.tolist(), (0, 0, 0, 1), physicsClientId=env.sim.client
            )
        obs, reward, _, truncated, info = env.step(env.action_space.sample())
        achieved.append(obs["achieved_goal"])
        desired.append(obs["desired_goal"])
        rewards.append(reward)
    assert truncated and set(rewards) == {-1.0, 0.0}
    batch = env.compute_reward(np.array(achieved), np.array(desired), {})
    assert batch.dtype == np.float32 and batch.shape == (50,)
    np.testing.assert_array_equal(batch, np.array(rewards, np.float32))
    grid = env.compute_reward(np.array(achieved).reshape(5, 10, 3), np.array(desired).reshape(5, 10, 3), None)
    np.testing.assert_array_equal(grid.ravel(), batch)


def test_goal_reward_threshold():
    goal = np.zeros(3)
    np.testing.assert_array_equal(goal_reward([[0.049, 0, 0], [0.051, 0, 0]], goal), [0.0, -1.0])
    assert goal_reward(np.zeros((2, 4, 3)), np.ones((2, 4, 3))).shape == (2, 4)


def test_task_input_single_and_batched():
    obs, _ = make("panda", "push").reset(seed=0)
    x = task_input(obs)
    assert x.shape == (15,) and x.dtype == np.float32
    np.testing.assert_array_equal(x[12:], obs["desired_goal"])
    batch = {k: np.stack([v, v]) for k, v in obs.items()}
    assert task_input(batch).shape == (2, 15)
    reach_obs, _ = make("panda", "reach").reset(seed=0)
    assert task_input(reach_obs).shape == (3,)


def test_truncation_after_50_steps():
    env = make("panda_l3", "reach")
    env.reset(seed=0)
    flags = [env.step(env.action_space.sample())[2:4] for _ in range(50)]
    assert not any(term for term, _ in flags)
    assert [trunc for _, trunc in flags] == [False] * 49 + [True]


# -- determinism ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "robot,task",
    [("panda", "push"), ("panda_l5", "push_rocks"), ("panda", "pick_stick"), ("panda_far", "push_blue")],
)
def test_seeded_replay_is_bit_identical(robot, task):
    env = make(robot, task)
    _, _, actions, infos = scripted_push(env, seed=3, height=0.0)  # presses on the table and the object
    assert any(i["contact"] for i in infos)
    actions = actions + np.random.default_rng(0).normal(0, 0.2, actions.shape).astype(np.float32)
    first = rollout(env, 3, actions)
    for seed in (4, 5):  # other contact-rich episodes in between
        scripted_push(env, seed=seed, height=0.0)
    again = rollout(env, 3, actions)
    fresh = rollout(make(robot, task), 3, actions)
    for key in first:
        np.testing.assert_array_equal(again[key], first[key], err_msg=f"same env: {key}")
        np.testing.assert_array_equal(fresh[key], first[key], err_msg=f"fresh env: {key}")


def test_rendering_does_not_change_physics():
    actions = np.random.default_rng(1).uniform(-1, 1, (10, 7)).astype(np.float32)
    plain = rollout(make("panda", "push_rocks"), 7, actions)
    rendered = rollout(make("panda", "push_rocks", render_mode="rgb_array"), 7, actions, render=True)
    for key in plain:
        np.testing.assert_array_equal(rendered[key], plain[key], err_msg=key)


def test_unseeded_resets_differ_and_seeded_resets_repeat():
    env = make("panda", "pick_cube")
    a = env.reset(seed=11)[0]
    b = env.reset()[0]
    c = env.reset(seed=11)[0]
    assert not np.array_equal(a["desired_goal"], b["desired_goal"])
    for key in a:
        np.testing.assert_array_equal(a[key], c[key])
