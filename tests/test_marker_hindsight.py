"""Hindsight that moves the named marker (train setting ``hindsight: marker``): a relabelled
transition keeps its real goal, and its scene is the one in which the named marker stood where the
episode's later outcome puts that goal; its reward is plain 'future' relabelling's."""

from __future__ import annotations

import numpy as np
import pytest

from ps_ray.data.her import HindsightReplay, MarkerShift
from ps_ray.envs import make
from ps_ray.envs.goals import goal_reward
from ps_ray.specs.engine import SpecError
from ps_ray.specs.train import TrainSpec, marker_columns


def episodes(env, n: int, seed: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """n episodes of random actions, as (obs (n, T+1, ...), actions (n, T, A))."""
    rng = np.random.default_rng(seed)
    obs_eps, act_eps = [], []
    for e in range(n):
        obs, _ = env.reset(seed=seed + e)
        steps, acts = [obs], []
        for _ in range(env.max_episode_steps):
            a = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            obs, *_ = env.step(a)
            steps.append(obs)
            acts.append(a)
        obs_eps.append({k: np.stack([s[k] for s in steps]) for k in obs})
        act_eps.append(np.stack(acts))
    return {k: np.stack([o[k] for o in obs_eps]) for k in obs_eps[0]}, np.stack(act_eps)


def replays(env, marker: MarkerShift) -> tuple[HindsightReplay, HindsightReplay]:
    spec = {k: (s.shape, np.float32) for k, s in env.observation_space.spaces.items()}
    args = (spec, env.action_space.shape[0], env.max_episode_steps, 8, goal_reward)
    return HindsightReplay(*args, seed=3), HindsightReplay(*args, seed=3, marker=marker)


@pytest.mark.parametrize("state", ["position", "from_object"])
def test_a_relabelled_transition_keeps_its_goal_and_is_the_scene_with_the_marker_moved(state):
    env = make("panda", {"name": "push_blue", "marker_state": state})
    columns, sign = marker_columns(env.task_spec)
    assert columns == slice(15, 18) and sign == (1.0 if state == "position" else -1.0)
    obs, actions = episodes(env, 3, seed=11)
    plain, moved = replays(env, MarkerShift("task_state", columns, sign))
    for replay in (plain, moved):
        replay.add_episodes(obs, actions)
    a, b = plain.sample(400), moved.sample(400)  # the same draws: one seed, one RNG use
    np.testing.assert_array_equal(a["rewards"], b["rewards"])
    np.testing.assert_array_equal(b["obs/desired_goal"], np.zeros((400, 3)))  # real goals only
    shift = a["obs/desired_goal"] - b["obs/desired_goal"]
    relabelled = np.abs(shift).sum(1) > 0
    assert 0.6 < relabelled.mean() < 0.95
    for side in ("obs", "next_obs"):
        moved_columns = b[f"{side}/task_state"][:, columns] - a[f"{side}/task_state"][:, columns]
        np.testing.assert_allclose(moved_columns, sign * shift, atol=1e-6)
        np.testing.assert_array_equal(b[f"{side}/task_state"][:, :15], a[f"{side}/task_state"][:, :15])
        np.testing.assert_allclose(b[f"{side}/achieved_goal"], a[f"{side}/achieved_goal"] - shift, atol=1e-6)
    # the scene a relabelled input says, set in the env, is the one the sample says it is
    for i in np.flatnonzero(relabelled)[:10]:
        env.reset(options={"task_input": np.concatenate([b["obs/task_state"][i], b["obs/desired_goal"][i]])})
        seen = env.task.observe(env.robot.ee_position())
        np.testing.assert_allclose(seen[0], b["obs/task_state"][i], atol=1e-4)
        np.testing.assert_allclose(seen[1], b["obs/achieved_goal"][i], atol=1e-4)
    # what the normalisers see: the same inputs, goals real
    seen = moved.relabelled(obs)
    np.testing.assert_array_equal(seen["desired_goal"], np.zeros_like(seen["desired_goal"]))
    collected = obs["task_state"][:, :-1].reshape(-1, 18)
    assert not np.allclose(seen["task_state"][:, columns], collected[:, columns])


def test_hindsight_marker_needs_a_task_said_in_a_marker_s_frame():
    assert TrainSpec(task="reach_red", hindsight="marker").hindsight == "marker"
    assert "hindsight" not in TrainSpec(task="push_red").to_dict()  # earlier runs keep their identity
    with pytest.raises(SpecError, match="needs a task said in a marker's frame, got task 'push'"):
        TrainSpec(task="push", hindsight="marker")
    with pytest.raises(SpecError, match="got task"):
        TrainSpec(task={"name": "push_red", "goal_frame": "world"}, hindsight="marker")
    with pytest.raises(SpecError, match="unknown hindsight 'scene'; valid hindsight: goal, marker"):
        TrainSpec(task="push_red", hindsight="scene")


@pytest.mark.e2e
def test_the_learner_s_replay_moves_the_marker_when_the_spec_says_so(ray_local):
    from ps_ray.rllib.algo import algo_config
    from tests.small_runs import CELL_TRAIN

    spec = TrainSpec.from_mapping({**CELL_TRAIN, "task": "push_blue", "hindsight": "marker", "seed": 5})
    algo = algo_config(spec, None).build_algo()
    try:
        assert algo.replay.marker == MarkerShift("task_state", slice(15, 18), 1.0)
        for _ in range(2):
            algo.train()
        batch = algo.replay.sample(256)  # what the learner read: real goals, the blue marker moved
        np.testing.assert_array_equal(batch["obs/desired_goal"], np.zeros((256, 3)))
        assert (batch["rewards"] == 0).any() and algo.counters["updates"] > 0
    finally:
        algo.stop()
