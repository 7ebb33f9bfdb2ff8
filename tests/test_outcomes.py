"""Task states paired by meaning (ps_ray.stitching.outcomes): each task's own policy rolled out,
its outcomes described by where the arm ended, matched across tasks through k-means points."""

from __future__ import annotations

import numpy as np
import pytest

from ps_ray.errors import UserError
from ps_ray.specs.names import EnvPart
from ps_ray.stitching.evaluate import evaluate
from ps_ray.stitching.outcomes import colour_swapped, matched_pairs, outcomes

RED, BLUE = slice(0, 3), slice(3, 6)  # the marker task state: red's position, then blue's


class Reacher:
    """A policy that knows its task (as a trained source does): it drives to the named marker."""

    def begin(self, envs, seeds) -> None:
        self.envs = envs

    def __call__(self, obs) -> np.ndarray:
        return np.stack([env.action_toward(env.task.target_position) for env in self.envs])


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


def test_the_swapped_scene_trades_the_two_tasks_markers():
    states = np.arange(18, dtype=np.float32).reshape(2, 9)
    swapped = colour_swapped(states, EnvPart("reach_red"), EnvPart("reach_blue"))
    np.testing.assert_array_equal(swapped[:, RED], states[:, BLUE])
    np.testing.assert_array_equal(swapped[:, BLUE], states[:, RED])
    np.testing.assert_array_equal(swapped[:, 6:], states[:, 6:])  # the goal offset stays
    with pytest.raises(UserError, match="two tasks of the marker family, got reach and reach_blue"):
        colour_swapped(states, EnvPart("reach"), EnvPart("reach_blue"))
