"""Tune sweeps end to end: MLflow runs per trial, resume after SIGKILL, crash retry, 2 nodes."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import time
from contextlib import closing
from pathlib import Path

import mlflow
import numpy as np
import pytest
import yaml

from ps_ray.nets.policy import GreedyPolicy
from ps_ray.nets.policy_file import load_policy
from ps_ray.pipeline.policy_models import example_observation
from ps_ray.specs.sweep import load_sweep
from ps_ray.store.attempts import START_STEPS
from ps_ray.store.checkpoint import latest as latest_checkpoint
from ps_ray.store.layout import sweep_layout
from ps_ray.store.tracking import git_commit


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
    db = sweep_layout(spec).root / "mlflow.db"
    if not _has_experiment(db, spec.name):  # a client opened first would make the store itself
        return {}
    client = mlflow.MlflowClient(f"sqlite:///{db}")
    experiment = client.get_experiment_by_name(spec.name)
    if experiment is None:
        return {}
    found = client.search_runs([experiment.experiment_id])
    # trials, not stages, by their exact key
    return {r.data.tags["ps_ray.trial_key"]: r for r in found if "ps_ray.stage_run" not in r.data.tags}


def _has_experiment(db: Path, name: str) -> bool:
    """Whether the sweep's driver made its store and experiment yet (read only: a test polling a
    running sweep never races the driver to make the tables)."""
    if not db.exists():
        return False
    try:
        with closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as con:
            return con.execute("SELECT 1 FROM experiments WHERE name = ?", (name,)).fetchone() is not None
    except sqlite3.OperationalError:  # tables not made yet, or the driver holds a write lock
        return False


def history(path: Path, run, key: str) -> list[tuple[int, float]]:
    client = mlflow.MlflowClient(f"sqlite:///{sweep_layout(load_sweep(path)).root / 'mlflow.db'}")
    return sorted((m.step, m.value) for m in client.get_metric_history(run.info.run_id, key))


def _interrupt_when_one_trial_finished(path: Path, proc) -> str:
    """Ctrl-C the sweep once one training trial finished and the next is running; its output."""
    deadline = time.time() + 300
    while True:
        status = [r.info.status for k, r in runs(path).items() if not k.startswith("anchors_")]
        if sorted(status) == ["FINISHED", "RUNNING"]:
            break
        assert time.time() < deadline and proc.poll() is None, "no trial finished in time"
        time.sleep(0.5)  # the first finished, the second started
    proc.send_signal(signal.SIGINT)  # what Ctrl-C or `kill -INT` sends the driver
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 130, out[-3000:]
    return out


def test_a_sweep_stopped_by_ctrl_c_resumes_never_unpickling_and_tracks_one_mlflow_run_per_trial(
    tmp_path, cli, tiny_train, planted
):
    """Ctrl-C mid-sweep ends it in one line; `sweep --resume` runs only the unfinished trials and
    loads none of the pickles planted where Tune and RLlib look; the finished sweep has one MLflow
    run per trial, nested under its stage's, with its artifacts and logged model. (A SIGKILL in
    training and the resume after it: tests/test_pipeline.py's fixture.)"""
    distilled = "ps_distilled+consolidate_updates=300"  # of 2,000: enough to align at this size
    methods = ("ps", distilled, "ablation")
    path = write_sweep(tmp_path, "track", tiny_train, methods=methods, seeds=(1,), max_concurrent=1)
    out = _interrupt_when_one_trial_finished(path, cli("sweep", str(path)))
    assert "Traceback" not in out
    assert out.strip().splitlines()[-1] == (
        "ps-ray sweep: interrupted: 1 of 3 training trials finished, 2 not; "
        "the same command with --resume finishes it"
    )
    (last_view,) = [line for line in out.splitlines() if "train: 1 done, 1 interrupted, 0 running" in line]
    assert "0 failed, 1 pending" in last_view  # the live view
    assert not last_view.endswith("ETA 0:00"), last_view  # the interrupted trial's work is left
    ((done_name, done),) = [
        (n, r) for n, r in runs(path).items() if r.info.status == "FINISHED" and "anchors_" not in n
    ]
    done_history = history(path, done, "env_steps")
    # Anyone who can write to shared storage could plant these where Tune and RLlib look.
    folder = sweep_layout(load_sweep(path)).root
    for place in [folder, *folder.glob("tune*"), *folder.glob("tune*/*"), *folder.glob("tune*/*/check*")]:
        if place.is_dir():
            planted(place)

    resumed = cli("sweep", str(path), "--resume")
    out, _ = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, out[-3000:]
    assert "3/3 trials finished" in out
    assert not planted.marker.exists(), "a planted pickle was loaded on resume"
    found = runs(path)
    assert history(path, found[done_name], "env_steps") == done_history  # not rerun
    # one run per trial, the interrupted one's too; the plain source policy of the anchor stage too
    plain = "anchors_plain/plain/panda/reach/1/i8"
    consolidated = f"{distilled}/panda/reach/1/i8"
    assert sorted(found) == ["ablation/panda/reach/1/i8", plain, "ps/panda/reach/1/i8", consolidated]
    assert found[plain].data.tags["ps_ray.stage"] == "anchors_plain"
    # named as a reader tells them apart: env, method, seed, width; no stage prefix
    names = {key: run.info.run_name for key, run in found.items()}
    assert names[plain] == "panda/reach · plain · 1 · i8 · plain policy for the anchor states"
    assert names[consolidated] == f"panda/reach · {distilled} · 1 · i8"
    client = mlflow.MlflowClient(f"sqlite:///{folder / 'mlflow.db'}")
    for run in found.values():  # each nested under its stage's run
        parent = client.get_run(run.data.tags["mlflow.parentRunId"])
        assert parent.data.tags["ps_ray.stage_run"] == run.data.tags["ps_ray.stage"] == parent.info.run_name
    # every run names the device its trial trained on (the default request: one CPU, no GPU)
    on_cpu = {"ps_ray.device": "cpu", "ps_ray.cpus": "1", "ps_ray.gpu_share": "0"}
    assert all({k: r.data.tags.get(k) for k in on_cpu} == on_cpu for r in found.values())
    found.pop(plain)
    for name, run in found.items():
        assert run.info.status == "FINISHED"
        assert run.data.params["method"] == name.split("/")[0]
        assert len(run.data.params) < 40  # our spec, not RLlib's hundreds of config keys
        assert run.data.tags["ps_ray.stage"] == "train"
        assert run.data.tags["mlflow.source.git.commit"] == git_commit()  # MLflow's own source tag
        steps = history(path, run, "env_steps")
        assert steps[-1][1] >= 300
        # every metric is logged at the trial's env steps, the x axis of a training curve
        assert all(step == value for step, value in steps) and len({s for s, _ in steps}) == len(steps)
        artifacts = {a.path for a in client.list_artifacts(run.info.run_id)}
        assert {"policy.safetensors", "signature.json", "spec.json"} <= artifacts
    # each source is a logged MLflow model: loaded by its run's URI, it acts as its policy file does
    run = found["ablation/panda/reach/1/i8"]
    mlflow.set_tracking_uri(f"sqlite:///{folder / 'mlflow.db'}")
    assert run.data.tags["ps_ray.model"] == "panda-reach-ablation-1-i8"  # named as its run: told apart
    model = mlflow.pyfunc.load_model(f"runs:/{run.info.run_id}/{run.data.tags['ps_ray.model']}")
    obs = example_observation("panda", "reach")
    policy = client.download_artifacts(run.info.run_id, "policy.safetensors", str(tmp_path))
    assert np.allclose(model.predict(obs), GreedyPolicy.from_file(policy)(obs), atol=1e-6)
    assert model.metadata.get_input_schema().input_names() == list(obs)  # the env's observation
    ps_artifacts = {a.path for a in client.list_artifacts(found["ps/panda/reach/1/i8"].info.run_id)}
    assert any(a.startswith("anchors_3d") for a in ps_artifacts)
    # a consolidating method's trial consolidates once it is done, before its last checkpoint;
    # ps_distilled's policy there has its relative projection switched on, and says so (an
    # interrupted trial resumes in a Tune folder of its own: the last one that checkpointed)
    tried = [t for t in (folder / "tune").glob("*method_ps_distilled*") if any(t.glob("checkpoint_*"))]
    trial = max(tried, key=lambda t: max(c.stat().st_mtime for c in t.glob("checkpoint_*")))
    last = latest_checkpoint(sorted(trial.glob("checkpoint_*")))
    progress = json.loads((last / "progress.json").read_text())
    assert progress["consolidated"]["gap_after"] < 0.5 * progress["consolidated"]["gap_before"]
    assert json.loads((last / "signature.json").read_text())["projection_off"] is False
    assert load_policy(last / "policy.safetensors")[0].actor.task.projection is not None


