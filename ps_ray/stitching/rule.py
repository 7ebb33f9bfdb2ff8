"""The stitching rules, on signatures and training specs alone (no torch, no Ray): which pairs
meet (:func:`meets`, :func:`stitchable`: the one pairing rule the stitching stages and the cost
model ask), what must agree for two modules to be stitched (:func:`stitch_problems`) and what a
policy needs to run a target env (:func:`target_problems`).

What must agree (:func:`stitch_problems`): method, latent width at the cut (the interface dim;
devin's is fixed at 16, plain's is ``hidden``), hidden width and anchor set (PS); a deferred
relative projection (ps_distilled) must be switched on in both. Dims: the task module brings the
task-input width, the robot module the robot-state and action widths, so a push task module (7-D
actions) can meet a pick robot module (8-D). Plain is one MLP cut in the middle: its bottom half
also sees the robot state (and, in a critic, the action), so both halves must agree on every dim.
Given a target env, the stitched dims must be the env's.

Target env (:func:`default_target`): the task of the task module, run by the same physical robot
as the robot module, i.e. with the gripper setting that robot module was trained with. A robot
module trained on pick (gripper on, 8-D actions) therefore drives a gripper-enabled push robot
(docs/authors_code.md §1, Push-v4), ``{"name": "panda_l3", "gripper": true}`` on push; a robot
module trained without the gripper cannot run a pick task (refused). So that a *push* robot
module can serve a pick target (E5), it must have been trained with the gripper: list ``{name:
panda_l3, gripper: true}`` among the sweep's robots, as ``sweeps/few_shot.yaml`` does.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from ps_ray.envs.core import effective_gripper, env_widths
from ps_ray.envs.robots import arm
from ps_ray.envs.tasks import resolve_task
from ps_ray.errors import UserError
from ps_ray.specs.names import EnvPart
from ps_ray.store.signature import Signature

EnvSpec = tuple[EnvPart, EnvPart]  # (robot, task)


# -- target envs ----------------------------------------------------------------------------------
def same_robot(robot: EnvPart, trained_task: EnvPart, target_task: EnvPart) -> EnvPart:
    """``robot`` as trained on ``trained_task``, for ``target_task``: the gripper setting is pinned
    when the two tasks' defaults differ (pick-trained panda_l3 on push -> gripper-enabled)."""
    gripper = effective_gripper(robot, trained_task)
    if gripper == effective_gripper(robot, target_task):
        return robot
    return EnvPart({**robot, "gripper": gripper})


def default_target(task_spec: Mapping, robot_spec: Mapping) -> EnvSpec:
    """(robot, task) of the target env from the two sources' training specs."""
    task = EnvPart(task_spec["task"])
    return same_robot(EnvPart(robot_spec["robot"]), EnvPart(robot_spec["task"]), task), task


# -- checks ---------------------------------------------------------------------------------------
def stitch_problems(sig_task: Signature, sig_robot: Signature, target: EnvSpec | None = None) -> list[str]:
    """Every reason the task modules of ``sig_task`` and robot modules of ``sig_robot`` cannot be
    stitched (into a policy for ``target``, if given); empty if they can."""
    problems = []
    pair = lambda a, b: f"task module {a!r} vs robot module {b!r}"  # noqa: E731
    if sig_task.spec != sig_robot.spec:  # resolved: a setting newer than one file reads as its default
        problems.append(f"method: {pair(sig_task.method, sig_robot.method)}")
    else:
        spec = sig_task.spec
        latents = [spec.latent_dim(s.interface_dim, s.hidden) for s in (sig_task, sig_robot)]
        if spec.modular and latents[0] != latents[1]:  # plain's latent is `hidden`, checked below
            problems.append(f"interface dim: {pair(*latents)}")
        if not spec.modular:  # plain: the bottom half sees the robot state and (critic) action
            for dim in ("robot_dim", "action_dim"):
                a, b = getattr(sig_task, dim), getattr(sig_robot, dim)
                if a != b:
                    problems.append(f"{dim.replace('_', ' ')} (plain needs equal dims): {pair(a, b)}")
    for role, sig in (("task module", sig_task), ("robot module", sig_robot)):
        if not sig.stitchable:
            problems.append(
                f"the {role}'s policy is from before its method {sig.method!r} switched to the "
                f"relative interface (at its run's end): stitch a finished run's policy.safetensors"
            )
    if sig_task.hidden != sig_robot.hidden:
        problems.append(f"hidden: {pair(sig_task.hidden, sig_robot.hidden)}")
    if sig_task.anchor_hash != sig_robot.anchor_hash:
        short = lambda h: h[:12] or "none"  # noqa: E731
        problems.append(f"anchor set: {pair(short(sig_task.anchor_hash), short(sig_robot.anchor_hash))}")
    if target is not None:
        problems += target_problems(stitched_signature(sig_task, sig_robot), target)
    return problems


