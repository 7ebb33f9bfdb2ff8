"""Task states paired by meaning (ps_ray.stitching.outcomes): each task's own policy rolled out,
its outcomes described by where the arm ended, matched across tasks through k-means points."""

from __future__ import annotations

import numpy as np
import pytest

from ps_ray.envs import make
from ps_ray.errors import UserError
from ps_ray.specs.names import EnvPart
from ps_ray.stitching.evaluate import evaluate
from ps_ray.stitching.outcomes import (
    Outcomes,
    anchor_ends,
    colour_swapped,
    decode_anchors,
    match_anchors,
    match_anchors_by_both,
    matched_anchors,
    matched_pairs,
    outcomes,
)

RED, BLUE = slice(0, 3), slice(3, 6)  # the marker task state: red's position, then blue's


class Reacher:
    """A policy that knows its task (as a trained source does): it drives to the named marker."""

    def begin(self, envs, seeds) -> None:
        self.envs = envs

    def __call__(self, obs) -> np.ndarray:
        return np.stack([env.action_toward(env.task.target_position) for env in self.envs])


@pytest.mark.e2e
def test_scenes_matched_by_outcome_mean_the_same_place_to_their_tasks():
    """reach_red's scenes and reach_blue's, paired through where each task's own policy ended: the
    red marker of a paired red scene lies where the blue marker of its blue scene does, which is
    what no pairing of the same states could give (there red and blue are 0.1 m or more apart)."""
    red = outcomes(Reacher(), "panda", "reach_red", 40)
    blue = outcomes(Reacher(), "panda_far", "reach_blue", 40)
    assert len(red.end) >= 35 and len(blue.end) >= 35  # the reacher succeeds; failures are dropped
    states_red, states_blue = matched_pairs(red, blue, points=20)
    assert states_red.shape == states_blue.shape == (20, 9)
    gap = np.linalg.norm(states_red[:, RED] - states_blue[:, BLUE], axis=1)
    same_scene = np.linalg.norm(states_red[:, RED] - states_red[:, BLUE], axis=1)
    assert np.median(gap) < 0.05  # matched to a few cm
    assert same_scene.min() >= 0.1 - 1e-6  # the markers of one scene: min_separation apart
    shuffled = np.linalg.norm(states_red[:, RED] - states_blue[::-1][:, BLUE], axis=1)
    assert np.median(shuffled) > 2 * np.median(gap)


def test_an_outcome_is_where_the_arm_ended_not_where_the_target_was():
    """A policy that never moves ends every scene at the same point, whatever the markers."""
    still = evaluate(
        lambda obs: np.zeros((len(obs["robot_state"]), 7)), "panda", "reach_red", episodes=6, repeats=1
    )
    ends = np.array([r["end_effector"] for r in still["records"]])
    targets = np.array([r["task_input"][RED] for r in still["records"]])
    np.testing.assert_allclose(ends, ends[:1].repeat(6, 0), atol=1e-6)
    assert np.ptp(targets, axis=0).max() > 0.05  # the scenes themselves differ


def test_a_push_outcome_is_where_the_object_ended_a_marker_outcome_where_the_arm_did():
    """Push's own outcome is the pushed object's final position; a task without an object keeps
    the end effector's (so every marker-family figure stands)."""
    from ps_ray.stitching.evaluate import outcome_point

    def still(obs):
        return np.zeros((len(obs["robot_state"]), 7))

    for r in evaluate(still, "panda", "push", episodes=4, repeats=1)["records"]:
        np.testing.assert_allclose(outcome_point(r), r["start"], atol=1e-3)  # untouched: where it was
        assert np.linalg.norm(np.subtract(outcome_point(r), r["end_effector"])) > 0.05
    for r in evaluate(still, "panda", "reach_red", episodes=2, repeats=1)["records"]:
        assert r["object_end"] == () and outcome_point(r) == tuple(r["end_effector"])


def test_the_swapped_scene_trades_the_two_tasks_markers():
    states = np.arange(18, dtype=np.float32).reshape(2, 9)
    swapped = colour_swapped(states, EnvPart("reach_red"), EnvPart("reach_blue"))
    np.testing.assert_array_equal(swapped[:, RED], states[:, BLUE])
    np.testing.assert_array_equal(swapped[:, BLUE], states[:, RED])
    np.testing.assert_array_equal(swapped[:, 6:], states[:, 6:])  # the goal offset stays
    with pytest.raises(UserError, match="two tasks of one marker family, got reach and reach_blue"):
        colour_swapped(states, EnvPart("reach"), EnvPart("reach_blue"))
    with pytest.raises(UserError, match="two tasks of one marker family, got push_red and reach_blue"):
        colour_swapped(states, EnvPart("push_red"), EnvPart("reach_blue"))
    # the push family: the markers stand after the object's 12 numbers; the object stays
    pushed = np.arange(42, dtype=np.float32).reshape(2, 21)
    swapped = colour_swapped(pushed, EnvPart("push_red"), EnvPart("push_blue"))
    np.testing.assert_array_equal(swapped[:, 12:15], pushed[:, 15:18])
    np.testing.assert_array_equal(swapped[:, 15:18], pushed[:, 12:15])
    np.testing.assert_array_equal(swapped[:, :12], pushed[:, :12])
    np.testing.assert_array_equal(swapped[:, 18:], pushed[:, 18:])


