"""The chance-level control (ps_ray.stitching.chance): policies with no task knowledge, scored on
the pair's own episodes, that still move the target robot on purpose."""

from __future__ import annotations

import numpy as np
import pytest

from ps_ray.envs import make
from ps_ray.envs.goals import SUCCESS_DISTANCE
from ps_ray.stitching.chance import DriveTo, RandomPoint, chance, has_floor, task_blind
from ps_ray.stitching.evaluate import evaluate

EPISODES = {"episodes": 30, "repeats": 1, "seed": 7}


@pytest.mark.parametrize("robot", ["panda", "panda_far"])
def test_the_arm_reaches_a_named_point_by_inverse_kinematics(robot):
    """What the random-point policy relies on: aimed at the env's own target, it reaches it."""
    env = make(robot, "reach_red")
    wins = []
    for seed in range(3):
        env.reset(seed=seed)
        for _ in range(50):
            _, _, _, _, info = env.step(env.action_toward(env.task.target_position))
        wins.append(info["is_success"])
    env.close()
    assert wins == [True] * 3


def test_random_points_lie_in_the_task_s_target_region_and_follow_the_episode_seed():
    env = make("panda", "reach_red")
    low, high = env.target_region()
    np.testing.assert_array_equal(low, env.task.options.marker_low)
    policy, again = RandomPoint(), RandomPoint()
    policy.begin([env] * 50, list(range(50)))
    again.begin([env] * 50, list(range(50)))
    points = np.stack(policy.points)
    assert ((points >= low) & (points <= high)).all()
    np.testing.assert_array_equal(points, np.stack(again.points))
    assert len(np.unique(points.round(6), axis=0)) == 50
    env.close()


@pytest.mark.e2e
def test_chance_on_the_marker_family_is_scored_on_the_pair_s_episodes():
    """On the pair's episodes (same digest as any policy's evaluation with those settings), the
    best of the two chance policies; a random point in the marker box reaches the named marker
    now and then (about 8% of the time over many episodes), never as a trained policy does."""
    found = chance("panda", "reach_blue", EPISODES)
    other = evaluate(lambda obs: np.zeros((len(obs["robot_state"]), 7)), "panda", "reach_blue", **EPISODES)
    assert found["episodes_digest"] == other["episodes_digest"]
    assert found["chance_success"] == max(found["random_point_success"], found["random_actions_success"])
    assert found["chance_policy"] in ("random_point", "random_actions")
    assert found["random_point_success"] <= 0.25 and found["random_actions_success"] <= 0.25


@pytest.mark.e2e
def test_the_task_blind_floor_is_the_mean_over_the_markers_on_the_pair_s_episodes():
    """The floor for a transfer claim on the marker family: it can reach every marker but is not
    told which one the task names. Taken in expectation, each episode is driven to both markers:
    the named marker's term is exactly a policy that always drives to the named marker, the other
    term reaches the named one almost never, so the floor is half of the named term, per episode
    one of 0, 1/2, 1, and no draw enters it (the same figure on any repeat of the evaluation)."""
    found = chance("panda_far", "reach_blue", EPISODES)
    floor = task_blind("panda_far", "reach_blue", EPISODES)
    named = evaluate(NamedMarker(), "panda_far", "reach_blue", **EPISODES)
    other = evaluate(OtherMarker(), "panda_far", "reach_blue", **EPISODES)
    pair = evaluate(lambda obs: np.zeros((len(obs["robot_state"]), 7)), "panda_far", "reach_blue", **EPISODES)
    assert named["episodes_digest"] == pair["episodes_digest"] == floor["episodes_digest"]  # the pair's
    assert floor["task_blind_per_candidate"][1] == named["success_mean"]  # reach_blue names marker 1
    assert floor["task_blind_per_candidate"] == [other["success_mean"], named["success_mean"]]
    assert floor["task_blind_success"] == pytest.approx((named["success_mean"] + other["success_mean"]) / 2)
    assert named["success_mean"] >= 0.9 and other["success_mean"] <= 0.1  # the arm reaches what it aims at
    assert set(floor["task_blind_per_episode"]) <= {0.0, 0.5, 1.0}
    assert found["task_blind_success"] == floor["task_blind_success"]  # chance() reports the same floor
    again = task_blind("panda_far", "reach_blue", EPISODES)
    assert found["task_blind_success"] == again["task_blind_success"]
    assert found["task_blind_wrong_target"] == pytest.approx((named["wrong_target_mean"] + 1.0) / 2)
    assert found["task_blind_success"] > found["chance_success"]
    assert has_floor("reach_blue") and not has_floor("reach") and not has_floor("push")


def test_drive_to_aims_at_one_candidate_whatever_the_task_names():
    env = make("panda", "reach_red")
    env.reset(seed=3)
    policy = DriveTo(1)
    policy.begin([env], [3])
    np.testing.assert_array_equal(policy.points[0], env.candidate_targets()[1])
    env.close()


class NamedMarker:
    """Drives to the marker the task names, every episode."""

    def begin(self, envs, seeds) -> None:
        self.envs = list(envs)

    def __call__(self, obs):
        return np.stack([e.action_toward(e.candidate_targets()[e.named_candidate]) for e in self.envs])


class OtherMarker:
    """Drives to the marker the task does not name, every episode."""

    def begin(self, envs, seeds) -> None:
        self.envs = list(envs)

    def __call__(self, obs):
        return np.stack([e.action_toward(e.candidate_targets()[1 - e.named_candidate]) for e in self.envs])


def test_a_policy_that_always_reaches_the_other_marker_has_a_wrong_target_rate_of_one():
    result = evaluate(OtherMarker(), "panda", "reach_red", episodes=6, repeats=1, seed=11)
    assert result["wrong_target_mean"] == 1.0 and result["success_mean"] == 0.0
    for record in result["records"]:
        named, other = record["candidate_distances"]  # reach_red names marker 0
        assert other < SUCCESS_DISTANCE < named and record["wrong_target"]
    # a scene of one target has no wrong one: NaN, not 0
    still = lambda obs: np.zeros((len(obs["robot_state"]), 7))  # noqa: E731
    reach = evaluate(still, "panda", "reach", episodes=2, repeats=1)
    assert np.isnan(reach["wrong_target_mean"]) and reach["records"][0]["candidate_distances"] == ()
