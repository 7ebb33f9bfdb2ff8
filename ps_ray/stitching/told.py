"""The robot source told the task: its own policy run on the target with the two tasks' markers
traded in what it reads (:func:`ps_ray.stitching.outcomes.colour_swapped`), so that its task
means there what the target's task means.

On a family whose tasks share a scene and differ in which marker they name (the reach markers,
the push family), a stitch joins the target task's module to the robot source's robot module
through a map of latents. The best such a map can do is give the robot module exactly the latent
its own task module would give on the traded scene, which is this policy. Its success on the
pair's episodes is the ceiling of every translation of the pair (a perfect map, not a fitted one):
beside the stitch it says how much of the remaining gap a better map could close, and how much is
the robot source's own skill. It reads the target's marker, so it is an upper bound, never a
control a stitch must beat.
"""

from __future__ import annotations

import numpy as np

from ps_ray.envs.tasks import resolve_task
from ps_ray.envs.tasks.markers import MarkerScene
from ps_ray.specs.names import EnvPart
from ps_ray.stitching.outcomes import colour_swapped


def can_tell(task: EnvPart, robot_task: EnvPart) -> bool:
    """Whether the robot source's task can be told ``task``: two tasks of one marker family that
    name different markers."""
    spec, other = resolve_task(task), resolve_task(robot_task)
    return (
        issubclass(spec.family, MarkerScene)
        and spec.family is other.family
        and spec.options.target != other.options.target
    )


class TellTask:
    """A batched action function (``act``, as :func:`ps_ray.stitching.evaluate.evaluate` takes)
    that reads ``task``'s scene with its marker and ``robot_task``'s trading places; a scripted
    policy's ``begin`` is passed on."""

    def __init__(self, act, task: EnvPart, robot_task: EnvPart) -> None:
        self.act, self.task, self.robot_task = act, task, robot_task

    def begin(self, envs, seeds) -> None:
        if hasattr(self.act, "begin"):
            self.act.begin(envs, seeds)

    def __call__(self, obs) -> np.ndarray:
        told = dict(obs)
        told["task_state"] = colour_swapped(obs["task_state"], self.task, self.robot_task)
        return self.act(told)
