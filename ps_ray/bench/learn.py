"""Learning benchmark: train each method on one robot-task pair and print greedy success/touching.

Each method is a real `ps-ray train` run (its own run directory, resumable); the table at the end
reads their result.json files, so an interrupted benchmark re-run only finishes what is missing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

from ps_ray.config import TrainSpec
from ps_ray.train import train


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="ps-ray bench learn", description=__doc__)
    parser.add_argument("--robot", default="panda")
    parser.add_argument("--task", default="reach")
    parser.add_argument("--methods", nargs="+", default=["ps", "ablation", "plain"])
    parser.add_argument("--env-steps", type=int, default=20_000)
    parser.add_argument("--interface-dim", type=int, default=128)
    parser.add_argument("--seed", type=int, default=101)
    parser.add_argument("--out", default="runs/bench_learn")
    args = parser.parse_args(argv)
    rows = []
    for method in args.methods:
        spec = TrainSpec(robot=args.robot, task=args.task, method=method, seed=args.seed,
                         env_steps=args.env_steps, interface_dim=args.interface_dim,
                         eval_episodes=20)
        run_dir = Path(args.out) / spec.slug()
        result_file = run_dir / "result.json"
        result = json.loads(result_file.read_text()) if result_file.exists() else train(spec, run_dir)
        curve = pd.read_csv(run_dir / "metrics.csv").dropna(subset=["eval_success"])
        reached = curve[curve["eval_success"] >= 0.9]["env_steps"]
        result["best_eval_success"] = curve["eval_success"].max()
        result["steps_to_90"] = int(reached.iloc[0]) if len(reached) else None
        rows.append((method, result))
    print(f"\n{args.robot} {args.task}, {args.env_steps} env steps; best periodic greedy evaluation "
          f"(20 fixed episodes) and final greedy evaluation (40 episodes)")
    print(f"{'method':<12}{'best eval':>10}{'steps to 0.9':>13}{'final':>7}{'touching':>10}"
          f"{'updates':>9}{'wall s':>8}")
    for method, r in rows:
        touching = r.get("final_touching")
        print(f"{method:<12}{r['best_eval_success']:>10.2f}{str(r['steps_to_90']):>13}"
              f"{r['final_success']:>7.2f}"
              f"{'n/a' if touching is None or touching != touching else f'{touching:.2f}':>10}"
              f"{r.get('updates', 0):>9}{r.get('wall_s', 0):>8.0f}")


if __name__ == "__main__":
    main()
