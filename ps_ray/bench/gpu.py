"""What a GPU host checks in one call (``ps-ray bench gpu``; ``python -m ps_ray.bench.gpu`` from the
repository where only torch is installed): that a population's update there gives each member what
a solo learner gives it, eager and captured as one CUDA graph (same start, batches and noise; the
graph against solo learners with its capturable Adam; the largest gap as a fraction of how far the
updates moved each tensor, after the first replay and after the last update), beside two
yardsticks (how far one float32 rounding reaches, what the capturable Adam alone changes), and
that the RLlib population learner's batched pass gives each member its solo gradients; then the
population's cost per source against K, eager and graph (``ps-ray bench update --population``'s
table). On a CPU the graph is left out, said so. Exit 1 when a checked gap is over
``--tolerance``."""

from __future__ import annotations

import copy
import sys

import numpy as np
import torch
from torch import Tensor

from ps_ray.bench.update import parse_dims, population_table
from ps_ray.cli.args import Parser, positive_int
from ps_ray.nets.population import Population, members_forward, members_losses
from ps_ray.nets.sac import SACHyper, SACNets, build_sac_nets, sac_forward, sac_losses
from ps_ray.nets.solo import SoloLearner
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import method_spec, uses_anchors

Inputs = tuple[dict[str, Tensor], Tensor, tuple[Tensor, Tensor]]


def members(method: str, dims: NetDims, k: int, interface_dim: int, device: str) -> list[SACNets]:
    """K members of the training widths, each with normaliser statistics of its own."""
    built = []
    for seed in range(k):
        torch.manual_seed(seed)
        rng = np.random.default_rng(seed)
        anchors = rng.normal(size=(interface_dim, dims.task_dim)) if uses_anchors(method) else None
        nets = build_sac_nets(method, dims, interface_dim=interface_dim, anchors=anchors)
        for module in nets.modules():
            if hasattr(module, "update"):
                module.update(torch.randn(64, module.mean.shape[0]) * (1 + seed))
        built.append(nets.to(device))
    return built


def inputs(dims: NetDims, k: int, batch_size: int, step: int, device: str) -> Inputs:
    """Update ``step``'s batch, rewards and noise for every member, ``[K, B, ...]``."""
    g = torch.Generator().manual_seed(1000 + step)
    widths = {"task_in": dims.task_dim, "robot_in": dims.robot_dim, "actions": dims.action_dim}
    widths |= {"next_task_in": dims.task_dim, "next_robot_in": dims.robot_dim}
    batch = {key: torch.randn(k, batch_size, w, generator=g).to(device) for key, w in widths.items()}
    rewards = -(torch.rand(k, batch_size, generator=g) < 0.7).float().to(device)
    noise = tuple(torch.randn(k, batch_size, dims.action_dim, generator=g).to(device) for _ in range(2))
    return batch, rewards, noise


def refill(into: Inputs, values: Inputs) -> None:
    """Copy ``values`` into the captured graph's input tensors, in place."""
    for key, tensor in into[0].items():
        tensor.copy_(values[0][key])
    into[1].copy_(values[1])
    for tensor, value in zip(into[2], values[2], strict=True):
        tensor.copy_(value)


def nudged(nets: SACNets, seed: int) -> SACNets:
    """A copy whose trained weights are each moved by about one float32 rounding (a relative
    1e-7); the targets are left as they are."""
    copied, g = copy.deepcopy(nets), torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in copied.named_parameters():
            if not name.startswith("target"):
                p.mul_(1 + 1e-7 * torch.randn(p.shape, generator=g).to(p.device))
    return copied


def member_states(learner: Population | list[SoloLearner], like: list[SACNets]) -> list[list[Tensor]]:
    """Each member's tensors (weights, targets, statistics, temperature), of a population or of
    solo learners."""
    if isinstance(learner, Population):
        exported = [learner.export(i, copy.deepcopy(nets)) for i, nets in enumerate(like)]
        return [[*nets.state_dict().values(), log_alpha.reshape(1)] for nets, log_alpha in exported]
    return [[*solo.nets.state_dict().values(), solo.log_alpha.detach()] for solo in learner]