# One Tune run through the stages' runner, then Ctrl-C (SIGINT to itself) while the driver does
# other work, as in a report stage after the few-shot stage.
AFTER_TUNE = """
import os, signal, sys, time
from pathlib import Path
import ray
from ray import tune
from ps_ray.pipeline.trials import run_trials
from ps_ray.store.attempts import FINISHED

# Ctrl-C as a terminal's foreground command gets it: a suite started in the background by a shell
# without job control (`cmd &` in a script) passes SIGINT on ignored, and Python keeps it so
signal.signal(signal.SIGINT, signal.default_int_handler)
ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
run_trials(lambda config: tune.report({FINISHED: True}), {"n": [0]}, folder=Path(sys.argv[1]),
           stage="one", callback=tune.Callback(), resume=False, progress=False, max_concurrent=None,
           max_failures=0)
print("SIGINT handler:", signal.getsignal(signal.SIGINT), flush=True)  # who holds it, should one be lost
try:
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(10)
    print("still running after Ctrl-C")
except KeyboardInterrupt:
    print("interrupted")
"""


@pytest.mark.e2e
def test_ctrl_c_after_a_tune_stage_interrupts_the_driver_at_once(tmp_path):
    """Tune leaves its own SIGINT handler set when its run ends, which swallowed the first Ctrl-C
    of a later stage (the report) with Tune's "Stop signal received" and ran on."""
    import subprocess
    import sys

    from tests.processes import own_ray_env

    proc = subprocess.run(
        [sys.executable, "-c", AFTER_TUNE, str(tmp_path / "tune" / "one")],
        capture_output=True,
        text=True,
        timeout=300,
        env=own_ray_env(),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().splitlines()[-1] == "interrupted", proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "Stop signal received" not in proc.stdout + proc.stderr


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
    path = write_sweep(tmp_path, "crash", {**tiny_train, "env_steps": 1500}, seeds=(1,))
    tag = f"PS_RAY_TEST_RUN={tmp_path.name}"
    proc = cli("sweep", str(path), env={"PS_RAY_TEST_RUN": tmp_path.name}, own_ray=True)
    tune_dir = sweep_layout(load_sweep(path)).root / "tune"
    deadline = time.time() + 300
    while not _reported_checkpoint(tune_dir):
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
    assert points[-1][1] >= 1500
    iterations, steps = [i for i, _ in points], [v for _, v in points]
    assert len(set(iterations)) == len(iterations)  # MLflow holds each step once
    assert steps == sorted(set(steps))
    # The retry was restored from the checkpoint saved before the crash, not started over: the
    # trial's results hold iteration 1 once.
    (trial_dir,) = tune_dir.glob("*/params.json")
    rows = _rows(trial_dir.parent)
    assert [r["training_iteration"] for r in rows].count(1) == 1
    # ... and its rows say what it restored (the live view's ETA counts only the steps it ran)
    starts = sorted({r[START_STEPS] for r in rows})
    assert starts[0] == 0 and len(starts) == 2 and 0 < starts[1] < 1500, starts


@pytest.mark.parametrize("entry", ["sweep", "sweep --resume", "run"])
def test_a_sweep_with_other_training_settings_is_refused_before_anything_runs(tmp_path, entry):
    from ps_ray.pipeline.run import run_pipeline
    from ps_ray.pipeline.stage import require_same_sweep
    from ps_ray.pipeline.sweep import run_sweep
    from ps_ray.specs.train import SpecError
    from ps_ray.store.layout import SweepLayout

    trained = load_sweep(write_sweep(tmp_path, "same", {"env_steps": 400}))
    root = sweep_layout(trained).root
    root.mkdir(parents=True)
    SweepLayout(root).spec_file.write_text(yaml.safe_dump(trained.to_dict()))
    other = load_sweep(write_sweep(tmp_path, "same", {"env_steps": 400, "hidden": 32}, seeds=(1, 3)))
    require_same_sweep(other)  # only the spec of a start that failed early: the new one may start
    SweepLayout(root).anchors.mkdir()
    (SweepLayout(root).anchors / "anchors_3d_k8.npz").write_bytes(b"")  # work done under the spec
    before = sorted(p.name for p in root.iterdir())
    refused = r"trained from a different sweep spec \(changed: seeds, train\); resume"
    with pytest.raises(SpecError, match=refused):
        if entry == "run":
            run_pipeline(other, progress=False)
        else:
            run_sweep(other, resume=entry.endswith("--resume"), progress=False)
    assert sorted(p.name for p in root.iterdir()) == before  # nothing written, no Ray started
    assert yaml.safe_load(SweepLayout(root).spec_file.read_text()) == trained.to_dict()


def _reported_checkpoint(tune_dir: Path) -> bool:
    """Whether Tune holds a sealed checkpoint, not only the disk: the worker writes checkpoint_N
    before it reports it, so a kill between the two leaves Tune nothing to restore from (under
    load that window is wide enough to hit). A result row naming the checkpoint means the driver
    has it."""
    sealed = latest_checkpoint(list(tune_dir.glob("*/checkpoint_*")))
    if sealed is None:
        return False
    return any(row.get("checkpoint_dir_name") == sealed.name for row in _rows(sealed.parent))


def _rows(trial_dir: Path) -> list[dict]:
    import json

    path = trial_dir / "result.json"
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip().endswith("}")]


