"""Shared fixtures: one torch thread; one local Ray instance for the session, started by the first
test that asks for it (``ray_local``); the three lanes of the suite.

Lanes: a test that starts Ray, a Python or Chromium subprocess (a `ps-ray` command, the report in a
browser), or rolls out many physics episodes, is end-to-end (``e2e``): marked by hand, or at
collection when it uses a fixture of :data:`E2E_FIXTURES`. Minutes-long checks (learning with small
budgets, cluster services) are ``slow``: ``./run.sh test-slow``, not CI's ``./run.sh test``. Everything
else is the fast lane (``./run.sh test-fast``: ``-m "not slow and not e2e"``), and a fast-lane test
that starts Ray or such a subprocess fails, naming the marker it lacks."""

import atexit
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
import torch

from tests.processes import cli_process, page_text
from tests.small_runs import RAY_PICKLES, TINY_TRAIN, TRAIN_ARGS, HostilePickle

torch.set_num_threads(1)
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
# No test reads this machine's measured rates (`ps-ray bench rates`): projections use the defaults.
os.environ["PS_RAY_CACHE"] = tempfile.mkdtemp(prefix="ps_ray_cache_")
atexit.register(shutil.rmtree, os.environ["PS_RAY_CACHE"], ignore_errors=True)  # no litter in /tmp


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


@pytest.fixture(scope="session")
def ray_local():
    """The session's local Ray (two CPUs); a test that runs Tune or RLlib asks for it."""
    import ray

    _E2E_RAY.append(True)  # from here on this worker's Ray is an end-to-end test's
    if not ray.is_initialized():
        _init_local_ray()
    yield
    _shutdown_ray()


# fixtures that start Ray, a subprocess or a browser: a test that uses one is end-to-end
E2E_FIXTURES = frozenset({"ray_local", "cli", "two_node_cluster", "visible_text", "train_cmd"})
# what a fast-lane test may not start as a subprocess
_E2E_PROGRAMS = ("python", "ps-ray", "chromium", "ray", "mlflow", "gcs_server")
_E2E_RAY: list[bool] = []  # non-empty once an end-to-end test of this worker asked for Ray


def _ray_running() -> bool:
    return "ray" in sys.modules and sys.modules["ray"].is_initialized()


@pytest.fixture(autouse=True)
def _fast_lane_guard(request, monkeypatch):
    """A test of the fast lane (neither ``e2e`` nor ``slow``) that starts Ray or a Python or
    Chromium subprocess fails here, naming the marker it lacks; the others get the session's Ray
    (a `ps-ray` command they run joins it)."""
    if request.node.get_closest_marker("e2e") or request.node.get_closest_marker("slow"):
        request.getfixturevalue("ray_local")
        yield
        return
    popen_init = subprocess.Popen.__init__

    def guarded(self, args, *rest, **kwargs):
        first = args[0] if isinstance(args, (list, tuple)) else str(args).split()[0]
        if str(first) == sys.executable or Path(str(first)).name.startswith(_E2E_PROGRAMS):
            pytest.fail(f"{request.node.nodeid} starts {first}: mark it e2e (pytest.mark.e2e)")
        popen_init(self, args, *rest, **kwargs)

    monkeypatch.setattr(subprocess.Popen, "__init__", guarded)
    if _ray_running() and not _E2E_RAY:
        pytest.fail(f"{request.node.nodeid}: Ray runs, started by a fixture of a fast-lane test; mark it e2e")
    yield
    if _ray_running() and not _E2E_RAY:
        pytest.fail(f"{request.node.nodeid} started Ray: ask for the ray_local fixture (it marks e2e)")


@pytest.fixture
def two_node_cluster():
    """A local two-node Ray cluster (head and one worker, one CPU each), connected. The session's
    single-node instance is stopped for it and restarted afterwards, so no later test depends on
    the order tests run in."""
    import ray
    from ray.cluster_utils import Cluster

    _E2E_RAY.append(True)
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


@pytest.fixture(scope="session")
def planted(tmp_path_factory):
    """``planted(folder, names=RAY_PICKLES)`` writes hostile pickles there; ``planted.marker``
    exists once any of them has been unpickled (by any test of the session)."""

    marker = tmp_path_factory.mktemp("planted") / "pickle-ran"

    def plant(folder, names=RAY_PICKLES) -> None:
        for name in names:
            (Path(folder) / name).write_bytes(pickle.dumps(HostilePickle(marker)))

    plant.marker = marker
    return plant


@pytest.fixture(scope="session")
def tiny_train() -> dict:
    return dict(TINY_TRAIN)


@pytest.fixture(scope="session")
def cli(ray_local):
    """``cli(*args, env=None, own_ray=False, **popen_kwargs)``: ``ps-ray`` in a subprocess, output
    in one pipe; it joins the session's Ray unless ``own_ray``."""
    return cli_process


@pytest.fixture
def visible_text():
    """The text of a page (file or URL) in headless Chromium once its scripts ran: what a person
    reads."""
    return page_text


# The heaviest modules first: under `pytest -n 2` the longest one starts at once instead of last.
# the files of the end-to-end lane, longest first (quiet durations, docs/cost.md): each xdist
# worker takes the next whole file (--dist loadfile; run.sh turns off xdist's own reordering by
# test count, --no-loadscope-reorder), so the longest start first and the short ones fill in
HEAVY_FIRST = (
    "test_pipeline.py",
    "test_sweep.py",
    "test_train.py",
    "test_search.py",
    "test_zero_shot.py",
    "test_grid.py",
    "test_rllib.py",
    "test_tracking.py",
    "test_jobs.py",
    "test_demo.py",
    "test_stitch_zoo.py",
    "test_evaluate_pair.py",
)


def pytest_collection_modifyitems(items):
    for item in items:
        if E2E_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.e2e)
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