def largest_gap(got: list[list[Tensor]], want: list[list[Tensor]], start: list[SACNets]) -> float:
    """Over members and tensors: the distance from the reference's tensor as a fraction of how far
    the updates moved it (Euclidean norms). Adam turns a rounding in a gradient near zero into a
    different step of that element, so the largest element gap is no measure; a member fed
    another's gradient is about 1."""
    gap = 0.0
    for got_i, want_i, nets in zip(got, want, start, strict=True):
        was = [*nets.state_dict().values(), torch.zeros(1, device=want_i[-1].device)]
        for g, w, s in zip(got_i, want_i, was, strict=True):
            moved = float((w - s).norm()) + 1e-6 * float(w.norm()) + 1e-12
            gap = max(gap, float((g - w).norm()) / moved)
    return gap


def equality_rows(
    method: str, dims: NetDims, k: int, updates: int, batch_size: int, interface_dim: int, device: str
):
    """(what, when, largest gap, checked) of the eager population against K solo learners from
    the same start on the same inputs and, on a GPU, of the captured one against K solo learners
    with the same capturable Adam. Beside them, not checked: how far one rounding reaches (solo
    learners whose start is nudged by 1e-7 against the others: SAC's updates amplify it, so a gap
    at or under this one is rounding) and what PyTorch's capturable Adam alone changes."""
    start = members(method, dims, k, interface_dim, device)
    solos = [SoloLearner(copy.deepcopy(nets)) for nets in start]
    learners = {"solo": solos, "eager population": Population([copy.deepcopy(n) for n in start])}
    learners["nudged solo"] = [SoloLearner(nudged(n, seed)) for seed, n in enumerate(start)]
    compared = [  # (learner, its reference, label, checked)
        ("eager population", "solo", "eager population vs solo learners", True),
        ("nudged solo", "solo", "one rounding's reach (nudged solo vs solo)", False),
    ]
    replay, graph_inputs = None, None
    if device == "cuda":
        learners["capturable solo"] = [SoloLearner(copy.deepcopy(n), capturable=True) for n in start]
        learners["captured"] = graph = Population([copy.deepcopy(n) for n in start], capturable=True)
        compared += [
            ("captured", "capturable solo", "one CUDA graph vs capturable solo learners", True),
            ("capturable solo", "solo", "capturable Adam alone (solo vs solo)", False),
        ]
        graph_inputs = inputs(dims, k, batch_size, 0, device)  # update 0 is the capture's warm-up
        replay = graph.captured(graph_inputs[0], graph_inputs[1], graph_inputs[2], warmups=1)
    rows = []
    for step in range(updates):
        batch, rewards, noise = inputs(dims, k, batch_size, step, device)
        for name, learner in learners.items():
            if isinstance(learner, list):
                for i, solo in enumerate(learner):
                    own = {key: v[i] for key, v in batch.items()}
                    solo.update(own, rewards[i], (noise[0][i], noise[1][i]))
            elif name != "captured":
                learner.update(batch, rewards, noise)
        if replay is not None and step > 0:
            refill(graph_inputs, (batch, rewards, noise))
            replay()
        if step in (1, updates - 1):
            states = {name: member_states(learner, start) for name, learner in learners.items()}
            for got, want, label, checked in compared:
                gap = largest_gap(states[got], states[want], start)
                rows.append((label, f"after {step + 1} updates", gap, checked))
    return rows


