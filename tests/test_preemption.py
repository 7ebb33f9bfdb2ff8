"""A trial whose node went away is launched again; one that failed on its own is not.

A real preemption cannot happen here: the classification is tested on Ray's own messages (built
by ray.exceptions, or as tests/test_sweep.py's killed node left them in error.txt), and the
relaunch on trials that raise those messages themselves."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from ray.core.generated.common_pb2 import ActorDiedErrorContext, NodeDeathInfo
from ray.exceptions import ActorDiedError, LocalRayletDiedError, NodeDiedError, WorkerCrashedError

from ps_ray.pipeline.preemption import failures, node_lost, preempted
from tests.processes import own_ray_env

NODE_ID = "0f5d1c3a9e4b2c7d8e6f1a2b3c4d5e6f7a8b9c0d1e2f3a4b5c6d7e8f"
ACTOR_ID = bytes.fromhex("c40f61913112a78fb3dab2ab01000000")


def actor_died(error_message: str, reason=NodeDeathInfo.UNEXPECTED_TERMINATION) -> str:
    """An ActorDiedError as Ray formats it from the GCS's context (ray/exceptions.py)."""
    context = ActorDiedErrorContext(
        error_message=error_message,
        class_name="ImplicitFunc",
        actor_id=ACTOR_ID,
        pid=4242,
        node_ip_address="10.0.3.17",
        node_death_info=NodeDeathInfo(reason=reason),
    )
    return str(ActorDiedError(context))


# the GCS's own texts (Ray 2.60) after a node dies, with its death reason
NODE_DIED = f"The actor died because its node has died. Node Id: {NODE_ID}\n"
SPOT_TAKEN = NODE_DIED + "\tthe actor's node was preempted: instance terminated by the cloud provider"
HEALTH = NODE_DIED + "\tthe actor's node was terminated unexpectedly: health check failed"
# what tests/test_sweep.py's killed worker node left in its trial's error.txt (Ray 2.60)
UNAVAILABLE = (
    "The actor c40f61913112a78fb3dab2ab01000000 is unavailable: The actor is temporarily unavailable: "
    "RpcError: RPC error: recvmsg:Connection reset by peer rpc_code: 14. The task may or may not "
    "have been executed on the actor."
)
# ... and what a worker process killed on a live node left (the trial's own failure)
WORKER_DIED = (
    "The actor is dead because its worker process has died. Worker exit type: SYSTEM_ERROR Worker "
    "exit detail: Worker unexpectedly exits with a connection error code 2. End of file. Some common "
    "causes include: (1) the process was killed by the OOM killer due to high memory usage, (2) ray "
    "stop --force was called, or (3) the worker crashed unexpectedly due to SIGSEGV or another "
    "unexpected error."
)
USER_ERROR = 'Traceback (most recent call last):\n  File "x.py", line 3\nRuntimeError: planned failure'


@pytest.mark.parametrize(
    "message",
    [
        actor_died(SPOT_TAKEN, NodeDeathInfo.AUTOSCALER_DRAIN_PREEMPTED),
        actor_died(HEALTH),
        actor_died(NODE_DIED),
        UNAVAILABLE,
        str(
            NodeDiedError(
                "Task failed because the node it was running on is dead or unavailable. Node IP: "
                f"10.0.3.17, node ID: {NODE_ID}. This can happen if the node was preempted, had a "
                "hardware failure, or its raylet crashed unexpectedly."
            )
        ),
        str(LocalRayletDiedError()),
    ],
)
def test_a_lost_node_is_a_preemption(message):
    assert node_lost(message)
    assert preempted([message]) and preempted([message, UNAVAILABLE])


@pytest.mark.parametrize(
    "message",
    [
        actor_died(WORKER_DIED, NodeDeathInfo.EXPECTED_TERMINATION),  # OOM kill on a live node
        WORKER_DIED,
        str(WorkerCrashedError()),
        str(ActorDiedError()),  # died, cause unknown
        USER_ERROR,
        "did not finish",
    ],
)
def test_a_trials_own_failure_is_not(message):
    assert not node_lost(message)
    assert not preempted([message])
    assert not preempted([UNAVAILABLE, message])  # one failure of its own: the trial's own


def test_nothing_failed_is_no_preemption():
    assert not preempted([])


def test_every_failure_of_an_error_txt_is_read():
    error_txt = (
        f"Failure # 1 (occurred at 2026-11-25_16-03-47)\n{UNAVAILABLE}\n"
        f"Failure # 2 (occurred at 2026-11-25_16-09-02)\n{USER_ERROR}\n\n"
    )
    assert failures(error_txt) == [UNAVAILABLE, USER_ERROR]
    assert not preempted(failures(error_txt))
    assert preempted(failures(error_txt.split("Failure # 2")[0]))
    assert failures("") == []


# Three trials through the stages' runner with no Tune retries (max_failures 0): "lost" raises a
# lost node's message on its first launch only, "own" always fails on its own, "always" loses its
# node on every launch. Each launch is counted in a file.
RELAUNCH = """
import json, sys
from pathlib import Path
import ray
from ray import tune
from ps_ray.pipeline.trials import run_trials
from ps_ray.store.attempts import FINISHED

LOST = "The actor is temporarily unavailable: RpcError: RPC error: Socket closed rpc_code: 14"
counts = Path(sys.argv[2])

def trial(config):
    name = config["n"]
    launches = counts / name
    launches.write_text(str(int(launches.read_text()) + 1 if launches.exists() else 1))
    if name == "own":
        raise RuntimeError("planned failure")
    if name == "always" or int(launches.read_text()) == 1:
        raise RuntimeError(LOST)
    tune.report({"launch": int(launches.read_text()), FINISHED: True})

ray.init(num_cpus=3, include_dashboard=False, log_to_driver=False)
out = run_trials(trial, {"n": ["lost", "own", "always"]}, folder=Path(sys.argv[1]), stage="spot",
                 callback=tune.Callback(), resume=False, progress=False, max_concurrent=None,
                 max_failures=0, preemption_retries=2)
print(json.dumps({o.config["n"]: [o.error is None, o.metrics.get("launch")] for o in out}))
"""


@pytest.mark.e2e
@pytest.mark.slow
def test_trials_that_lost_their_node_are_launched_again_and_others_are_not(tmp_path):
    counts = tmp_path / "launches"
    counts.mkdir()
    proc = subprocess.run(
        [sys.executable, "-c", RELAUNCH, str(tmp_path / "tune" / "spot"), str(counts)],
        capture_output=True,
        text=True,
        timeout=300,
        env=own_ray_env(),  # its own Ray, with three CPUs
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["lost"] == [True, 2]  # finished on its second launch, though max_failures is 0
    assert out["own"][0] is False and out["always"][0] is False
    launches = {p.name: int(p.read_text()) for p in counts.iterdir()}
    assert launches == {"lost": 2, "own": 1, "always": 3}  # 1 + preemption_retries at most
