"""Cost of one SAC gradient update per method: `sac_forward` + `sac_losses` + backward + Adam step.

The nets are the ones training builds (the task's real dims, hidden 256, interface 128, batch
256, one torch thread); the batch and the anchors are random, which changes values, not cost.
Methods take turns round by round, so a noisy machine slows them alike; the last column is each
method's median over rounds divided by the ablation's (the ablation is added when not listed).
``--compile`` adds each method with its forward pass and losses compiled (``torch.compile``; the
backward pass follows through AOTAutograd), eager and compiled taking turns, and prints the
compilation time (docs/cost.md has the figures of this machine).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from ps_ray.cli.parsers import Parser, positive_int
from ps_ray.nets.obs import dims_from_spaces
from ps_ray.nets.sac import SACHyper, build_sac_nets, sac_forward, sac_losses
from ps_ray.rllib.loop import make_env
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import method_spec, uses_anchors
from ps_ray.specs.train import TrainSpec


class UpdateLoop:
    """One method's nets, optimiser and a fixed random batch."""

    def __init__(
        self,
        method: str,
        dims: NetDims,
        batch_size: int,
        interface_dim: int,
        seed: int = 0,
        compile: bool = False,
    ):
        rng = np.random.default_rng(seed)
        anchors = rng.normal(size=(interface_dim, dims.task_dim)) if uses_anchors(method) else None
        self.nets = build_sac_nets(method, dims, interface_dim=interface_dim, anchors=anchors)
        self.log_alpha = torch.zeros(1, requires_grad=True)
        trained = (self.nets.actor, self.nets.critic, self.nets.critic_twin)
        self.optimizer = torch.optim.Adam([p for n in trained for p in n.parameters()] + [self.log_alpha])
        widths = {"task_in": dims.task_dim, "robot_in": dims.robot_dim, "actions": dims.action_dim}
        widths |= {"next_task_in": dims.task_dim, "next_robot_in": dims.robot_dim}
        self.batch = {
            k: torch.as_tensor(rng.normal(size=(batch_size, w)), dtype=torch.float32)
            for k, w in widths.items()
        }
        self.rewards = -torch.ones(batch_size)
        self.action_dim = dims.action_dim
        self.loss = torch.compile(self._loss) if compile else self._loss

    def _loss(self) -> torch.Tensor:
        fwd = sac_forward(self.nets, self.batch)
        return sac_losses(fwd, self.rewards, self.log_alpha, SACHyper(), self.action_dim)["total"]

    def update(self) -> None:
        loss = self.loss()
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()


def main(argv: list[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench update", description=__doc__)
    parser.add_argument("--task", default="reach")
    parser.add_argument("--methods", nargs="+", default=["ps", "ps_distilled", "ablation", "plain"])
    parser.add_argument("--updates", type=positive_int, default=30, help="updates per method per round")
    parser.add_argument("--rounds", type=positive_int, default=7)
    parser.add_argument("--batch-size", type=positive_int, default=256)
    parser.add_argument("--interface-dim", type=positive_int, default=128)
    parser.add_argument("--compile", action="store_true", help="also each method compiled (torch.compile)")
    args = parser.parse_args(argv)
    methods = list(dict.fromkeys(["ablation", *args.methods]))
    for method in methods:
        method_spec(method)  # an unknown name fails in one line before anything is built
    torch.set_num_threads(1)
    env = make_env(TrainSpec(task=args.task))
    dims = dims_from_spaces(env.observation_space, env.action_space)
    env.close()
    loops = {m: UpdateLoop(m, dims, args.batch_size, args.interface_dim) for m in methods}
    compiled = {}
    for m in methods if args.compile else ():
        compiled[f"{m} compiled"] = UpdateLoop(m, dims, args.batch_size, args.interface_dim, compile=True)
        start = time.perf_counter()
        compiled[f"{m} compiled"].update()  # the first call compiles
        print(f"{m}: compiled in {time.perf_counter() - start:.1f} s", flush=True)
    loops |= compiled
    for loop in loops.values():
        loop.update()  # warm-up: allocator, Adam state
    seconds: dict[str, list[float]] = {m: [] for m in loops}
    for _ in range(args.rounds):
        for method, loop in loops.items():
            start = time.perf_counter()
            for _ in range(args.updates):
                loop.update()
            seconds[method].append((time.perf_counter() - start) / args.updates)
    print(
        f"task {args.task} (task {dims.task_dim}, robot {dims.robot_dim}, action {dims.action_dim}), "
        f"batch {args.batch_size}, interface {args.interface_dim}, 1 torch thread; "
        f"median over {args.rounds} rounds of {args.updates} updates"
    )
    print(f"{'method':<22}{'ms/update':>10}{'min':>8}{'max':>8}{'/ ablation':>12}")
    base = float(np.median(seconds["ablation"]))
    for method, values in seconds.items():
        ms, ratio = 1000 * np.asarray(values), np.median(values) / base
        print(f"{method:<22}{np.median(ms):>10.2f}{ms.min():>8.2f}{ms.max():>8.2f}{ratio:>12.2f}")


if __name__ == "__main__":
    main()