def test_an_env_reset_to_a_task_input_shows_that_scene():
    env = make("panda", "reach_blue")
    try:
        scene = np.array([0.05, -0.06, 0.12, -0.07, 0.08, 0.18, 0.01, 0.0, -0.02], np.float32)
        obs, _ = env.reset(seed=3, options={"task_input": scene})
        np.testing.assert_allclose(obs["task_state"], scene[:6], atol=1e-7)
        np.testing.assert_allclose(obs["desired_goal"], scene[6:], atol=1e-7)
        np.testing.assert_allclose(obs["achieved_goal"], env.ee_position - scene[BLUE], atol=1e-6)
        drawn, _ = env.reset(seed=3)  # without the option, the seed's own scene
        assert np.abs(drawn["task_state"] - scene[:6]).max() > 0.01
        with pytest.raises(
            UserError, match=r"unknown reset options \['goal'\]; valid reset options: task_input"
        ):
            env.reset(seed=3, options={"goal": scene})
        with pytest.raises(UserError, match="a task input of this scene is 9 finite numbers, got"):
            env.reset(seed=3, options={"task_input": scene[:6]})
        with pytest.raises(UserError, match="9 finite numbers"):
            env.reset(seed=3, options={"task_input": np.r_[scene[:8], np.nan]})
    finally:
        env.close()
    reach = make("panda", "reach")
    try:
        with pytest.raises(
            UserError, match="a reach scene cannot be set from a task input; valid: the marker families"
        ):
            reach.reset(seed=0, options={"task_input": np.zeros(3)})
    finally:
        reach.close()


def test_a_swapped_push_scene_means_to_one_task_what_the_original_means_to_the_other():
    red, blue = make("panda", "push_red"), make("panda", "push_blue")
    try:
        obs, _ = red.reset(seed=5)
        original = np.r_[obs["task_state"], obs["desired_goal"]].astype(np.float32)
        swapped = colour_swapped(original[None], EnvPart("push_red"), EnvPart("push_blue"))[0]
        seen, _ = blue.reset(seed=9, options={"task_input": swapped})
        # the object where it was, the blue marker where the red one was: the same push
        np.testing.assert_allclose(seen["achieved_goal"], obs["achieved_goal"], atol=1e-5)
        np.testing.assert_allclose(seen["task_state"][:3], obs["task_state"][:3], atol=1e-5)
        blue_there = obs["task_state"][:3] - obs["task_state"][15:18]  # push_blue's in the original
        assert np.linalg.norm(seen["achieved_goal"] - blue_there) >= 0.1  # markers 0.1 m apart
    finally:
        red.close(), blue.close()


@pytest.mark.e2e
def test_anchors_matched_by_outcome_mean_to_the_task_module_what_they_mean_to_the_robot_module():
    """The robot module's anchors are reach_blue scenes; the robot source (a blue reacher on
    panda_far) ends each where its blue marker is; the reach_red scene ending nearest takes its
    place, so its red marker lies where the anchor's blue one does. Outcomes are where the arm
    ended: a policy that goes nowhere ends every anchor at one point."""
    anchors = np.array(
        [
            r["task_input"]
            for r in evaluate(Reacher(), "panda", "reach_blue", episodes=12, repeats=1, seed=77)["records"]
        ],
        np.float32,
    )
    ends = anchor_ends(Reacher(), "panda_far", "reach_blue", anchors)
    assert np.median(np.linalg.norm(ends - anchors[:, BLUE], axis=1)) < 0.05  # it reached them
    red = outcomes(Reacher(), "panda", "reach_red", 80)
    matched = match_anchors(red, ends)
    assert matched.shape == anchors.shape
    gap = np.linalg.norm(matched[:, RED] - anchors[:, BLUE], axis=1)
    unmatched = np.linalg.norm(matched[::-1][:, RED] - anchors[:, BLUE], axis=1)
    assert np.median(gap) < 0.05 and np.median(unmatched) > 2 * np.median(gap)
    still = anchor_ends(lambda obs: np.zeros((len(obs["robot_state"]), 7)), "panda", "reach_blue", anchors)
    np.testing.assert_allclose(still, still[:1].repeat(len(anchors), 0), atol=1e-6)


