"""Env steps/s per task (panda, random actions) next to a bare PyBullet loop of the same scene.

The bare loop replays, on the same bodies (same URDFs and shapes), exactly the motor targets the
env sent: per step one ``setJointMotorControlArray`` and the same 20 ``stepSimulation`` calls;
every 50 steps it puts the joints and the object back in place (no observation, no scene rebuild).
So both loops simulate the same motions. They run in this process, interleaved in rounds, and each
keeps its best round (robust to load from other processes).

    ps-ray bench env [--steps 2000] [--rounds 3] [--tasks push reach]
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import pybullet as p

from ps_ray.cli.args import Parser, positive_int
from ps_ray.envs import EPISODE_STEPS, TASKS, make


def _env_rate(env, actions: np.ndarray, record: bool = False) -> tuple[float, list, list]:
    """Steps/s of ``env.step`` (with a reset every 50 steps); optionally records targets and starts."""
    targets, starts = [], []
    cid = env.sim.client
    start = time.perf_counter()
    for i, action in enumerate(actions):
        if i % EPISODE_STEPS == 0:
            env.reset(seed=i)
            if record and env.task.object is not None:
                starts.append(p.getBasePositionAndOrientation(env.task.object, physicsClientId=cid))
        env.step(action)
        if record:
            targets.append(list(env.robot.target))
    return len(actions) / (time.perf_counter() - start), targets, starts


def _bare_rate(env, targets: list, starts: list) -> float:
    """Replay ``targets`` on ``env``'s scene with raw PyBullet calls only."""
    cid, body, obj, substeps = env.sim.client, env.robot.body, env.task.object, env.sim.substeps
    joints, forces, neutral = env.robot.joints, env.robot.forces, env.robot.neutral
    start = time.perf_counter()
    for i, target in enumerate(targets):
        if i % EPISODE_STEPS == 0:
            for joint, angle in zip(joints, neutral):
                p.resetJointState(body, joint, angle, 0.0, physicsClientId=cid)
            if obj is not None:
                p.resetBasePositionAndOrientation(obj, *starts[i // EPISODE_STEPS], physicsClientId=cid)
                p.resetBaseVelocity(obj, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
        p.setJointMotorControlArray(
            body, joints, p.POSITION_CONTROL, targetPositions=target, forces=forces, physicsClientId=cid
        )
        for _ in range(substeps):
            p.stepSimulation(physicsClientId=cid)
    return len(targets) / (time.perf_counter() - start)


def run(
    steps: int = 2000, tasks: Sequence[str] | None = None, rounds: int = 3, robot: str = "panda"
) -> list[dict]:
    """``[{"task", "env_steps_per_s", "bare_steps_per_s", "ratio"}, ...]`` for each task."""
    results = []
    for task in tasks or list(TASKS):
        env, bare = make(robot, task), make(robot, task)  # separate clients, same scene
        actions = (
            np.random.default_rng(0).uniform(-1, 1, (steps, env.action_space.shape[0])).astype(np.float32)
        )
        _, targets, starts = _env_rate(env, actions, record=True)
        bare.reset(seed=0)
        env_rate = bare_rate = 0.0
        for _ in range(rounds):
            bare_rate = max(bare_rate, _bare_rate(bare, targets, starts))
            env_rate = max(env_rate, _env_rate(env, actions)[0])
        env.close()
        bare.close()
        results.append(
            {
                "task": task,
                "env_steps_per_s": env_rate,
                "bare_steps_per_s": bare_rate,
                "ratio": env_rate / bare_rate,
            }
        )
    return results


def main(argv: Sequence[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench env", description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--steps", type=positive_int, default=2000)
    parser.add_argument("--rounds", type=positive_int, default=3)
    parser.add_argument("--tasks", nargs="*", default=None)
    args = parser.parse_args(argv)
    print(f"{'task':<15}{'env steps/s':>13}{'bare steps/s':>14}{'ratio':>8}")
    for r in run(args.steps, args.tasks, args.rounds):
        print(f"{r['task']:<15}{r['env_steps_per_s']:>13.0f}{r['bare_steps_per_s']:>14.0f}{r['ratio']:>8.2f}")


if __name__ == "__main__":
    main()
