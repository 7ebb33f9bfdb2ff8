"""Learning benchmark: env steps to a greedy success target per method, over seeds.

Each (method, seed) is a real `ps-ray train` run (its own run directory, resumable) that stops
once the target is met in two evaluations in a row, or at the budget cap. The table reads their
metrics.csv files, so an interrupted benchmark re-run only finishes what is missing.
Steps to target is the first evaluation at or above it; a run that never gets there counts as
the cap (a lower bound, marked with '>').
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

from ps_ray.cli_parsers import Parser, positive_int
from ps_ray.config import TrainSpec
from ps_ray.train import train


def steps_to(curve: pd.DataFrame, target: float) -> int | None:
    reached = curve[curve["eval_success"] >= target]["env_steps"]
    return int(reached.iloc[0]) if len(reached) else None


def run_one(args: argparse.Namespace, method: str, seed: int) -> dict:
    spec = TrainSpec(
        robot=args.robot,
        task=args.task,
        method=method,
        seed=seed,
        env_steps=args.env_steps,
        interface_dim=args.interface_dim,
        eval_episodes=args.eval_episodes,
        target_success=args.target,
    )
    run_dir = Path(args.out) / spec.slug()
    result_file = run_dir / "result.json"
    result = (
        json.loads(result_file.read_text()) if result_file.exists() else train(spec, run_dir, progress=False)
    )
    curve = pd.read_csv(run_dir / "metrics.csv").dropna(subset=["eval_success"])
    reached = steps_to(curve, args.target)
    print(
        f"  {method:<14} seed {seed}: steps to {args.target:.2f} "
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
    parser.add_argument("--methods", nargs="+", default=["ps", "ps_ref_actor", "ablation", "plain"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[101, 102, 103])
    parser.add_argument("--env-steps", type=positive_int, default=20_000, help="budget cap per run")
    parser.add_argument("--target", type=float, default=0.9, help="greedy success target")
    parser.add_argument("--eval-episodes", type=positive_int, default=20)
    parser.add_argument("--interface-dim", type=positive_int, default=128)
    parser.add_argument("--out", default="runs/bench_learn")
    args = parser.parse_args(argv)
    for name in ("env_steps", "eval_episodes", "interface_dim"):
        if getattr(args, name) <= 0:
            parser.error(f"--{name.replace('_', '-')} must be positive, got {getattr(args, name)}")
    rows = [run_one(args, m, s) for m in args.methods for s in args.seeds]
    df = pd.DataFrame(rows)
    print(
        f"\n{args.robot} {args.task}, interface {args.interface_dim}: env steps to greedy success "
        f"{args.target} ({args.eval_episodes} fixed episodes per evaluation, every 1,000 steps), "
        f"cap {args.env_steps}; mean over seeds {args.seeds} (a run that never reached the "
        f"target counts as the cap)"
    )
    print(
        f"{'method':<14}{'mean steps':>11}{'min':>7}{'max':>7}{'reached':>9}{'best eval':>10}"
        f"{'final':>7}{'wall s':>8}"
    )
    for method, g in df.groupby("method", sort=False):
        steps = g["steps"].fillna(args.env_steps).to_numpy(float)
        censored = g["steps"].isna().any()
        print(
            f"{method:<14}{('>' if censored else '') + f'{steps.mean():.0f}':>11}"
            f"{steps.min():>7.0f}{steps.max():>7.0f}{g['steps'].notna().sum():>6}/{len(g):<2}"
            f"{g['best'].mean():>10.2f}{g['final'].mean():>7.2f}{np.mean(g['wall_s']):>8.0f}"
        )


if __name__ == "__main__":
    main()