def batched_pass_gap(method: str, dims: NetDims, k: int, batch_size: int, interface_dim: int, device: str):
    """The RLlib population learner's pass (:func:`~ps_ray.nets.population.members_forward` and
    ``members_losses``, each member keeping its own parameters): the largest distance of a
    member's gradient from its solo pass's, as a fraction of the solo gradient's norm."""
    batched = members(method, dims, k, interface_dim, device)
    alone = [copy.deepcopy(nets) for nets in batched]
    batch, rewards, noise = inputs(dims, k, batch_size, 0, device)
    hp, log_alpha = SACHyper(), torch.zeros(k, device=device, requires_grad=True)
    fwd = members_forward(batched, batch, noise)
    members_losses(fwd, rewards, log_alpha, hp, dims.action_dim)["total"].sum().backward()
    gap = 0.0
    for i, nets in enumerate(alone):
        own = sac_forward(nets, {key: v[i] for key, v in batch.items()}, (noise[0][i], noise[1][i]))
        own_alpha = torch.zeros((), device=device, requires_grad=True)
        sac_losses(own, rewards[i], own_alpha, hp, dims.action_dim)["total"].backward()
        for got, want in zip(batched[i].parameters(), nets.parameters(), strict=True):
            if want.grad is not None:
                gap = max(gap, float((got.grad - want.grad).norm() / want.grad.norm().clamp_min(1e-12)))
    return gap


def main(argv: list[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench gpu", description=__doc__)
    default_device = "cuda" if torch.cuda.is_available() else "cpu"
    parser.add_argument("--device", default=default_device, choices=["cpu", "cuda"])
    parser.add_argument("--method", default="ablation")
    parser.add_argument("--dims", type=parse_dims, default=NetDims(15, 8, 7), help="TASK,ROBOT,ACTION (push)")
    parser.add_argument("--members", type=positive_int, default=4, help="members in the equality check")
    parser.add_argument("--check-updates", type=positive_int, default=10)
    parser.add_argument("--tolerance", type=float, default=1e-2, help="largest gap allowed (a fraction)")
    parser.add_argument("--population", type=positive_int, nargs="+", default=None, metavar="K")
    parser.add_argument("--batch-size", type=positive_int, default=256)
    parser.add_argument("--interface-dim", type=positive_int, default=128)
    parser.add_argument("--rounds", type=positive_int, default=5)
    parser.add_argument("--updates", type=positive_int, default=20, help="updates per row per round")
    args = parser.parse_args(argv)
    method_spec(args.method)  # an unknown name fails in one line before anything is built
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: this torch finds no CUDA device")
    if args.check_updates < 2:
        parser.error(
            f"--check-updates {args.check_updates}: at least 2 (the graph's first replay is the 2nd)"
        )
    torch.set_num_threads(1)
    torch.backends.cuda.matmul.allow_tf32 = False  # float32 products, as on a CPU (the default)
    gpu = args.device == "cuda"
    where = f"cuda: {torch.cuda.get_device_name()}" if gpu else "cpu (no CUDA graph here)"
    print(f"{where}, torch {torch.__version__}, float32 products (tf32 off)", flush=True)
    dims = args.dims
    shape = (args.method, dims, args.members)
    rows = equality_rows(*shape, args.check_updates, args.batch_size, args.interface_dim, args.device)
    gradients = batched_pass_gap(*shape, args.batch_size, args.interface_dim, args.device)
    rows.append(("batched pass (the RLlib population learner)", "gradients", gradients, True))
    widths = f"{dims.task_dim},{dims.robot_dim},{dims.action_dim}"
    print(f"{args.members} {args.method} members, widths {widths}, against solo learners:")
    failed = [row for row in rows if row[3] and not row[2] <= args.tolerance]
    for name, when, gap, checked in rows:
        verdict = "ok" if gap <= args.tolerance else f"OVER {args.tolerance:g}"
        verdict = verdict if checked else "(yardstick)"
        print(f"  {name:<44} {when:<17} largest gap {gap:.2e}  {verdict}", flush=True)
    sizes = args.population or ([1, 8, 64, 256, 1024] if gpu else [1, 2, 4, 8])
    population_table(
        args.method,
        dims,
        sorted(set(sizes)),
        device=args.device,
        batch_size=args.batch_size,
        interface_dim=args.interface_dim,
        rounds=args.rounds,
        updates=args.updates,
        graph=gpu,
    )
    if failed:
        sys.exit(f"{len(failed)} equality check(s) over the tolerance {args.tolerance:g}")


if __name__ == "__main__":
    main()
