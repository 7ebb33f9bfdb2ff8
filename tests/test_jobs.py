"""`ray job submit` path: a local head with token auth, a small sweep submitted as a job, MLflow."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import mlflow
import pytest
import yaml

from tests.processes import own_ray_env

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ray_head():
    """`ray start --head --block` in its own session, shared by this file's tests (its start is
    most of their time); killed with its process group afterwards."""
    env = {**own_ray_env(), "RAY_AUTH_MODE": "token", "RAY_USAGE_STATS_ENABLED": "0"}
    dashboard = free_port()
    head = subprocess.Popen(
        [
            str(BIN / "ray"),
            "start",
            "--head",
            "--block",
            f"--port={free_port()}",
            "--num-cpus=2",
            "--dashboard-host=127.0.0.1",
            f"--dashboard-port={dashboard}",
            # Own ports for every agent: another Ray instance on this machine (the test session's)
            # must not keep the job agent from starting.
            *(
                f"--{name}={free_port()}"
                for name in (
                    "dashboard-agent-listen-port",
                    "dashboard-agent-grpc-port",
                    "metrics-export-port",
                    "runtime-env-agent-port",
                    "ray-client-server-port",
                )
            ),
            f"--temp-dir={Path('/tmp') / f'ps_ray_head_{dashboard}'}",
            "--include-dashboard=true",
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    address = f"http://127.0.0.1:{dashboard}"
    deadline = time.time() + 120
    while time.time() < deadline:  # the dashboard answers over HTTP (a refusal for want of a token too)
        try:
            urllib.request.urlopen(f"{address}/api/version", timeout=2).close()
            break
        except urllib.error.HTTPError:
            break
        except OSError:
            time.sleep(1)
    else:
        os.killpg(head.pid, signal.SIGKILL)
        pytest.fail("the Ray head did not come up")
    yield address, env
    os.killpg(head.pid, signal.SIGTERM)
    try:  # `ray start --block` seldom exits on SIGTERM alone: a short grace, then SIGKILL
        head.wait(timeout=5)
    except subprocess.TimeoutExpired:
        os.killpg(head.pid, signal.SIGKILL)
    shutil.rmtree(Path("/tmp") / f"ps_ray_head_{dashboard}", ignore_errors=True)


@pytest.mark.e2e
@pytest.mark.slow
def test_sweep_submitted_as_a_ray_job_lands_in_mlflow(ray_head, tmp_path, tiny_train):
    address, env = ray_head
    storage = tmp_path / "store"
    sweep = tmp_path / "job.yaml"
    sweep.write_text(
        yaml.safe_dump(
            {
                "name": "job",
                "methods": ["ablation"],
                "robots": ["panda"],
                "tasks": ["reach"],
                "seeds": [1],
                "interface_dims": [8],
                "storage": str(storage),
                "train": {**tiny_train, "env_steps": 200},
            }
        )
    )
    command = [
        str(BIN / "ray"),
        "job",
        "submit",
        "--address",
        address,
        "--working-dir",
        str(REPO),
        "--",
        str(BIN / "ps-ray"),
        "sweep",
        str(sweep),
    ]
    for _ in range(30):  # the job agent may come up a little after the dashboard answers
        submit = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
        if "No available agent" not in submit.stderr + submit.stdout:
            break
        time.sleep(3)
    assert submit.returncode == 0, submit.stdout[-3000:] + submit.stderr[-2000:]
    assert "succeeded" in submit.stdout
    client = mlflow.MlflowClient(f"sqlite:///{storage / 'job' / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("job")
    (run,) = client.search_runs([experiment.experiment_id], "tags.`ps_ray.stage` = 'train'")
    assert run.info.run_name == "panda/reach · ablation · 1 · i8"
    assert run.info.status == "FINISHED"
    assert run.data.metrics["env_steps"] >= 200


@pytest.mark.e2e
def test_job_cli_without_a_token_is_refused(ray_head):
    address, env = ray_head
    no_auth = {k: v for k, v in env.items() if k != "RAY_AUTH_MODE"}
    listing = subprocess.run(
        [str(BIN / "ray"), "job", "list", "--address", address],
        env=no_auth,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert listing.returncode != 0
    # refused for the missing token, not for any other reason (a dead head, a wrong address)
    assert "Unauthorized: Missing authentication token" in listing.stderr, listing.stderr[-2000:]
