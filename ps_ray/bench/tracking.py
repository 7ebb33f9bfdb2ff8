"""Benchmark the driver-side cost of MLflow tracking per Tune result.

Against a fresh sqlite store in a temp dir, in one process, with the same synthetic results
(``--metrics`` whitelisted metrics each, nested like RLlib's ``env_runners/...``):

  callback     MLflowTuneCallback.on_trial_result, flush_every=20 (log_batch every 20 results)
  callback/1   the same with flush_every=1 (one log_batch per result)
  log_metric   one ``mlflow.log_metric`` call per metric, as Ray's MLflowLoggerCallback does

Prints mean, median and p95 ms per result (the callback's mean includes its flushes).

    ps-ray bench tracking [--results 200] [--metrics 10]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from ps_ray.cli.args import Parser, positive_int
from ps_ray.pipeline.tune_tracking import MLflowTuneCallback
from ps_ray.specs.names import trial_key
from ps_ray.store.mlflow_values import flatten_params
from ps_ray.store.tracking import default_tracking_uri, ensure_experiment

SPEC = {
    "method": "ps",
    "robot": "panda",
    "task": "reach",
    "seed": 101,
    "interface_dim": 128,
    "env_steps": 50_000,
}


def fake_result(i: int, n_metrics: int) -> dict:
    """A Tune result: ``n_metrics`` whitelisted values under ``env_runners``, plus noise keys."""
    metrics = {f"m{k}": i * 0.1 + k for k in range(n_metrics)}
    return {
        "training_iteration": i,
        "timestamp": time.time(),
        "env_runners": metrics,
        "config": {"lots": "of", "other": "keys"},
        "time_total_s": float(i),
    }


def metric_keys(n_metrics: int) -> list[str]:
    return [f"env_runners/m{k}" for k in range(n_metrics)]


def summarize(times: list[float]) -> tuple[float, float, float]:
    """(mean, median, p95) in ms."""
    ms = sorted(t * 1e3 for t in times)
    return statistics.fmean(ms), statistics.median(ms), ms[int(0.95 * (len(ms) - 1))]


def time_each(fn: Callable[[int], None], n: int) -> list[float]:
    times = []
    for i in range(1, n + 1):
        t0 = time.perf_counter()
        fn(i)
        times.append(time.perf_counter() - t0)
    return times


def bench_callback(
    uri: str, exp_id: str, seed: int, n: int, n_metrics: int, flush_every: int
) -> tuple[list[float], float]:
    from ray.tune.experiment import Trial

    trial = Trial("bench", config={"spec": {**SPEC, "seed": seed}}, stub=True)
    callback = MLflowTuneCallback(
        uri,
        exp_id,
        metric_keys=metric_keys(n_metrics),
        key_fn=lambda trial: trial_key(trial.config["spec"]),
        params_fn=lambda trial: flatten_params(trial.config["spec"]),
        flush_every=flush_every,
        tags={"ps_ray.stage": "bench"},
    )
    t0 = time.perf_counter()
    callback.on_trial_start(0, [trial], trial)
    start_s = time.perf_counter() - t0
    times = time_each(lambda i: callback.on_trial_result(i, [trial], trial, fake_result(i, n_metrics)), n)
    callback.on_trial_complete(n, [trial], trial)
    return times, start_s


def bench_log_metric(uri: str, exp_id: str, n: int, n_metrics: int) -> list[float]:
    import mlflow

    mlflow.set_tracking_uri(uri)
    run_id = mlflow.MlflowClient(uri).create_run(exp_id, run_name="log_metric").info.run_id
    keys = metric_keys(n_metrics)

    def one(i: int) -> None:
        result = fake_result(i, n_metrics)
        for key in keys:
            mlflow.log_metric(key, result["env_runners"][key.split("/")[1]], step=i, run_id=run_id)

    times = time_each(one, n)
    mlflow.MlflowClient(uri).set_terminated(run_id)
    return times


def main(argv: list[str] | None = None) -> None:
    parser = Parser(
        prog="ps-ray bench tracking",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--results", type=positive_int, default=200, help="results per variant")
    parser.add_argument("--metrics", type=positive_int, default=10, help="whitelisted metrics per result")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="ps_ray_bench_tracking_") as tmp:
        uri = default_tracking_uri(tmp)
        t0 = time.perf_counter()
        exp_id = ensure_experiment(uri, "bench", Path(tmp) / "artifacts")
        create_s = time.perf_counter() - t0
        rows = {}
        rows["callback"], start_s = bench_callback(uri, exp_id, 1, args.results, args.metrics, 20)
        rows["callback/1"], _ = bench_callback(uri, exp_id, 2, args.results, args.metrics, 1)
        rows["log_metric"] = bench_log_metric(uri, exp_id, args.results, args.metrics)
    print(
        f"sqlite store, {args.results} results x {args.metrics} metrics per variant; "
        f"store + experiment created in {create_s:.2f} s, run created/found in {start_s * 1e3:.0f} ms"
    )
    print(f"{'ms per result':<14}{'mean':>9}{'median':>9}{'p95':>9}")
    for name, times in rows.items():
        mean, median, p95 = summarize(times)
        print(f"{name:<14}{mean:>9.2f}{median:>9.2f}{p95:>9.2f}")
    ratio = summarize(rows["log_metric"])[0] / summarize(rows["callback"])[0]
    print(f"log_metric / callback (mean): {ratio:.0f}x")


if __name__ == "__main__":
    main()
