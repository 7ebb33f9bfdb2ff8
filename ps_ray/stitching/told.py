"""The robot source told the task: its own policy run on the target with the two tasks' markers
traded in what it reads (:func:`ps_ray.stitching.outcomes.colour_swapped`), so that its task
means there what the target's task means.

On a family whose tasks share a scene and differ in which marker they name (the reach markers,
the push family), a stitch joins the target task's module to the robot source's robot module
through a map of latents. A perfect map gives the robot module exactly the latent its own task
module would give on the traded scene, which is this policy. Its success on the pair's episodes
is the ceiling the report shows (what a perfect map reaches; not a strict bound, as a map could
in principle hand the robot module latents it acts on better than its own): beside the stitch
it says how much of the gap a better map could close, and how much is the robot source's own
skill. It reads the target's marker, so it is never a control a stitch must beat.
"""

from __future__ import annotations

import numpy as np

from ps_ray.envs.tasks import resolve_task
from ps_ray.envs.tasks.markers import MarkerScene
from ps_ray.specs.names import EnvPart
from ps_ray.stitching.outcomes import colour_swapped

# the options two tasks of a marker family must share for their scenes to be said alike
SCENE_OPTIONS = ("markers", "marker_state", "goal_frame")


def can_tell(task: EnvPart, robot_task: EnvPart) -> bool:
    """Whether the robot source's task can be told ``task``: two tasks of one marker family that
    say their scenes alike (:data:`SCENE_OPTIONS`) and name different markers."""
    spec, other = resolve_task(task), resolve_task(robot_task)
    alike = all(getattr(spec.options, k, None) == getattr(other.options, k, None) for k in SCENE_OPTIONS)
    return (
        issubclass(spec.family, MarkerScene)
        and spec.family is other.family
        and alike
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
