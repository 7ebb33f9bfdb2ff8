"""The push member of the transfer family: one object, two goal markers on the table, the task
names the marker the object must end at; goals said in the named marker's frame, and every
outcome (success, touching, the wrong-target rate, outcome matching) read from the object."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pybullet as p
import pytest

from ps_ray.envs import make
from ps_ray.envs.goals import task_input
from ps_ray.errors import UserError
from ps_ray.stitching.evaluate import evaluate, outcome_point


def place(env, point) -> dict:
    """The object set down at ``point`` (world frame, at rest); the step's info after it."""
    p.resetBasePositionAndOrientation(
        env.task.object, list(map(float, point)), (0, 0, 0, 1), physicsClientId=env.sim.client
    )
    return env.step(np.zeros(env.action_space.shape, np.float32))


def test_the_object_and_the_markers_are_the_task_state_and_the_goal_is_an_offset_from_the_named_one():
    for name, target in (("push_red", 0), ("push_blue", 1)):
        env = make("panda", name)
        for seed in range(20):
            obs, info = env.reset(seed=seed)
            state = obs["task_state"]
            markers, start = state[12:].reshape(2, 3), env.object_position
            np.testing.assert_allclose(state[:3], start, atol=1e-6)
            np.testing.assert_array_equal(obs["desired_goal"], np.zeros(3))
            np.testing.assert_allclose(obs["achieved_goal"], start - markers[target], atol=1e-6)
            # apart, off the mounts' axis, on the table, and never where the object starts
            assert np.linalg.norm(markers[0] - markers[1]) >= 0.1
            assert np.all(np.hypot(markers[:, 0], markers[:, 1]) >= 0.06)
            assert np.all(np.linalg.norm(markers[:, :2] - start[:2], axis=1) >= 0.08)
            np.testing.assert_allclose(markers[:, 2], 0.02)
            assert not info["initially_successful"] and task_input(obs).shape == (21,)
        assert env.observation_space["task_state"].shape == (18,)


def test_both_tasks_see_the_same_scenes_and_differ_only_in_the_marker_they_mean():
    red, blue = make("panda", "push_red"), make("panda", "push_blue")
    a, _ = red.reset(seed=7)
    b, _ = blue.reset(seed=7)
    np.testing.assert_array_equal(a["task_state"], b["task_state"])
    assert not np.allclose(a["achieved_goal"], b["achieved_goal"])


@pytest.mark.parametrize("marker", [0, 1])
def test_the_object_at_a_marker_succeeds_for_its_task_and_is_the_wrong_target_for_the_other(marker):
    from ps_ray.stitching.evaluate import _candidate_ends

    for name, target in (("push_red", 0), ("push_blue", 1)):
        env = make("panda", name)
        env.reset(seed=3)
        spot = env.candidate_targets()[marker]
        obs, reward, _, _, info = place(env, spot)
        assert info["is_success"] == (marker == target) and reward == (0.0 if marker == target else -1.0)
        distances, wrong = _candidate_ends(env)  # what evaluate records per episode
        assert distances[marker] < 0.01 and wrong == (marker != target)
        np.testing.assert_allclose(env.object_position, spot, atol=0.005)


def test_an_episode_s_outcome_is_where_the_object_ended_not_the_hand_nor_the_achieved_goal():
    env = make("panda", "push_red")
    still = lambda obs: np.zeros((len(obs["task_state"]), 7))  # noqa: E731 (a policy that never moves)
    result = evaluate(still, "panda", "push_red", episodes=2, repeats=1, seed=5)
    for record in result["records"]:
        env.reset(seed=record["seed"])
        start = env.object_position  # nothing touched the object: it ends where it started
        np.testing.assert_allclose(outcome_point(record), start, atol=1e-3)
        assert not np.allclose(outcome_point(record), record["end_effector"], atol=0.05)
        assert record["wrong_target"] is False and len(record["candidate_distances"]) == 2
    assert result["success_mean"] == 0.0


