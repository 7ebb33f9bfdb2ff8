"""Cost of one co-trained grid update (:mod:`ps_ray.rllib.grid_module`) against bare torch and
against one source's update.

Three loops on the same kind of nets and replay batches (one minibatch of every trained cell per
grid update; one torch thread): the grid's RLlib learner (``GridSAC.learn``: its losses summed
over the cells, one backward, one step of each optimiser, Polyak of each shared target once), the
same update in bare torch (the cells' views of one set of shared modules, the same losses, Adam,
Polyak), and a single source's RLlib learner (``ModularSAC.learn``) on one cell's batch. Loops take
turns round by round, so a noisy machine slows them alike. Printed: ms per update, ms per cell
and the cost per cell divided by bare torch's.
"""

from __future__ import annotations

import time

import numpy as np
import torch
from torch import nn

from ps_ray.cli.args import Parser, positive_int
from ps_ray.nets.grid import add_grid_modules, grid_critic_pairs
from ps_ray.nets.sac import SACHyper, polyak_pairs, sac_forward, sac_losses
from ps_ray.specs.grid import GridSpec
from ps_ray.specs.train import TrainSpec


class BareGrid:
    """The grid update in plain torch: shared modules, the cells' summed losses, Adam, Polyak."""

    def __init__(self, grid: GridSpec, module, batch: dict[str, torch.Tensor]):
        self.owner = nn.Module()
        cells = [(grid.tasks.index(t), grid.robots.index(r)) for r, t in grid.cells]
        spec = grid.base
        self.views = add_grid_modules(
            self.owner,
            spec.method,
            module.dims,
            tasks=len(grid.tasks),
            robots=len(grid.robots),
            cells=cells,
            interface_dim=spec.interface_dim,
            hidden=spec.hidden,
            anchors=[None] * len(grid.tasks),
        )
        self.keys = module.keys
        self.log_alpha = torch.zeros(len(cells), requires_grad=True)
        trained = [p for name, p in self.owner.named_parameters() if not name.startswith("target")]
        self.optimizer = torch.optim.Adam([*trained, self.log_alpha])
        self.batch, self.action_dim, self.tau = batch, module.dims.action_dim, spec.tau

    def update(self, rows: slice) -> None:
        loss = 0.0
        for index, (key, view) in enumerate(zip(self.keys, self.views)):
            cell = {k[len(key) + 1 :]: v[rows] for k, v in self.batch.items() if k.startswith(key + "/")}
            fwd = sac_forward(view, cell)
            loss = (
                loss
                + sac_losses(fwd, cell["rewards"], self.log_alpha[index], SACHyper(), self.action_dim)[
                    "total"
                ]
            )
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        polyak_pairs(grid_critic_pairs(self.owner), self.tau)


def main(argv: list[str] | None = None) -> None:
    from ray.rllib.core import DEFAULT_MODULE_ID

    from ps_ray.rllib.algo import algo_config, grid_algo_config
    from ps_ray.rllib.ray_start import init_ray

    parser = Parser(prog="ps-ray bench grid", description=__doc__)
    parser.add_argument("--method", default="ablation")
    parser.add_argument("--robots", nargs="+", default=["panda", "panda_far"])
    parser.add_argument("--tasks", nargs="+", default=["reach_red", "reach_blue"])
    parser.add_argument("--held-out", nargs="*", default=["panda_far/reach_blue"])
    parser.add_argument("--hidden", type=positive_int, default=128)
    parser.add_argument("--updates", type=positive_int, default=20, help="updates per loop per round")
    parser.add_argument("--rounds", type=positive_int, default=5)
    args = parser.parse_args(argv)
    base = TrainSpec(
        method=args.method, hidden=args.hidden, learning_starts=10**9, random_episodes=2, eval_every=0
    )
    grid = GridSpec.of(base, args.robots, args.tasks, args.held_out)
    if grid.base.resolved.uses_anchors:
        parser.error("the benchmark builds no anchors: use a method without them (ablation, devin, plain)")
    torch.set_num_threads(1)
    init_ray(num_cpus=1)
    grid_algo = grid_algo_config(grid, [None] * len(grid.tasks)).build_algo()
    single = algo_config(grid.cell_spec(grid.cells[0])).build_algo()
    for algo in (grid_algo, single):
        for _ in range(3):  # replay to draw from (learning_starts is out of reach: no update yet)
            algo.train()
    n, size = args.updates, base.batch_size
    grid_batch, single_batch = grid_algo.sample_batch(n), single.sample_batch(n)
    module = grid_algo.learner_group.foreach_learner(lambda learner: learner.module[DEFAULT_MODULE_ID])
    bare = BareGrid(grid, module.result_or_errors[0].get(), grid_batch)
    loops = {
        "grid, RLlib learner": lambda: grid_algo.learn(grid_batch, n),
        "grid, bare torch": lambda: [bare.update(slice(i * size, (i + 1) * size)) for i in range(n)],
        "one source, RLlib learner": lambda: single.learn(single_batch, n),
    }
    seconds: dict[str, list[float]] = {name: [] for name in loops}
    for loop in loops.values():
        loop()  # warm-up
    for _ in range(args.rounds):
        for name, loop in loops.items():
            start = time.perf_counter()
            loop()
            seconds[name].append((time.perf_counter() - start) / n)
    cells = len(grid.cells)
    names = ", ".join(f"{r.text}/{t.text}" for r, t in grid.cells)
    print(
        f"grid {args.method}: {cells} trained cells ({names}), hidden {args.hidden}, batch {size} per "
        f"cell, 1 torch thread; median over {args.rounds} rounds of {n} updates"
    )
    print(f"{'loop':<28}{'ms/update':>10}{'ms/cell':>9}{'cell / bare':>13}")
    reference = 1000 * float(np.median(seconds["grid, bare torch"])) / cells
    for name, values in seconds.items():
        ms = 1000 * float(np.median(values))
        per_cell = ms / (cells if name.startswith("grid") else 1)
        print(f"{name:<28}{ms:>10.2f}{per_cell:>9.2f}{per_cell / reference:>13.2f}")
    grid_algo.stop()
    single.stop()


if __name__ == "__main__":
    main()
