"""Cost of one SAC gradient update per method: `sac_forward` + `sac_losses` + backward + Adam step.

The nets are the ones training builds (the task's real dims, hidden 256, interface 128, batch
256, one torch thread); the batch and the anchors are random, which changes values, not cost.
Methods take turns round by round, so a noisy machine slows them alike; the last column is each
row's median over rounds divided by the eager ablation's on the first device (the ablation is
added when not listed).
``--compile`` adds each method with its forward pass and losses compiled (``torch.compile``; the
backward pass follows through AOTAutograd), eager and compiled taking turns, and prints the
compilation time (docs/cost.md has the figures of this machine). ``--devices cpu cuda`` times
each method on each device (a CUDA update is timed to its end: the host waits for the GPU);
``--dims`` gives the widths instead of building the task's env, for a GPU host without PyBullet;
``--save DIR`` writes each row's nets, as its updates left them, as a policy file (written from
the GPU, read and stitched on a CPU host). ``--population K ...`` times instead K sources of the
first method updated as one (:mod:`ps_ray.nets.population`) beside K solo updates, per source;
with ``--graph`` also each population's whole update captured as one CUDA graph (a GPU only).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from ps_ray.cli.args import Parser, positive_int
from ps_ray.nets.sac import SACHyper, build_sac_nets, sac_forward, sac_losses
from ps_ray.specs.defaults import HIDDEN
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import method_spec, uses_anchors


class UpdateLoop:
    """One method's nets, optimiser and a fixed random batch."""

    def __init__(
        self,
        method: str,
        dims: NetDims,
        batch_size: int,
        interface_dim: int,
        seed: int = 0,
        compile: str = "",
        device: str = "cpu",
    ):
        rng = np.random.default_rng(seed)
        self.method, self.interface_dim = method, interface_dim
        anchors = rng.normal(size=(interface_dim, dims.task_dim)) if uses_anchors(method) else None
        self.nets = build_sac_nets(method, dims, interface_dim=interface_dim, anchors=anchors).to(device)
        self.device = torch.device(device)
        self.log_alpha = torch.zeros(1, device=device, requires_grad=True)
        trained = (self.nets.actor, self.nets.critic, self.nets.critic_twin)
        self.optimizer = torch.optim.Adam([p for n in trained for p in n.parameters()] + [self.log_alpha])
        widths = {"task_in": dims.task_dim, "robot_in": dims.robot_dim, "actions": dims.action_dim}
        widths |= {"next_task_in": dims.task_dim, "next_robot_in": dims.robot_dim}
        self.batch = {
            k: torch.as_tensor(rng.normal(size=(batch_size, w)), dtype=torch.float32, device=device)
            for k, w in widths.items()
        }
        self.rewards = -torch.ones(batch_size, device=device)
        self.action_dim = dims.action_dim
        self.loss = torch.compile(self._loss, mode=compile) if compile else self._loss

    def _loss(self) -> torch.Tensor:
        fwd = sac_forward(self.nets, self.batch)
        return sac_losses(fwd, self.rewards, self.log_alpha, SACHyper(), self.action_dim)["total"]

    def update(self) -> None:
        loss = self.loss()
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()

    def save(self, path: Path) -> Path:
        from ps_ray.nets.from_signature import signature_of
        from ps_ray.nets.policy_file import save_policy

        signature = signature_of(self.nets, self.method, self.interface_dim, HIDDEN)
        return save_policy(path, self.nets, signature, extra={"written_on": str(self.device)})

    def timed(self, updates: int) -> float:
        """Seconds per update over ``updates`` updates, the GPU's queued work included."""
        start = time.perf_counter()
        for _ in range(updates):
            self.update()
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        return (time.perf_counter() - start) / updates


class PopulationLoop:
    """``k`` members of one method updated as one population, each on a fixed random batch."""

    def __init__(
        self,
        method: str,
        dims: NetDims,
        k: int,
        batch_size: int,
        interface_dim: int,
        device: str,
        graph=False,
    ):
        from ps_ray.nets.population import Population

        solos = [UpdateLoop(method, dims, batch_size, interface_dim, seed=i, device=device) for i in range(k)]
        self.device = torch.device(device)
        self.population = Population([loop.nets for loop in solos], capturable=graph)
        self.batch = {key: torch.stack([loop.batch[key] for loop in solos]) for key in solos[0].batch}
        self.rewards = torch.stack([loop.rewards for loop in solos])
        if graph:
            self.step = self.population.captured(self.batch, self.rewards)
        else:
            self.step = lambda: self.population.update(self.batch, self.rewards)

    def timed(self, updates: int) -> float:
        start = time.perf_counter()
        for _ in range(updates):
            self.step()
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        return (time.perf_counter() - start) / updates


def population_table(
    method: str,
    dims: NetDims,
    sizes: list[int],
    *,
    device: str,
    batch_size: int,
    interface_dim: int,
    rounds: int,
    updates: int,
    graph: bool,
) -> None:
    """Per source: K solo updates one after another against one update of a population of K
    (eager, and with ``graph`` also captured as one CUDA graph)."""
    solo = UpdateLoop(method, dims, batch_size, interface_dim, device=device)
    loops = {
        (k, captured): PopulationLoop(method, dims, k, batch_size, interface_dim, device, captured)
        for k in sizes
        for captured in ((False, True) if graph else (False,))
    }
    for loop in (solo, *loops.values()):
        loop.timed(3)
    seconds = {"solo": [], **{key: [] for key in loops}}
    for _ in range(rounds):  # taking turns: a noisy machine slows them alike
        seconds["solo"].append(solo.timed(updates))
        for key, loop in loops.items():
            seconds[key].append(loop.timed(updates))
    base = float(np.median(seconds["solo"]))
    print(
        f"{method} on {device}, batch {batch_size}, interface {interface_dim}, 1 torch thread; "
        f"median over {rounds} rounds of {updates} updates"
    )
    print(f"{'sources':>8}{'ms/update (all)':>17}{'ms per source':>15}{'/ solo':>8}{'update':>8}")
    print(f"{'1 solo':>8}{1000 * base:>17.2f}{1000 * base:>15.2f}{1.0:>8.2f}{'eager':>8}")
    for k, captured in loops:
        ms = 1000 * float(np.median(seconds[(k, captured)]))
        kind = "graph" if captured else "eager"
        print(f"{k:>8}{ms:>17.2f}{ms / k:>15.2f}{ms / k / (1000 * base):>8.2f}{kind:>8}")


