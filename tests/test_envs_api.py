"""ps_ray.envs API: gymnasium checker, registration, error messages, rendering."""

from __future__ import annotations

import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from ps_ray.envs import BUILTIN_PAIRS, ROBOTS, TASKS, RobotSpec, make
from ps_ray.envs.registry import create_env, env_id, register
from ps_ray.envs.render import record

IDS = register(rllib=False)


def test_builtin_pairs_and_ids():
    assert len(BUILTIN_PAIRS) == len(ROBOTS) * len(TASKS)
    assert {"panda", "panda_l3", "panda_l5"} <= set(ROBOTS)
    assert {"reach", "push", "push_slippery", "push_rocks", "pick_cube", "pick_stick"} <= set(TASKS)
    assert env_id("panda_l3", "push_slippery") == "ps_ray/PandaL3PushSlippery-v0"
    assert env_id("panda_side", "reach_red") == "ps_ray/PandaSideReachRed-v0"
    assert len(set(IDS)) == len(BUILTIN_PAIRS) and register(rllib=False) == IDS  # idempotent


@pytest.mark.parametrize("robot,task", BUILTIN_PAIRS)
def test_gymnasium_check_env(robot, task):
    env = gymnasium.make(env_id(robot, task), disable_env_checker=True).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any checker warning fails the test
        check_env(env)
    assert env.observation_space["robot_state"].shape == (8,)
    # markers: 3 per marker; objects: 12; an object and two markers: 18
    widths = {"reach": 0, "reach_red": 6, "reach_blue": 6, "push_red": 18, "push_blue": 18}
    assert env.observation_space["task_state"].shape == (widths.get(task, 12),)
    assert env.action_space.shape == ((8,) if task.startswith("pick") else (7,))
    env.close()


def test_gymnasium_make_passes_options():
    env = gymnasium.make("ps_ray/PandaReach-v0", goal_region="q3")
    assert env.unwrapped.task_spec.options.goal_region == "q3"
    env.close()


@pytest.mark.e2e
def test_rllib_creator_and_registration():
    env = create_env(
        {"robot": {"base": "panda", "locked_joints": [1]}, "task": "push", "object_friction": 0.2}
    )
    assert env.robot_spec == RobotSpec(locked_joints=(1,))
    assert env.task_spec.options.object_friction == 0.2
    code = (
        "from ps_ray.envs.registry import register, RLLIB_ENV; register();"
        "from ray.tune.registry import _global_registry, ENV_CREATOR;"
        "env = _global_registry.get(ENV_CREATOR, RLLIB_ENV)({'robot': 'panda_l5', 'task': 'reach'});"
        "print(env.reset(seed=0)[0]['robot_state'].shape)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "(8,)" in out.stdout


@pytest.mark.e2e
def test_envs_import_no_torch_or_ray():
    code = "import sys, ps_ray.envs, ps_ray.envs.render; print('torch' in sys.modules, 'ray' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.split() == ["False", "False"], out.stderr


@pytest.mark.parametrize(
    "kwargs,fragments",
    [
        ({"robot": "pandaa"}, ["'pandaa'", "panda, panda_l3, panda_l5"]),
        ({"task": "pusj"}, ["'pusj'", "reach, push, push_slippery, push_rocks, pick_cube, pick_stick"]),
        ({"robot": {"locked_joints": [7]}}, ["7", "0..6"]),
        ({"robot": {"locked_joints": [-1]}}, ["-1", "0..6"]),
        ({"robot": {"base": "ur5"}}, ["'ur5'", "panda"]),
        ({"robot": {"lock": [1]}}, ["'lock'", "locked_joints"]),
        ({"task": "push", "object_frction": 0.1}, ["'object_frction'", "object_friction"]),
        ({"task": {"name": "reach", "goal_regoin": "q1"}}, ["'goal_regoin'", "goal_region"]),
        ({"task": "reach", "goal_region": "q5"}, ["'q5'", "q1, q2, q3, q4"]),
        ({"task": {"goal_region": "q1"}}, ["'name'", "reach"]),
        ({"render_mode": "human"}, ["'human'", "rgb_array"]),
    ],
)
def test_bad_input_names_the_value_and_the_choices(kwargs, fragments):
    with pytest.raises(ValueError) as err:
        make(**kwargs)
    for fragment in fragments:
        assert fragment in str(err.value), str(err.value)


def test_robot_error_message_exact():
    with pytest.raises(ValueError, match=rf"^unknown robot 'pandaa'; valid robots: {', '.join(ROBOTS)}$"):
        make("pandaa", "reach")


def test_render_frame_and_files(tmp_path):
    env = make("panda_l3", "pick_stick", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (360, 480, 3) and frame.dtype == np.uint8
    assert frame.std() > 20 and len(np.unique(frame.reshape(-1, 3), axis=0)) > 50  # not blank
    assert make("panda", "reach").render() is None  # no render_mode: no frame
    frames = record("panda", "push", seed=0, png=tmp_path / "last.png", gif=tmp_path / "ep.gif", every=10)
    assert len(frames) == 6 and (tmp_path / "last.png").stat().st_size > 1000
    from PIL import Image

    with Image.open(tmp_path / "ep.gif") as gif:
        assert gif.n_frames == 6 and gif.size == (480, 360)
    # a picture alone renders only the first and last frames, and is the same picture
    alone = record("panda", "push", seed=0, png=tmp_path / "alone.png")
    assert len(alone) == 2 and np.array_equal(alone[-1], frames[-1])
    assert (tmp_path / "alone.png").read_bytes() == (tmp_path / "last.png").read_bytes()
