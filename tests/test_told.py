"""The robot source told the task (ps_ray.stitching.told): its own policy on the target with the
two tasks' markers traded in what it reads, so that it drives to the marker the target names."""

from __future__ import annotations

import numpy as np
import pytest

from ps_ray.specs.names import EnvPart
from ps_ray.stitching.evaluate import evaluate
from ps_ray.stitching.told import TellTask, can_tell

BLUE = slice(3, 6)  # the reach markers' task state: red's position, then blue's


class BlueReacher:
    """A reach_blue source that reads its marker from the task input, as a trained one does."""

    def begin(self, envs, seeds) -> None:
        self.envs = envs

    def __call__(self, obs) -> np.ndarray:
        return np.stack([env.action_toward(obs["task_state"][i, BLUE]) for i, env in enumerate(self.envs)])


def test_a_blue_reacher_told_the_red_task_reaches_the_red_marker():
    kwargs = dict(episodes=4, repeats=1, seed=11, num_envs=4)
    as_it_is = evaluate(BlueReacher(), "panda", "reach_red", **kwargs)
    told = evaluate(
        TellTask(BlueReacher(), EnvPart("reach_red"), EnvPart("reach_blue")), "panda", "reach_red", **kwargs
    )
    assert as_it_is["success_mean"] == 0.0 and as_it_is["wrong_target_mean"] == 1.0  # it goes to blue
    assert told["success_mean"] == 1.0 and told["wrong_target_mean"] == 0.0
    assert told["episodes_digest"] == as_it_is["episodes_digest"]  # on the same episodes


@pytest.mark.parametrize(
    "task, robot_task, tellable",
    [
        ("reach_red", "reach_blue", True),
        ("push_blue", "push_red", True),
        ("reach_red", "reach_red", False),  # the same task: nothing to tell
        ("push_red", "reach_blue", False),  # two families: no markers to trade
        ("push", "push_slippery", False),  # no markers at all
        ({"name": "push_red", "marker_state": "from_object"}, "push_blue", False),  # said otherwise
    ],
)
def test_only_two_tasks_of_one_marker_family_naming_different_markers_can_be_told(task, robot_task, tellable):
    assert can_tell(EnvPart(task), EnvPart(robot_task)) is tellable