def test_the_swapped_anchors_are_the_robot_module_s_with_the_two_markers_traded():
    """anchors@swapped needs no rollout: anchor j, a scene of the robot source's task (reach_red),
    with red and blue trading places is the reach_blue scene that means the same."""
    anchors = np.arange(27, dtype=np.float32).reshape(3, 9)
    task_source = ("never-read.safetensors", EnvPart("panda"), EnvPart("reach_blue"))
    robot_source = ("never-read.safetensors", EnvPart("panda_far"), EnvPart("reach_red"))
    swapped = matched_anchors("swapped", anchors, task_source, robot_source, scenes=10)
    np.testing.assert_array_equal(swapped[:, BLUE], anchors[:, RED])
    np.testing.assert_array_equal(swapped[:, RED], anchors[:, BLUE])


def test_anchors_matched_by_both_outcomes_are_the_anchors_with_the_meanings_traded():
    """Sources that end at their own marker (as trained reachers do, to a cm): one outcome finds a
    scene whose red marker is where the anchor's blue one is, with its blue marker anywhere; both
    outcomes also put its blue marker where the anchor's red one is, without reading a target."""
    rng = np.random.default_rng(0)

    def scenes(n: int) -> np.ndarray:
        markers = rng.uniform((-0.1, -0.1, 0.1), (0.1, 0.1, 0.2), size=(n, 2, 3)).reshape(n, 6)
        return np.hstack([markers, np.zeros((n, 3))]).astype(np.float32)

    def ends(states: np.ndarray, marker: slice) -> np.ndarray:
        return states[:, marker] + rng.normal(0, 0.01, size=(len(states), 3))

    candidates, anchors = scenes(2000), scenes(30)  # blue scenes; the robot module's red anchors
    mine = Outcomes(candidates, ends(candidates, BLUE))  # the blue source ends at blue
    one = match_anchors(mine, ends(anchors, RED))
    both = match_anchors_by_both(mine, ends(candidates, RED), ends(anchors, RED), ends(anchors, BLUE))
    meant = np.linalg.norm(both[:, BLUE] - anchors[:, RED], axis=1)
    other = np.linalg.norm(both[:, RED] - anchors[:, BLUE], axis=1)
    other_one = np.linalg.norm(one[:, RED] - anchors[:, BLUE], axis=1)
    assert np.median(meant) < 0.04 and np.median(other) < 0.04
    assert np.median(other_one) > 2 * np.median(other)  # one outcome leaves the other marker anywhere


def test_anchors_decoded_from_both_outcomes_lie_between_the_candidates():
    """Among as few candidate scenes as a stage rolls out (400), the nearest one to both outcomes
    is some cm off; an affine map from a scene's two outcomes to the scene, fitted on the
    candidates, decodes each anchor with its meanings traded to about the sources' own noise."""
    rng = np.random.default_rng(1)
    low, high = (-0.1, -0.1, 0.1), (0.1, 0.1, 0.2)

    def scenes(n: int) -> np.ndarray:
        markers = rng.uniform(low, high, size=(n, 2, 3)).reshape(n, 6)
        return np.hstack([markers, np.zeros((n, 3))]).astype(np.float32)

    def ends(states: np.ndarray, marker: slice) -> np.ndarray:  # 1 cm of end-point noise
        return states[:, marker] + rng.normal(0, 0.01, size=(len(states), 3))

    candidates, anchors = scenes(400), scenes(128)
    mine = Outcomes(candidates, ends(candidates, BLUE))
    crossed = (mine, ends(candidates, RED), ends(anchors, RED), ends(anchors, BLUE))
    truth = np.hstack([anchors[:, BLUE], anchors[:, RED], anchors[:, 6:]])  # the known swap
    nearest = np.linalg.norm(match_anchors_by_both(*crossed) - truth, axis=1)
    decoded = decode_anchors(*crossed)
    assert decoded.shape == anchors.shape and decoded.dtype == np.float32
    error = np.linalg.norm(decoded - truth, axis=1)
    assert np.median(error) < 0.03  # about sqrt(2 x 3) x 1 cm: the noise of the two outcomes
    assert np.median(error) < 0.6 * np.median(nearest)
    np.testing.assert_allclose(decoded[:, 6:], 0, atol=1e-6)  # a constant part stays as it is


def test_a_fit_is_priced_in_the_env_steps_its_rollouts_take():
    """affine@outcome rolls out both sources on every scene; re-anchoring by one outcome the task
    source on its scenes and the robot source on each anchor; by both outcomes also the robot
    source on each successful candidate and the task source on each anchor; swapped nothing."""
    from ps_ray.stitching.outcomes import fit_env_steps

    assert fit_env_steps("affine", "outcome", 400) == 2 * 400 * 50
    assert fit_env_steps("anchors", "outcome", 400, anchors=128) == (400 + 128) * 50
    assert fit_env_steps("anchors", "both", 400, anchors=128, candidates=300) == (400 + 300 + 256) * 50
    assert fit_env_steps("anchors", "swapped", 400, anchors=128) == 0
