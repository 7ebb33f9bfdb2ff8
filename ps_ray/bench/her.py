"""Benchmark ps_ray.data.her.HindsightReplay with the push spec (T=50, A=7, 8+12+3+3 obs floats).

Prints add_episodes time per 100 episodes, sample(256) and sample_many(40, 256) times, storage
size and resident-memory growth, for buffers of 2,000 and 20,000 episodes (1e5 and 1e6
transitions). For context: RLlib's episode replay costs 25-31 ms per 256-sample here.

    ps-ray bench her [--capacities 2000 20000] [--repeats 300]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from ps_ray.cli.args import Parser, positive_int
from ps_ray.data.her import HindsightReplay
from ps_ray.envs.goals import goal_reward

T, A = 50, 7
PUSH_SPEC = {
    "robot_state": ((8,), np.float32),
    "task_state": ((12,), np.float32),
    "achieved_goal": ((3,), np.float32),
    "desired_goal": ((3,), np.float32),
}


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def timed_ms(fn, repeats: int) -> tuple[float, float]:
    """(median, p95) wall time in ms."""
    fn()  # warm-up
    times = np.empty(repeats)
    for i in range(repeats):
        t0 = time.perf_counter()
        fn()
        times[i] = time.perf_counter() - t0
    return float(np.median(times) * 1e3), float(np.percentile(times, 95) * 1e3)


def bench(capacity: int, repeats: int) -> None:
    rng = np.random.default_rng(0)
    chunk = {k: rng.standard_normal((100, T + 1, *s)).astype(dt) for k, (s, dt) in PUSH_SPEC.items()}
    actions = rng.uniform(-1, 1, (100, T, A)).astype(np.float32)
    rss0 = rss_mb()
    buf = HindsightReplay(PUSH_SPEC, A, T, capacity, goal_reward, relabel_prob=0.8, seed=0)
    fill_times, wrap_times = [], []
    while buf.episodes_added < 2 * capacity:  # fill (first touch of each page), then overwrite
        times = fill_times if buf.episodes_added < capacity else wrap_times
        t0 = time.perf_counter()
        buf.add_episodes(chunk, actions)
        times.append(time.perf_counter() - t0)
        if len(fill_times) == capacity // 100 and not wrap_times:
            rss1 = rss_mb()
    data_mb = capacity * (T + 1) * sum(int(np.prod(s)) for s, _ in PUSH_SPEC.values()) * 4 / 2**20
    act_mb = capacity * T * A * 4 / 2**20

    print(f"\n== capacity {capacity:,} episodes = {buf.num_transitions:,} transitions ==")
    print(
        f"storage allocated   {buf.nbytes / 2**20:8.1f} MiB  (obs {data_mb:.1f} + actions {act_mb:.1f});"
        f" RSS growth after filling {rss1 - rss0:.1f} MiB"
    )
    print(
        f"add_episodes(100)   median {np.median(fill_times) * 1e3:7.3f} ms while filling,"
        f" {np.median(wrap_times) * 1e3:.3f} ms overwriting (ring full)"
    )
    for label, fn in [
        ("sample(256)        ", lambda: buf.sample(256)),
        ("sample_many(40,256)", lambda: buf.sample_many(40, 256)),
    ]:
        med, p95 = timed_ms(fn, repeats)
        print(f"{label} median {med:7.3f} ms   p95 {p95:7.3f} ms")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "replay.npz"
        t0 = time.perf_counter()
        buf.save(path)
        t1 = time.perf_counter()
        HindsightReplay.from_file(path, goal_reward)
        t2 = time.perf_counter()
        print(f"save {t1 - t0:.2f} s, from_file {t2 - t1:.2f} s, file {path.stat().st_size / 2**20:.1f} MiB")


def main(argv: list[str] | None = None) -> None:
    ap = Parser(
        prog="ps-ray bench her", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--capacities", type=positive_int, nargs="+", default=[2_000, 20_000])
    ap.add_argument("--repeats", type=positive_int, default=300)
    args = ap.parse_args(argv)
    floats = sum(int(np.prod(s)) for s, _ in PUSH_SPEC.values())
    print(f"numpy {np.__version__}; push spec T={T}, A={A}, obs {floats} floats/step")
    for cap in args.capacities:
        bench(cap, args.repeats)


if __name__ == "__main__":
    main()