def test_a_relabelled_goal_is_the_named_marker_plus_an_offset_and_rewards_agree():
    env = make("panda", "push_blue")
    obs, _ = env.reset(seed=2)
    start = env.object_position
    shoved = start + np.array([0.03, -0.02, 0.0])
    obs, *_ = place(env, shoved)
    markers = obs["task_state"][12:].reshape(2, 3)
    np.testing.assert_allclose(obs["achieved_goal"], shoved - markers[1], atol=2e-3)
    # hindsight: that achieved goal as the desired one is "push to the blue marker plus that offset"
    assert env.compute_reward(obs["achieved_goal"], obs["achieved_goal"], None) == 0.0
    env.reset(seed=2)
    env.task.goal = obs["achieved_goal"].astype(np.float64)
    _, reward, _, _, info = place(env, shoved)
    assert reward == 0.0 and info["is_success"]


def test_bad_marker_options_are_one_line():
    from ps_ray.errors import UserError

    with pytest.raises(UserError, match="bad target 2; valid targets: 0..1"):
        make("panda", {"name": "push_red", "target": 2})
    with pytest.raises(UserError, match="cannot place 4 markers 0.3 m apart"):
        make("panda", {"name": "push_red", "markers": 4, "min_separation": 0.3}).reset(seed=0)


def test_no_script_stands_in_for_the_push_family_s_floor():
    """Driving the hand to a marker pushes nothing: the task-blind floor of the push family is its
    tasks' oracles' mean, not a scripted driver's (left unmeasured, NaN, rather than a false 0)."""
    from ps_ray.stitching.chance import chance, has_floor, scripted_floor

    assert has_floor("push_red") and not scripted_floor("push_red") and scripted_floor("reach_red")
    levels = chance("panda", "push_red", {"episodes": 2, "repeats": 1, "seed": 0})
    assert np.isnan(levels["task_blind_success"]) and np.isnan(levels["task_blind_wrong_target"])
    assert 0.0 <= levels["chance_success"] <= 1.0


def test_the_push_family_s_floor_is_the_mean_of_its_tasks_oracles_run_on_the_target(tmp_path):
    """Per method, the sweep's sources on the target robot for each of the scene's tasks, run as
    they are on the target's episodes: the floor is their mean, per episode, and the best method's
    is the floor (its wrong-target rate the same mean)."""
    from ps_ray.stitching.chance import chance, oracle_floor, scene_oracles
    from ps_ray.stitching.evaluate import evaluate
    from ps_ray.stitching.zoo import ModuleZoo
    from tests.stitch_sources import spec, write_trial

    for method in ("ps", "ablation"):
        for robot in ("panda", "panda_far"):
            for task in ("push_red", "push_blue"):
                write_trial(tmp_path, "tune", spec(method, robot, task, seed=1))
    write_trial(tmp_path, "tune", spec("plain", "panda_far", "push_red", seed=1))  # no push_blue one
    write_trial(tmp_path, "tune", spec("ps", "panda_far", "push_blue", seed=2))  # another seed
    wider = spec("ps", "panda_far", "push_red", seed=1, interface_dim=16)
    write_trial(tmp_path, "tune", wider)  # at i16 no push_blue one
    zoo = ModuleZoo.from_sweep(tmp_path)
    oracles = scene_oracles(zoo, "panda_far", "push_blue", seed=1)
    assert sorted(oracles) == ["ablation/i8", "ps/i8"]  # plain, ps at i16: a candidate missing
    for files in oracles.values():  # candidate order: red (0), then blue (1)
        trained = [json.loads((Path(f).parent / "spec.json").read_text()) for f in files]
        assert [(t["robot"], t["task"]) for t in trained] == [
            ("panda_far", "push_red"),
            ("panda_far", "push_blue"),
        ]
    settings = {"episodes": 3, "repeats": 1, "seed": 4}
    floor = oracle_floor("panda_far", "push_blue", settings, oracles["ps/i8"])
    runs = [evaluate(f, "panda_far", "push_blue", **settings) for f in oracles["ps/i8"]]
    assert floor["task_blind_per_candidate"] == [r["success_mean"] for r in runs]
    assert floor["task_blind_success"] == pytest.approx(np.mean([r["success_mean"] for r in runs]))
    assert floor["task_blind_wrong_target"] == pytest.approx(np.mean([r["wrong_target_mean"] for r in runs]))
    levels = chance("panda_far", "push_blue", settings, oracles)
    best = max(
        oracle_floor("panda_far", "push_blue", settings, o)["task_blind_success"] for o in oracles.values()
    )
    assert levels["task_blind_success"] == best and levels["task_blind_policy"].endswith(" oracles")


