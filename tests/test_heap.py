"""A reused Tune worker gives each finished trial's memory back (ps_ray.pipeline.heap)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).parents[1]

# A reused Tune worker's life: each trial a training run in a new thread of one process.
PROBE = """
import threading
from ps_ray.pipeline.heap import releasing
from ps_ray.rllib.loop import TrainingRun, start_local_ray
from ps_ray.specs.train import TrainSpec

def rss_mb():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024

def train(config):
    spec = TrainSpec(method="plain", task="reach", seed=config["seed"], env_steps=300,
                     learning_starts=100, eval_every=3, eval_episodes=2, hidden=64)
    run = TrainingRun(spec, None)
    for tick in run.ticks():
        if tick.finished is not None:
            break
    run.stop()

start_local_ray()
for trial in (train, releasing(train)):  # three trials kept, then three released
    sizes = []
    for seed in range(3):
        thread = threading.Thread(target=trial, args=({"seed": seed},))
        thread.start()
        thread.join()
        sizes.append(rss_mb())
    print(" ".join(f"{size:.0f}" for size in sizes))
"""


@pytest.mark.e2e
@pytest.mark.slow
def test_a_reused_worker_gives_each_trials_memory_back():
    """One process runs three trials as a reused worker did, then three releasing ones (the first
    of those trims what the kept ones left): the growth over the last two of each."""
    run = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    kept, released = ([float(v) for v in line.split()] for line in run.stdout.strip().splitlines()[-2:])
    assert kept[-1] - kept[0] > 300, kept  # the growth is real: each trial's thread keeps its freed heap
    assert released[-1] - released[0] < 100, released