def task_dims(task: str) -> NetDims:
    """The widths of a task's nets on the Panda (``ps_ray.envs`` loads PyBullet)."""
    from ps_ray.envs.core import env_widths

    return NetDims(*env_widths("panda", task))


def parse_dims(text: str) -> NetDims:
    try:
        task_dim, robot_dim, action_dim = (positive_int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--dims takes TASK,ROBOT,ACTION widths, e.g. 15,8,7; got {text!r}"
        ) from None
    return NetDims(task_dim, robot_dim, action_dim)


def main(argv: list[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench update", description=__doc__)
    parser.add_argument("--task", default="reach")
    parser.add_argument("--methods", nargs="+", default=["ps", "ps_distilled", "ablation", "plain"])
    parser.add_argument("--updates", type=positive_int, default=30, help="updates per method per round")
    parser.add_argument("--rounds", type=positive_int, default=7)
    parser.add_argument("--batch-size", type=positive_int, default=256)
    parser.add_argument("--interface-dim", type=positive_int, default=128)
    parser.add_argument("--compile", action="store_true", help="also each method compiled (torch.compile)")
    parser.add_argument(
        "--compile-mode",
        default="default",
        choices=["default", "reduce-overhead", "max-autotune-no-cudagraphs"],
        help="torch.compile's mode (reduce-overhead: CUDA graphs on a GPU)",
    )
    parser.add_argument("--devices", nargs="+", default=["cpu"], choices=["cpu", "cuda"])
    parser.add_argument("--dims", type=parse_dims, default=None, help="TASK,ROBOT,ACTION widths (no env)")
    parser.add_argument("--save", type=Path, default=None, help="write each row's nets here (policy files)")
    parser.add_argument(
        "--population",
        type=positive_int,
        nargs="+",
        default=None,
        metavar="K",
        help="time populations of K sources of the first method updated as one, per source",
    )
    parser.add_argument(
        "--graph",
        action="store_true",
        help="with --population on --devices cuda: also each whole update captured as one CUDA graph",
    )
    args = parser.parse_args(argv)
    methods = list(dict.fromkeys(["ablation", *args.methods]))
    for method in methods:
        method_spec(method)  # an unknown name fails in one line before anything is built
    if "cuda" in args.devices and not torch.cuda.is_available():
        parser.error("--devices cuda: this torch finds no CUDA device")
    if args.graph and (not args.population or args.devices[0] != "cuda"):
        parser.error("--graph captures a population's update on a GPU: give --population K --devices cuda")
    torch.set_num_threads(1)
    dims = args.dims or task_dims(args.task)
    if args.population:
        return population_table(
            args.methods[0],
            dims,
            sorted(set(args.population)),
            device=args.devices[0],
            batch_size=args.batch_size,
            interface_dim=args.interface_dim,
            rounds=args.rounds,
            updates=args.updates,
            graph=args.graph,
        )
    loops: dict[str, UpdateLoop] = {}
    for device in args.devices:
        for m in methods:
            loops[f"{m} {device}"] = UpdateLoop(m, dims, args.batch_size, args.interface_dim, device=device)
        for m in methods if args.compile else ():
            name = f"{m} {device} compiled"
            loops[name] = UpdateLoop(
                m, dims, args.batch_size, args.interface_dim, compile=args.compile_mode, device=device
            )
            start = time.perf_counter()
            loops[name].timed(3)  # the first calls compile (reduce-overhead records its graphs later)
            print(f"{name}: compiled in {time.perf_counter() - start:.1f} s", flush=True)
    for loop in loops.values():
        loop.timed(3)  # warm-up: allocator, Adam state, CUDA kernels
    seconds: dict[str, list[float]] = {name: [] for name in loops}
    for _ in range(args.rounds):
        for name, loop in loops.items():
            seconds[name].append(loop.timed(args.updates))
    where = "given widths" if args.dims else f"task {args.task}"
    print(
        f"{where} (task {dims.task_dim}, robot {dims.robot_dim}, action {dims.action_dim}), "
        f"batch {args.batch_size}, interface {args.interface_dim}, 1 torch thread; "
        f"median over {args.rounds} rounds of {args.updates} updates"
    )
    if "cuda" in args.devices:
        print(f"cuda: {torch.cuda.get_device_name()}, torch {torch.__version__}")
    print(f"{'method':<34}{'ms/update':>10}{'min':>8}{'max':>8}{'/ ablation':>12}")
    base = float(np.median(seconds[f"ablation {args.devices[0]}"]))
    for name, values in seconds.items():
        ms, ratio = 1000 * np.asarray(values), np.median(values) / base
        print(f"{name:<34}{np.median(ms):>10.2f}{ms.min():>8.2f}{ms.max():>8.2f}{ratio:>12.2f}")
    for name, loop in loops.items() if args.save else ():
        print("wrote", loop.save(args.save / f"{name.replace(' ', '_')}.safetensors"))


if __name__ == "__main__":
    main()
