"""Tune sweeps end to end: MLflow runs per trial, resume after SIGKILL, crash retry, 2 nodes."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import mlflow
import pytest
import yaml

from ps_ray.config import load_sweep
from ps_ray.sweep import sweep_dir


def write_sweep(
    tmp_path: Path, name: str, train: dict, *, methods=("ablation",), seeds=(1, 2), max_concurrent: int = 2
) -> Path:
    data = {
        "name": name,
        "methods": list(methods),
        "robots": ["panda"],
        "tasks": ["reach"],
        "seeds": list(seeds),
        "interface_dims": [8],
        "train": train,
        "anchors": {"episodes": 12},
        "max_concurrent": max_concurrent,
        "storage": str(tmp_path / "store"),
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def runs(path: Path) -> dict[str, mlflow.entities.Run]:
    spec = load_sweep(path)
    client = mlflow.MlflowClient(f"sqlite:///{sweep_dir(spec) / 'mlflow.db'}")
    experiment = client.get_experiment_by_name(spec.name)
    if experiment is None:
        return {}
    return {r.info.run_name: r for r in client.search_runs([experiment.experiment_id])}


def history(path: Path, run, key: str) -> list[tuple[int, float]]:
    client = mlflow.MlflowClient(f"sqlite:///{sweep_dir(load_sweep(path)) / 'mlflow.db'}")
    return sorted((m.step, m.value) for m in client.get_metric_history(run.info.run_id, key))


def test_sweep_tracks_one_mlflow_run_per_trial_with_artifacts(tmp_path, cli, tiny_train):
    path = write_sweep(tmp_path, "track", tiny_train, methods=("ps", "ablation"), seeds=(1,))
    proc = cli("sweep", str(path))
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    found = runs(path)
    # the plain source policy of the anchor stage is tracked too
    assert sorted(found) == ["ablation/panda/reach/1/i8", "plain/panda/reach/1/i8", "ps/panda/reach/1/i8"]
    assert found["plain/panda/reach/1/i8"].data.tags["ps_ray.stage"] == "anchors_plain"
    found.pop("plain/panda/reach/1/i8")
    client = mlflow.MlflowClient(f"sqlite:///{sweep_dir(load_sweep(path)) / 'mlflow.db'}")
    for name, run in found.items():
        assert run.info.status == "FINISHED"
        assert run.data.params["method"] == name.split("/")[0]
        assert len(run.data.params) < 40  # our spec, not RLlib's hundreds of config keys
        assert run.data.tags["ps_ray.stage"] == "train"
        assert history(path, run, "env_steps")[-1][1] >= 300
        artifacts = {a.path for a in client.list_artifacts(run.info.run_id)}
        assert {"policy.safetensors", "signature.json", "spec.json"} <= artifacts
    ps_artifacts = {a.path for a in client.list_artifacts(found["ps/panda/reach/1/i8"].info.run_id)}
    assert any(a.startswith("anchors_3d") for a in ps_artifacts)


def test_resume_after_sigkill_reruns_only_missing_trials_and_never_unpickles(
    tmp_path, cli, tiny_train, planted
):
    path = write_sweep(tmp_path, "killed", tiny_train, seeds=(1, 2, 3), max_concurrent=1)
    proc = cli("sweep", str(path), start_new_session=True)
    deadline = time.time() + 300
    while time.time() < deadline:
        if any(r.info.status == "FINISHED" for r in runs(path).values()):
            break
        time.sleep(0.5)
    else:
        pytest.fail("no trial finished in time")
    os.killpg(proc.pid, signal.SIGKILL)  # the driver and everything it started
    proc.wait()
    before = {n: r for n, r in runs(path).items() if r.info.status == "FINISHED"}
    assert 1 <= len(before) < 3
    done_name = next(iter(before))
    done_history = history(path, before[done_name], "env_steps")
    # Anyone who can write to shared storage could plant these where Tune and RLlib look.
    folder = sweep_dir(load_sweep(path))
    for place in [folder, *folder.glob("tune*"), *folder.glob("tune*/*"), *folder.glob("tune*/*/check*")]:
        if place.is_dir():
            planted(place)

    resumed = cli("sweep", str(path), "--resume")
    out, _ = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, out[-3000:]
    after = runs(path)
    assert sorted(after) == [f"ablation/panda/reach/{s}/i8" for s in (1, 2, 3)]  # one run per trial
    assert all(r.info.status == "FINISHED" for r in after.values())
    assert history(path, after[done_name], "env_steps") == done_history  # not rerun
    assert not planted.marker.exists(), "a planted pickle was loaded on resume"


def _trial_workers(tag: str) -> list[int]:
    """PIDs of Tune trial workers (``ray::ImplicitFunc``) started under the environment ``tag``."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            if (
                b"ray::ImplicitFunc" in (proc / "cmdline").read_bytes()
                and tag.encode() in (proc / "environ").read_bytes()
            ):
                found.append(int(proc.name))
        except (OSError, ValueError):
            continue
    return found


def test_a_killed_trial_worker_is_retried_from_its_checkpoint(tmp_path, cli, tiny_train):
    """SIGKILL of a trial's worker process once it has a sealed checkpoint, as a crash or an
    out-of-memory kill would: Tune retries the trial (FailureConfig), from that checkpoint."""
    path = write_sweep(tmp_path, "crash", {**tiny_train, "env_steps": 3000}, seeds=(1,))
    tag = f"PS_RAY_TEST_RUN={tmp_path.name}"
    proc = cli("sweep", str(path), env={"PS_RAY_TEST_RUN": tmp_path.name})
    tune_dir = sweep_dir(load_sweep(path)) / "tune"
    deadline = time.time() + 300
    while not list(tune_dir.glob("*/checkpoint_*/manifest.json")):
        assert proc.poll() is None and time.time() < deadline, "no checkpoint before the kill"
        time.sleep(0.2)
    workers = _trial_workers(tag)
    assert len(workers) == 1, workers
    os.kill(workers[0], signal.SIGKILL)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    assert len(list(tune_dir.glob("*/params.json"))) == 1  # one trial, retried in place
    (run,) = runs(path).values()
    assert run.info.status == "FINISHED"
    points = history(path, run, "env_steps")
    assert points[-1][1] >= 3000
    # Restored from the checkpoint saved just before the crash: iterations and env steps go on
    # from there, none is trained twice.
    iterations, steps = [i for i, _ in points], [v for _, v in points]
    assert len(set(iterations)) == len(iterations)
    assert steps == sorted(set(steps))


def test_trials_spread_over_two_nodes(tmp_path, tiny_train):
    import ray
    from ray.cluster_utils import Cluster

    from ps_ray.sweep import run_sweep

    path = write_sweep(tmp_path, "nodes", tiny_train, seeds=(1, 2))
    if ray.is_initialized():  # the session's single-node instance
        ray.shutdown()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    cluster.add_node(num_cpus=1)
    try:
        ray.init(address=cluster.address, log_to_driver=False)
        results = run_sweep(load_sweep(path), progress=False)
        assert not any(r.error for r in results)
        node_ids = {r.metrics["node_id"] for r in results}
        assert len(node_ids) == 2, node_ids
    finally:
        ray.shutdown()
        cluster.shutdown()
