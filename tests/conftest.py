"""Shared fixtures: one torch thread, one local Ray instance for the whole session."""

import html
import os
import pickle
import re
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import pytest
import torch

from ps_ray.analysis.browser import run_chromium

torch.set_num_threads(1)
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
# No test reads this machine's measured rates (`ps-ray bench rates`): projections use the defaults.
os.environ["PS_RAY_CACHE"] = tempfile.mkdtemp(prefix="ps_ray_cache_")


def _init_local_ray() -> None:
    """The session's Ray; its address goes into RAY_ADDRESS, so that a `ps-ray` command a test
    runs in a subprocess joins it instead of starting its own (about 10 s of CPU each,
    docs/cost.md "The test suite's time")."""
    import ray

    ray.init(
        address="local", num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False
    )
    os.environ["RAY_ADDRESS"] = ray.get_runtime_context().gcs_address


def _shutdown_ray() -> None:
    import ray

    os.environ.pop("RAY_ADDRESS", None)
    ray.shutdown()


def own_ray_env() -> dict[str, str]:
    """This process's environment without RAY_ADDRESS: a subprocess started with it starts its
    own Ray, for tests that kill a run together with every process it started."""
    return {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}


@pytest.fixture(scope="session", autouse=True)
def ray_local():
    _init_local_ray()
    yield
    _shutdown_ray()


@pytest.fixture
def two_node_cluster():
    """A local two-node Ray cluster (head and one worker, one CPU each), connected. The session's
    single-node instance is stopped for it and restarted afterwards, so no later test depends on
    the order tests run in."""
    import ray
    from ray.cluster_utils import Cluster

    was_running = ray.is_initialized()
    if was_running:
        _shutdown_ray()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    cluster.add_node(num_cpus=1)
    try:
        ray.init(address=cluster.address, log_to_driver=False)
        yield cluster
    finally:
        ray.shutdown()
        cluster.shutdown()
        if was_running:
            _init_local_ray()


# A small `ps-ray train` on the point task: PS, interface 8, checkpoints every 3 steps.
TRAIN_ARGS = (
    "--task point --method ps --interface-dim 8 --hidden 32 --learning-starts 200 "
    "--random-episodes 2 --episodes-per-step 4 --checkpoint-every 3 --eval-every 3 "
    "--eval-episodes 4 --batch-size 64 --anchor-episodes 20"
).split()


@pytest.fixture
def train_cmd():
    """``train_cmd(run_dir, env_steps)``: the command line of that small training run."""

    def command(run_dir, steps: int) -> list[str]:
        return [
            sys.executable,
            "-m",
            "ps_ray.cli",
            "train",
            *TRAIN_ARGS,
            "--env-steps",
            str(steps),
            "--run-dir",
            str(run_dir),
        ]

    return command


class _Planted:
    """A pickle that, if ever loaded, writes a marker file."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (exec, (f"open({self.marker!r}, 'w').write('pickle ran')",))


RAY_PICKLES = ("algorithm_state.pkl", "class_and_ctor_args.pkl", "state.pkl", "params.pkl", "tuner.pkl")


@pytest.fixture(scope="session")
def planted(tmp_path_factory):
    """``planted(folder, names=RAY_PICKLES)`` writes hostile pickles there; ``planted.marker``
    exists once any of them has been unpickled (by any test of the session)."""

    marker = tmp_path_factory.mktemp("planted") / "pickle-ran"

    def plant(folder, names=RAY_PICKLES) -> None:
        for name in names:
            (Path(folder) / name).write_bytes(pickle.dumps(_Planted(marker)))

    plant.marker = marker
    return plant


# Training settings small enough for a sweep of several trials in a test (real RLlib runs).
TINY_TRAIN = {
    "env_steps": 300,
    "hidden": 32,
    "learning_starts": 100,
    "random_episodes": 2,
    "eval_every": 2,
    "eval_episodes": 2,
    "checkpoint_every": 2,
    "batch_size": 32,
}


@pytest.fixture(scope="session")
def tiny_train() -> dict:
    return dict(TINY_TRAIN)


def _cli(*args: str, env: dict | None = None, own_ray: bool = False, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "ps_ray.cli", *args],
        env={**(own_ray_env() if own_ray else os.environ), **(env or {})},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        **kwargs,
    )


@pytest.fixture(scope="session")
def cli():
    """``cli(*args, env=None, own_ray=False, **popen_kwargs)``: ``ps-ray`` in a subprocess, output
    in one pipe; it joins the session's Ray unless ``own_ray``."""
    return _cli


def _visible_text(page: str | Path, *, wait_ms: int = 20_000, timeout: float = 120) -> str:
    """The text of ``page`` after its scripts ran for ``wait_ms`` of virtual time (tags, scripts
    and styles removed, whitespace collapsed)."""
    wait = (f"--virtual-time-budget={wait_ms}",) if wait_ms else ()
    dom = run_chromium(page, *wait, "--dump-dom", width=1400, height=1000, timeout=timeout)
    dom = re.sub(r"<(script|style)\b.*?</\1>", " ", dom, flags=re.S)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", dom)).split())


@pytest.fixture
def visible_text():
    """The text of a page (file or URL) in headless Chromium once its scripts ran: what a person
    reads."""
    return _visible_text


# The heaviest modules first: under `pytest -n 2` the longest one starts at once instead of last.
HEAVY_FIRST = ("test_pipeline.py", "test_sweep.py", "test_train.py", "test_checkpoint.py", "test_rllib.py")


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def wait_until_serving(base: str, server: subprocess.Popen, what: str, timeout: float = 120) -> None:
    """Poll ``<base>/health`` until the server answers; fail if it exited or the time ran out."""
    deadline = time.time() + timeout
    while True:
        try:
            with urllib.request.urlopen(f"{base}/health", timeout=2):
                return
        except OSError:
            assert server.poll() is None and time.time() < deadline, f"{what} did not start"
            time.sleep(0.5)