@pytest.mark.slow
def test_a_killed_worker_node_s_trial_resumes_from_its_checkpoint_on_another_node(
    tmp_path, tiny_train, two_node_cluster
):
    """Two trials spread over two nodes; the worker node dies mid-sweep (its raylet and every
    process on it killed): Tune retries its trial from the last sealed checkpoint on the node that
    is left, and the sweep completes."""
    import threading

    from ps_ray.pipeline.sweep import run_sweep

    path = write_sweep(tmp_path, "nodekill", {**tiny_train, "env_steps": 1500}, seeds=(1, 2))
    spec = load_sweep(path)
    cluster = two_node_cluster
    worker = cluster.list_all_nodes()[1]  # [head, worker]
    tune_dir = sweep_layout(spec).root / "tune"
    killed: dict[str, object] = {}

    def kill_the_worker_once_its_trial_has_a_checkpoint():
        deadline = time.time() + 300
        while time.time() < deadline:
            for trial_dir in tune_dir.glob("*"):
                rows = _rows(trial_dir)
                on_worker = rows and rows[-1].get("node_id") == worker.node_id
                if on_worker and latest_checkpoint(list(trial_dir.glob("checkpoint_*"))) is not None:
                    nodes = {r[-1]["node_id"] for r in map(_rows, tune_dir.glob("*")) if r}
                    killed.update(trial=trial_dir.name, env_steps=rows[-1]["env_steps"], nodes=nodes)
                    cluster.remove_node(worker, allow_graceful=False)
                    return
            time.sleep(0.2)

    killer = threading.Thread(target=kill_the_worker_once_its_trial_has_a_checkpoint)
    killer.start()
    results = run_sweep(spec, progress=False)
    killer.join()
    assert killed, "no trial ran on the worker node long enough to checkpoint"
    assert len(killed["nodes"]) == 2, killed  # the two trials ran at once, one on each node
    assert killed["env_steps"] < 1500  # killed mid-training
    assert not any(r.error for r in results)
    assert all(r.metrics["env_steps"] >= 1500 for r in results)
    retried = [r for r in results if Path(r.path).name == killed["trial"]]
    assert retried and retried[0].metrics["node_id"] != worker.node_id  # finished on the head
    from ps_ray.specs.train import TrainSpec

    run = runs(path)[TrainSpec.from_mapping(retried[0].config["trial"]["spec"]).label()]
    steps = [v for _, v in history(path, run, "env_steps")]
    # restored from its checkpoint, not from zero: no env step is reported twice
    assert steps == sorted(set(steps)) and steps[-1] >= 1500