def target_problems(signature: Signature, target: EnvSpec) -> list[str]:
    """Reasons a policy with ``signature`` cannot run the target env (robot, task)."""
    robot, task = EnvPart(target[0]), EnvPart(target[1])
    name = f"target env ({robot.short}, {task.short})"
    try:
        dims = dict(zip(("task_dim", "robot_dim", "action_dim"), env_widths(robot, task)))
        needs_gripper = resolve_task(task).family.default_gripper
    except (ValueError, TypeError) as e:
        return [f"{name}: {e}"]
    problems = [
        f"{what}: policy {getattr(signature, field)} vs {name} {dims[field]}"
        for what, field in (
            ("task dim", "task_dim"),
            ("robot dim", "robot_dim"),
            ("action dim", "action_dim"),
        )
        if getattr(signature, field) != dims[field]
    ]
    if needs_gripper and not effective_gripper(robot, task):
        problems.append(
            f"{name}: {task.short} needs the gripper; use a robot module "
            f'trained with it, e.g. robot {{"name": ..., "gripper": true}}'
        )
    return problems


def start_problems(spec, signature: Signature) -> list[str]:
    """Why a policy file of ``signature`` cannot start a training run of ``spec`` (a TrainSpec whose
    ``init_policy`` it is): another method, interface dim or hidden width, nets that cannot run
    its env, or a stitch aligned at stitch time (for zero-shot use only); empty when it can. Reads
    the signature alone: no nets are built."""
    wanted = (spec.method, spec.interface_dim, spec.hidden)
    found = (signature.method, signature.interface_dim, signature.hidden)
    problems = [] if found == wanted else [f"(method, interface dim, hidden) {found} vs {wanted}"]
    if spec.env is None:
        problems += target_problems(signature, (spec.robot, spec.task))
    if signature.translation:
        problems.append(f"a stitch aligned at stitch time ({signature.translation}) is for zero-shot use")
    return problems


def check_stitchable(sig_task: Signature, sig_robot: Signature, target: EnvSpec | None = None) -> Signature:
    """The stitched policy's signature, or one ValueError naming every mismatch."""
    problems = stitch_problems(sig_task, sig_robot, target)
    if problems:
        raise UserError("cannot stitch: " + "; ".join(problems))
    return stitched_signature(sig_task, sig_robot)


def stitched_signature(sig_task: Signature, sig_robot: Signature) -> Signature:
    return dataclasses.replace(sig_task, robot_dim=sig_robot.robot_dim, action_dim=sig_robot.action_dim)


# -- the pairing rule: the stitching stages and the cost model ask it ------------------------------
def meets(task_from: Mapping, robot_from: Mapping) -> EnvSpec | None:
    """Whether the task module of one trained spec meets the robot module of another (another
    task, another arm): their target env (robot, task), else None. The signatures then decide
    (:func:`stitch_problems`), from policy files or, before training, from :func:`expected_signature`."""
    if EnvPart(task_from["task"]) == EnvPart(robot_from["task"]):
        return None
    if arm(task_from["robot"]) == arm(robot_from["robot"]):
        return None
    return default_target(task_from, robot_from)


def expected_signature(spec: Mapping) -> Signature:
    """The signature a training spec's policy file will carry, from the spec alone; the anchor
    set stands as the task-input width it is drawn for (a sweep draws one per width and K:
    ps_ray.plan.train.anchor_file)."""
    from ps_ray.specs.methods import method_spec, spec_json, uses_anchors

    method = method_spec(str(spec["method"]))
    task_dim, robot_dim, action_dim = env_widths(spec["robot"], spec["task"])
    return Signature(
        method=method.name,
        interface_dim=int(spec["interface_dim"]),
        hidden=int(spec["hidden"]),
        anchor_hash=f"anchors for {task_dim}-D task inputs" if uses_anchors(method.name) else "",
        task_dim=task_dim,
        robot_dim=robot_dim,
        action_dim=action_dim,
        settings=spec_json(method),
    )


def stitchable(
    task_from: Mapping, robot_from: Mapping, sig_task: Signature, sig_robot: Signature
) -> EnvSpec | None:
    """The one pairing rule: the target env of a (task module, robot module) pair of two trained
    specs with these signatures, or None where they do not meet or cannot be stitched for it."""
    target = meets(task_from, robot_from)
    if target is None or stitch_problems(sig_task, sig_robot, target):
        return None
    return target
