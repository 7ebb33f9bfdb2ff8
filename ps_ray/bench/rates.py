"""Per-core rates for the cost projection (`ps-ray sweep FILE --check`), measured and cached.

Four short real training runs on reach (ablation and ps, hidden 64 and 256, batch 256) separate
the costs: rows before ``learning_starts`` give seconds per collected env step, rows after give
seconds per gradient update; the time outside the training loop (Ray, envs, RLlib build, anchors)
is not the whole fixed cost of a trial, because a Tune trial is a fresh worker process that imports
torch, Ray and RLlib first: the fixed cost is the wall time of a whole `ps-ray train` process with
one training step. Two hidden sizes fit ``fixed + per_unit * batch * hidden**2``; ps
over ablation gives the relative methods' factor. A greedy evaluation of the last policy gives
seconds per evaluation step. The rates go to ``ps_ray.analysis.cost.rates_path()``.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from ps_ray.analysis.cost import rates_path
from ps_ray.analysis.hardware import DEFAULT_RATES, Rates
from ps_ray.cli.args import Parser, positive_int
from ps_ray.envs import EPISODE_STEPS
from ps_ray.specs.train import TrainSpec
from ps_ray.store.atomic import write_text


def _slope(x: pd.Series, y: pd.Series) -> float:
    return float(np.polyfit(x.to_numpy(float), y.to_numpy(float), 1)[0])


def measure_run(method: str, hidden: int, env_steps: int, learning_starts: int, root: Path) -> dict:
    """One real training run; seconds per env step, per update, and outside the loop."""
    from ps_ray.rllib.train import train

    spec = TrainSpec(
        task="reach",
        method=method,
        hidden=hidden,
        env_steps=env_steps,
        learning_starts=learning_starts,
        random_episodes=learning_starts // EPISODE_STEPS,
        eval_every=10_000,
        checkpoint_every=10_000,
    )
    start = time.perf_counter()
    train(spec, root / f"{method}-{hidden}", progress=False)
    total = time.perf_counter() - start
    rows = pd.read_csv(root / f"{method}-{hidden}" / "metrics.csv")
    warmup, learning = rows[rows.updates == 0].iloc[1:], rows[rows.updates > 0].iloc[1:]
    env_step_s = _slope(warmup.env_steps, warmup.wall_s)
    per_update = _slope(learning.updates, learning.wall_s - env_step_s * learning.env_steps)
    return {
        "method": method,
        "hidden": hidden,
        "env_step_s": env_step_s,
        "update_s": per_update,
        "outside_s": total - float(rows.wall_s.iloc[-1]),
        "policy": root / f"{method}-{hidden}" / "policy.safetensors",
    }


def process_start_s(root: Path) -> float:
    """Wall seconds of a fresh `ps-ray train` process that trains one step: what a Tune trial
    pays before its first env step (imports, envs, RLlib build) and after its last."""
    command = [sys.executable, "-m", "ps_ray.cli", "train", "--task", "reach", "--method", "ablation"]
    command += ["--env-steps", "100", "--learning-starts", "100", "--random-episodes", "2", "--quiet"]
    start = time.perf_counter()
    subprocess.run([*command, "--run-dir", str(root / "start")], check=True, capture_output=True)
    return time.perf_counter() - start


def measure(env_steps: int, learning_starts: int, root: Path) -> tuple[Rates, list[dict]]:
    from ps_ray.stitching.evaluate import evaluate

    grid = [(method, hidden) for method in ("ablation", "ps") for hidden in (64, 256)]
    runs = [measure_run(method, hidden, env_steps, learning_starts, root) for method, hidden in grid]
    by = {(r["method"], r["hidden"]): r for r in runs}
    units = {h: 256 * h**2 / 256**3 for h in (64, 256)}
    per_unit = (by["ablation", 256]["update_s"] - by["ablation", 64]["update_s"]) / (units[256] - units[64])
    fixed = max(0.0, by["ablation", 64]["update_s"] - per_unit * units[64])
    result = evaluate(str(by["ablation", 256]["policy"]), "panda", "reach", episodes=40, repeats=1)
    rates = Rates(
        trial_s=process_start_s(root),
        stage_s=DEFAULT_RATES.stage_s,
        env_step_s=float(np.mean([r["env_step_s"] for r in runs])),
        eval_step_s=1.0 / result["env_steps_per_s"],
        update_fixed_s=fixed,
        update_per_unit_s=per_unit,
        relative_factor=by["ps", 256]["update_s"] / by["ablation", 256]["update_s"],
        source=f"measured by `ps-ray bench rates` on {time.strftime('%Y-%m-%d')}",
    )
    return rates, runs


def main(argv: list[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench rates", description=__doc__)
    parser.add_argument("--env-steps", type=positive_int, default=2400, help="per run (default 2400)")
    parser.add_argument("--learning-starts", type=int, default=1000, help="warm-up steps (no updates)")
    parser.add_argument("--out", default=None, help="rates file (default: this machine's cache)")
    args = parser.parse_args(argv)
    if not 0 < args.learning_starts < args.env_steps - 500:
        parser.error("--learning-starts must be positive and at least 500 below --env-steps")
    with tempfile.TemporaryDirectory() as tmp:
        rates, runs = measure(args.env_steps, args.learning_starts, Path(tmp))
    for r in runs:
        print(
            f"  {r['method']:9} hidden {r['hidden']:3}: {r['env_step_s'] * 1e3:6.2f} ms/env step, "
            f"{r['update_s'] * 1e3:6.1f} ms/update, {r['outside_s']:5.1f} s outside the loop"
        )
    path = Path(args.out) if args.out else rates_path()
    write_text(path, json.dumps(dataclasses.asdict(rates), indent=2) + "\n")
    print(f"rates -> {path}")
    for name, value in dataclasses.asdict(rates).items():
        print(f"  {name:18} {value}")


if __name__ == "__main__":
    main()
