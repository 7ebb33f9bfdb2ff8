"""Learning benchmark: env steps to a greedy success target per method, over seeds.

Each (method, seed) is a real `ps-ray train` run (its own run directory, resumable) that stops
once the target is met in two evaluations in a row, or at the budget cap. The table reads their
metrics.csv files, so an interrupted benchmark re-run only finishes what is missing.
Steps to target is the first evaluation at or above it; a run that never gets there counts as
the cap (a lower bound, marked with '>'). ``final`` is the greedy success of the policy the run
leaves (after consolidation, for methods that consolidate), and ``final ok`` counts the runs where
it is at or above the target: a consolidated policy must keep what training reached. Means
carry 95% CIs over seeds, and each method's mean is divided by the baseline's (the ablation by
default) on the same seeds, with a paired bootstrap CI (ps_ray/analysis/stats.py). Runs are
deterministic per seed: a re-run repeats its figures.
"""

from __future__ import annotations

import argparse
import functools
import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from ps_ray.analysis.stats import estimate, ratio_of_means
from ps_ray.cli.args import Parser, positive_int
from ps_ray.rllib.train import train
from ps_ray.specs.train import TrainSpec


def steps_to(curve: pd.DataFrame, target: float) -> int | None:
    reached = curve[curve["eval_success"] >= target]["env_steps"]
    return int(reached.iloc[0]) if len(reached) else None


def train_spec(args: argparse.Namespace, method: str, seed: int) -> TrainSpec:
    return TrainSpec(
        robot=args.robot,
        task=args.task,
        method=method,
        seed=seed,
        env_steps=args.env_steps,
        interface_dim=args.interface_dim,
        eval_episodes=args.eval_episodes,
        target_success=args.target,
    )


def train_in_fresh_process(spec: TrainSpec, run_dir: Path) -> dict:
    """``train`` in a spawned process of its own, as ``ps-ray train`` and every Tune trial run, so
    that no process-wide state set by an earlier run (thread pools, Ray's settings) reaches it.
    Such state once made a seed's run depend on the runs before it: k-means followed the OpenMP
    thread count that an earlier run had left (fixed in :mod:`ps_ray.data.anchors`)."""
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(functools.partial(train, spec, run_dir, progress=False)).result()


def run_one(args: argparse.Namespace, spec: TrainSpec) -> dict:
    method, seed = spec.method, spec.seed
    run_dir = Path(args.out) / spec.slug()
    result_file = run_dir / "result.json"
    result = (
        json.loads(result_file.read_text()) if result_file.exists() else train_in_fresh_process(spec, run_dir)
    )
    curve = pd.read_csv(run_dir / "metrics.csv").dropna(subset=["eval_success"])
    reached = steps_to(curve, args.target)
    print(
        f"  {method:<16} seed {seed}: steps to {args.target:.2f} "
        f"{reached if reached is not None else '> ' + str(args.env_steps)}, "
        f"best eval {curve['eval_success'].max():.2f}, wall {result.get('wall_s', 0):.0f} s",
        flush=True,
    )
    return {
        "method": method,
        "seed": seed,
        "steps": reached,
        "best": curve["eval_success"].max(),
        "final": result["final_success"],
        "wall_s": result.get("wall_s", 0.0),
    }


def main(argv: list[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench learn", description=__doc__)
    parser.add_argument("--robot", default="panda")
    parser.add_argument("--task", default="reach")
    parser.add_argument("--methods", nargs="+", default=["ps", "ps_distilled", "ablation", "plain"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[101, 102, 103])
    parser.add_argument("--env-steps", type=positive_int, default=20_000, help="budget cap per run")
    parser.add_argument("--target", type=float, default=0.9, help="greedy success target")
    parser.add_argument("--eval-episodes", type=positive_int, default=20)
    parser.add_argument("--interface-dim", type=positive_int, default=128)
    parser.add_argument("--baseline", default="ablation", help="method the others are divided by")
    parser.add_argument("--out", default="runs/bench_learn")
    args = parser.parse_args(argv)
    for name in ("env_steps", "eval_episodes", "interface_dim"):
        if getattr(args, name) <= 0:
            parser.error(f"--{name.replace('_', '-')} must be positive, got {getattr(args, name)}")
    if args.baseline not in args.methods:
        parser.error(f"--baseline {args.baseline!r} is not among --methods {args.methods}")
    specs = [train_spec(args, m, s) for m in args.methods for s in args.seeds]  # bad input: before any run
    rows = [run_one(args, spec) for spec in specs]
    df = pd.DataFrame(rows)
    print(
        f"\n{args.robot} {args.task}, interface {args.interface_dim}: env steps to greedy success "
        f"{args.target} ({args.eval_episodes} fixed episodes per evaluation, every 1,000 steps), "
        f"cap {args.env_steps}; mean over seeds {args.seeds} (a run that never reached the "
        f"target counts as the cap)"
    )
    ratio_label = f"x {args.baseline} [95% CI]"
    name_w, ratio_w = max(14, *(len(m) + 1 for m in args.methods)), max(24, len(ratio_label) + 2)
    print(
        f"{'method':<{name_w}}{'mean steps [95% CI]':>24}{ratio_label:>{ratio_w}}"
        f"{'min':>7}{'max':>7}{'reached':>9}{'best eval':>10}{'final':>7}{'final ok':>10}{'wall s':>8}"
    )
    steps_of = {
        m: g.set_index("seed")["steps"].fillna(args.env_steps) for m, g in df.groupby("method", sort=False)
    }
    for method, g in df.groupby("method", sort=False):
        steps = steps_of[method]
        mean = estimate(steps.to_numpy(), steps.index.to_numpy())
        ratio = ratio_of_means(steps.to_numpy(), steps_of[args.baseline].loc[steps.index].to_numpy())
        censored = ">" if g["steps"].isna().any() else ""
        print(
            f"{method:<{name_w}}{censored + _ci(mean.mean, mean.mean_lo, mean.mean_hi, '.0f'):>24}"
            f"{censored + _ci(*ratio, '.2f'):>{ratio_w}}{steps.min():>7.0f}{steps.max():>7.0f}"
            f"{g['steps'].notna().sum():>6}/{len(g):<2}{g['best'].mean():>10.2f}{g['final'].mean():>7.2f}"
            f"{(g['final'] >= args.target).sum():>7}/{len(g):<2}{np.mean(g['wall_s']):>8.0f}"
        )


def _ci(point: float, lo: float, hi: float, fmt: str) -> str:
    interval = "n/a" if np.isnan(lo) else f"{lo:{fmt}}, {hi:{fmt}}"
    return f"{point:{fmt}} [{interval}]"


if __name__ == "__main__":
    main()