@pytest.mark.parametrize("stage", ["train", "zero_shot", "few_shot"])
def test_a_stage_run_afresh_on_a_folder_with_earlier_attempts_is_refused_before_writing(tmp_path, stage):
    """Without --resume, a stage whose Tune folder holds attempts is refused in one line naming
    --resume, before Ray starts or anything (stitched starts, sweep.yaml) is written."""
    import json

    from ps_ray.pipeline.few_shot import run_few_shot
    from ps_ray.pipeline.zero_shot import run_zero_shot
    from ps_ray.store.attempts import PARAMS_FILE, StageExistsError

    spec = load_sweep(write_sweep(tmp_path, "again", {"env_steps": 400}))
    layout = sweep_layout(spec)
    folder, key = {
        "train": (layout.tune_train, "trial"),
        "zero_shot": (layout.tune_zero_shot, "batch"),
        "few_shot": (layout.tune_few_shot, "trial"),
    }[stage]
    attempt = folder / "attempt_0"
    attempt.mkdir(parents=True)
    (attempt / PARAMS_FILE).write_text(json.dumps({key: {"earlier": True}}))
    layout.spec_file.write_text(yaml.safe_dump(spec.to_dict()))
    before = sorted(p.relative_to(layout.root) for p in layout.root.rglob("*"))
    run = {
        "train": lambda: __import__("ps_ray.pipeline.sweep", fromlist=["run_sweep"]).run_sweep(
            spec, progress=False
        ),
        "zero_shot": lambda: run_zero_shot(spec, progress=False),
        "few_shot": lambda: run_few_shot(spec, progress=False),
    }[stage]
    with pytest.raises(StageExistsError, match=f"holds an earlier run of stage '{stage}'; pass --resume"):
        run()
    assert sorted(p.relative_to(layout.root) for p in layout.root.rglob("*")) == before