def test_an_env_reset_to_a_task_input_shows_that_scene_object_and_markers_included():
    """Outcome matching sets scenes from task inputs (anchors@..., swapped): the object's pose and
    velocities, both markers and the desired offset stand where the input says."""
    env = make("panda", "push_blue")
    drawn, _ = env.reset(seed=4)
    scene = task_input(drawn).copy()
    scene[:2] += [0.03, -0.02]  # the object moved
    scene[12:15], scene[15:18] = scene[15:18].copy(), scene[12:15].copy()  # the markers traded
    obs, info = env.reset(seed=9, options={"task_input": scene})
    np.testing.assert_allclose(obs["task_state"], scene[:18], atol=1e-5)
    np.testing.assert_allclose(obs["desired_goal"], scene[18:], atol=1e-7)
    np.testing.assert_allclose(obs["achieved_goal"], scene[:3] - scene[15:18], atol=1e-5)
    np.testing.assert_allclose(env.object_position, scene[:3], atol=1e-5)
    with pytest.raises(UserError, match="a task input of this scene is 21 finite numbers"):
        env.reset(seed=9, options={"task_input": scene[:18]})


def test_the_world_frame_diagnostic_says_the_same_scenes_in_world_coordinates():
    """goal_frame world: the goal the named marker's position, the achieved goal the object's; the
    scene, the candidates and the success of the object at each marker as in the marker frame."""
    for name, target in (("push_red", 0), ("push_blue", 1)):
        marker_env, world_env = make("panda", name), make("panda", {"name": name, "goal_frame": "world"})
        for seed in range(5):
            a, _ = marker_env.reset(seed=seed)
            b, _ = world_env.reset(seed=seed)
            np.testing.assert_array_equal(a["task_state"], b["task_state"])
            markers = b["task_state"][12:].reshape(2, 3)
            np.testing.assert_allclose(b["desired_goal"], markers[target], atol=1e-6)
            np.testing.assert_allclose(b["achieved_goal"], world_env.object_position, atol=1e-6)
            np.testing.assert_allclose(world_env.candidate_targets(), marker_env.candidate_targets())
        for marker in (0, 1):
            world_env.reset(seed=3)
            _, reward, _, _, info = place(world_env, world_env.candidate_targets()[marker])
            assert info["is_success"] == (marker == target) and reward == (0.0 if marker == target else -1.0)
    with pytest.raises(UserError, match="bad goal_frame 'hand'; valid goal frames: marker, world"):
        make("panda", {"name": "push_red", "goal_frame": "hand"})


def test_markers_said_from_the_object_are_each_task_s_achieved_goal_and_set_scenes_round_trip():
    """marker_state from_object: the task state holds the object's position minus each marker's, so
    each task's achieved goal is its own marker's columns; both tasks still see the same state; a
    scene set from a task input is the scene that input came from."""
    options = {"marker_state": "from_object"}
    red, blue = (make("panda", {"name": n, **options}) for n in ("push_red", "push_blue"))
    plain = make("panda", "push_red")
    for seed in range(5):
        a, _ = red.reset(seed=seed)
        b, _ = blue.reset(seed=seed)
        c, _ = plain.reset(seed=seed)
        np.testing.assert_array_equal(a["task_state"], b["task_state"])
        markers = c["task_state"][12:].reshape(2, 3)
        from_object = a["task_state"][12:].reshape(2, 3)
        np.testing.assert_allclose(from_object, red.object_position - markers, atol=1e-6)
        np.testing.assert_allclose(a["achieved_goal"], a["task_state"][12:15], atol=1e-6)
        np.testing.assert_allclose(b["achieved_goal"], b["task_state"][15:18], atol=1e-6)
        again, _ = red.reset(options={"task_input": task_input(a)})
        np.testing.assert_allclose(red.candidate_targets(), plain.candidate_targets(), atol=1e-5)
        np.testing.assert_allclose(again["task_state"], a["task_state"], atol=1e-5)
    with pytest.raises(UserError, match="bad marker_state 'hand'; valid marker states: position, from_obj"):
        make("panda", {"name": "push_red", "marker_state": "hand"})
