"""Zero-shot evaluation speed: `evaluate` (num_envs 1 and 8) next to the env's own step rate.

The env rate is one env stepped with uniform random actions and reset (with a seed) every 50
steps, exactly the env work of an evaluation episode, measured in the same process and
interleaved with the evaluation rounds; each keeps its best round (robust to load from other
processes). ``ratio`` = evaluation env-steps/s over the env's steps/s (goal >= 0.8): what the
policy forward, batching and bookkeeping cost on top of the simulator. The policy is an untrained
net of the chosen method and size (speed does not depend on training); "eager" is the actor's own
forward (PS anchors re-embedded at every step, no TorchScript), for comparison.

    ps-ray bench evaluate [--task push] [--method ps] [--episodes 24] [--rounds 3]
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import torch

from ps_ray.cli.args import Parser, positive_int
from ps_ray.envs import make, task_input
from ps_ray.nets.obs import dims_from_spaces
from ps_ray.nets.sac import build_sac_nets
from ps_ray.specs.defaults import HIDDEN, INTERFACE_DIM
from ps_ray.specs.methods import uses_anchors
from ps_ray.stitching.evaluate import evaluate


def env_rate(robot: str, task: str, steps: int, seed: int = 0) -> float:
    """Steps/s of env.step with random actions, reset every episode (env construction excluded)."""
    env = make(robot, task)
    actions = np.random.default_rng(seed).uniform(-1, 1, (steps, env.action_space.shape[0]))
    start = time.perf_counter()
    for i, action in enumerate(actions.astype(np.float32)):
        if i % env.max_episode_steps == 0:
            env.reset(seed=seed + i)
        env.step(action)
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def policy_nets(robot: str, task: str, method: str, interface_dim: int, hidden: int):
    env = make(robot, task)
    dims = dims_from_spaces(env.observation_space, env.action_space)
    states = []
    for s in range(interface_dim):  # anchors: real task inputs from resets
        obs, _ = env.reset(seed=s)
        states.append(task_input(obs))
    env.close()
    torch.manual_seed(0)
    return build_sac_nets(
        method,
        dims,
        interface_dim=interface_dim,
        hidden=hidden,
        anchors=np.stack(states) if uses_anchors(method) else None,
    )


def run(
    robot: str = "panda",
    task: str = "push",
    method: str = "ps",
    episodes: int = 24,
    rounds: int = 3,
    num_envs: Sequence[int] = (1, 8),
    interface_dim: int = INTERFACE_DIM,
    hidden: int = HIDDEN,
) -> dict:
    nets = policy_nets(robot, task, method, interface_dim, hidden)
    variants = [(n, True) for n in num_envs] + [(1, False)]
    best = {v: 0.0 for v in variants}
    env_best = 0.0
    steps = episodes * 50
    for _ in range(rounds):
        env_best = max(env_best, env_rate(robot, task, steps))
        for n, fast in variants:
            result = evaluate(nets, robot, task, episodes=episodes, repeats=1, num_envs=n, fast=fast)
            best[(n, fast)] = max(best[(n, fast)], result["env_steps_per_s"])
    return {"env_steps_per_s": env_best, "eval": best}


def main(argv: Sequence[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench evaluate", description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--robot", default="panda")
    parser.add_argument("--task", default="push")
    parser.add_argument("--method", default="ps")
    parser.add_argument("--episodes", type=positive_int, default=24)
    parser.add_argument("--rounds", type=positive_int, default=3)
    parser.add_argument("--hidden", type=positive_int, default=256)
    parser.add_argument("--interface-dim", type=positive_int, default=128)
    args = parser.parse_args(argv)
    out = run(
        args.robot,
        args.task,
        args.method,
        args.episodes,
        args.rounds,
        interface_dim=args.interface_dim,
        hidden=args.hidden,
    )
    env = out["env_steps_per_s"]
    print(
        f"{args.method} on {args.task}/{args.robot}, hidden {args.hidden}, interface "
        f"{args.interface_dim}; {args.episodes} episodes x 50 steps, best of {args.rounds} rounds; "
        f"torch threads during evaluation: 1 (of {torch.get_num_threads()})"
    )
    print(f"{'':<28}{'env steps/s':>12}{'episodes/s':>12}{'ratio':>8}")
    print(f"{'env.step, random actions':<28}{env:>12.0f}{env / 50:>12.1f}{1.0:>8.2f}")
    for (n, fast), rate in out["eval"].items():
        name = f"evaluate num_envs={n}" + ("" if fast else " eager")
        print(f"{name:<28}{rate:>12.0f}{rate / 50:>12.1f}{rate / env:>8.2f}")


if __name__ == "__main__":
    main()
