"""ps_ray.store.tracking against a real sqlite MLflow store and a real (local) Tune."""

from __future__ import annotations

import os
import pickle
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import urlparse

import pytest
from mlflow import MlflowClient
from mlflow.entities import ViewType

from ps_ray.pipeline.tune_tracking import (
    MLflowTuneCallback,
    lookup,
)
from ps_ray.specs.names import trial_key
from ps_ray.store.mlflow_values import flatten_params, relative_paths
from ps_ray.store.stage_run import open_stage
from ps_ray.store.tracking import (
    NOTE_TAG,
    PARENT_TAG,
    TRIAL_KEY_TAG,
    TrialTracker,
    check_tracking_uri,
    default_tracking_uri,
    ensure_experiment,
    git_commit,
    runs_page,
)
from tests.processes import wait_until_serving


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> dict:
    """One sqlite store for the module (creating one costs about 5 s of migrations)."""
    root = tmp_path_factory.mktemp("mlflow")
    uri = default_tracking_uri(root)
    existed = (root / "mlflow.db").exists()
    exp_id = ensure_experiment(uri, "tracking-tests", root / "artifacts")
    return {
        "root": root,
        "uri": uri,
        "existed": existed,
        "exp_id": exp_id,
        "client": MlflowClient(tracking_uri=uri),
    }


def runs_of(store: dict, exp_id: str) -> list:
    return store["client"].search_runs([exp_id], run_view_type=ViewType.ALL, max_results=1000)


def new_experiment(store: dict, name: str) -> str:
    return ensure_experiment(store["uri"], name, store["root"] / f"artifacts-{name}")


def artifact_dir(store: dict, run_id: str) -> Path:
    return Path(urlparse(store["client"].get_run(run_id).info.artifact_uri).path)


# ------------------------------------------------------------------------- store


@pytest.mark.e2e
def test_ensure_experiment_creates_store_and_is_idempotent(store):
    root = store["root"]
    assert store["uri"] == f"sqlite:///{root.resolve()}/mlflow.db"
    assert not store["existed"] and (root / "mlflow.db").is_file()
    assert ensure_experiment(store["uri"], "tracking-tests", root / "artifacts") == store["exp_id"]
    experiment = store["client"].get_experiment(store["exp_id"])
    assert experiment.name == "tracking-tests"
    assert experiment.artifact_location == (root / "artifacts").resolve().as_uri()
    assert [e.name for e in store["client"].search_experiments()].count("tracking-tests") == 1
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"
    page = f"http://127.0.0.1:5000/#/experiments/{store['exp_id']}?workflowType=machine_learning"
    assert runs_page(store["uri"], "tracking-tests") == page  # the UI's runs, not its GenAI overview
    assert runs_page(store["uri"], "no-such-experiment") is None
    # an experiment made before the tag gets it when it is opened again
    store["client"].delete_experiment_tag(store["exp_id"], "mlflow.experimentKind")
    ensure_experiment(store["uri"], "tracking-tests", root / "artifacts")
    again = store["client"].get_experiment(store["exp_id"])
    assert again.tags["mlflow.experimentKind"] == "custom_model_development"


def test_ensure_experiment_errors_are_one_line(store, tmp_path):
    with pytest.raises(ValueError, match="keeps artifacts in"):
        ensure_experiment(store["uri"], "tracking-tests", tmp_path / "elsewhere")
    blocker = tmp_path / "file"
    blocker.write_text("")
    bad_uri = f"sqlite:///{blocker}/sub/mlflow.db"
    with pytest.raises(ValueError, match=f"cannot use MLflow tracking URI '{bad_uri}'") as info:
        ensure_experiment(bad_uri, "x", tmp_path)
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="'bogus://nowhere'"):
        ensure_experiment("bogus://nowhere", "x", tmp_path)
    foreign = tmp_path / "foreign.db"
    foreign.write_bytes(b"not a sqlite file, " * 100)
    with pytest.raises(ValueError, match=f"cannot use MLflow tracking URI 'sqlite:///{foreign}'") as info:
        ensure_experiment(f"sqlite:///{foreign}", "x", tmp_path)
    assert "\n" not in str(info.value)


@pytest.mark.e2e
@pytest.mark.slow
def test_a_tracking_server_as_docs_cluster_md_starts_it_takes_a_sweeps_runs(tmp_path):
    """`mlflow server` on 127.0.0.1 over a sqlite store (docs/cluster.md): an http URI passes the
    check, and a run logged through it keeps its artifacts in the sweep folder."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    server = subprocess.Popen(
        [
            str(Path(sys.executable).with_name("mlflow")),
            "server",
            *("--backend-store-uri", f"sqlite:///{tmp_path / 'server' / 'mlflow.db'}"),
            *("--artifacts-destination", str(tmp_path / "server" / "artifacts")),
            *("--host", "127.0.0.1", "--port", str(port)),
            *("--workers", "1"),  # the docs' head serves many readers; one test needs one worker
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        uri = f"http://127.0.0.1:{port}"
        wait_until_serving(uri, server, "mlflow server")
        check_tracking_uri(uri)  # accepted, no error
        sweep = tmp_path / "storage" / "big"
        exp_id = ensure_experiment(uri, "big", sweep / "mlartifacts")
        tracker = TrialTracker(
            uri, exp_id, "ps/panda/push/1", params={"seed": 1}, tags={"ps_ray.device": "cuda"}
        )
        policy = tmp_path / "policy.safetensors"
        policy.write_bytes(b"weights")
        tracker.log_artifact(policy)
        tracker.close("FINISHED")
        (run,) = MlflowClient(uri).search_runs([exp_id])
        assert run.data.tags["ps_ray.device"] == "cuda" and run.info.status == "FINISHED"
        stored = sweep / "mlartifacts" / run.info.run_id / "artifacts" / "policy.safetensors"
        assert stored.read_bytes() == b"weights"  # in the sweep folder, not the server's destination
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:  # its workers shut down slowly on a loaded machine
            os.killpg(server.pid, signal.SIGKILL)
            server.wait(timeout=30)


def test_git_commit(tmp_path):
    # the tests run from a git checkout (CI clones the repo): the source tree's HEAD is recorded
    repo = Path(__file__).resolve().parents[1]
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True, check=True)
    assert git_commit() == head.stdout.strip() and len(git_commit()) == 40
    assert git_commit(tmp_path) is None  # not a repository


# ------------------------------------------------------------------------- TrialTracker


PARAMS = {
    "method": "ps",
    "robot": {"name": "panda", "locked_joints": [1]},
    "task": "reach",
    "seed": 101,
    "interface_dim": 128,
}
FLAT = {
    "method": "ps",
    "robot.name": "panda",
    "robot.locked_joints": "[1]",
    "task": "reach",
    "seed": "101",
    "interface_dim": "128",
}


def test_a_run_is_named_as_a_reader_writes_its_key_and_found_by_the_exact_key(store):
    exp = new_experiment(store, "tracker-names")
    key = 'zero_shot/ps/t: reach{"goal_region":"q3"}-panda_l3 & r: reach{"goal_region":"q1"}-panda/102'
    tracker = TrialTracker(store["uri"], exp, key, params={}, tags={})
    run = store["client"].get_run(tracker.run_id)
    assert run.info.run_name == "zero_shot/ps/t: reach q3-panda_l3 & r: reach q1-panda/102"
    assert run.data.tags[TRIAL_KEY_TAG] == key
    assert TrialTracker(store["uri"], exp, key, params={}, tags={}).run_id == tracker.run_id  # resumed


def test_a_sweeps_experiment_carries_its_description_and_its_store_no_empty_default(tmp_path):
    uri = default_tracking_uri(tmp_path)
    exp = ensure_experiment(uri, "s", tmp_path / "artifacts", "What the sweep is for.")
    client = MlflowClient(uri)
    assert [e.name for e in client.search_experiments()] == ["s"]  # MLflow's empty Default is gone
    assert client.get_experiment(exp).tags[NOTE_TAG] == "What the sweep is for."  # the UI's description
    assert ensure_experiment(uri, "s", tmp_path / "artifacts", "Reworded.") == exp
    assert client.get_experiment(exp).tags[NOTE_TAG] == "Reworded."


def test_a_run_takes_its_records_title_and_a_run_named_before_is_renamed_on_resume(store):
    exp = new_experiment(store, "tracker-titles")
    key = "ablation/panda_far/reach_blue/431"
    old = TrialTracker(store["uri"], exp, key, params={}, tags={})  # the old scheme: its key
    assert store["client"].get_run(old.run_id).info.run_name == key
    title = "panda_far/reach_blue · ablation · 431"
    again = TrialTracker(store["uri"], exp, key, params={}, tags={}, name=title)
    assert again.run_id == old.run_id and store["client"].get_run(old.run_id).info.run_name == title


def test_tracker_params_tags_and_batched_metrics(store):
    exp = new_experiment(store, "tracker-basic")
    tracker = TrialTracker(
        store["uri"],
        exp,
        "ps/panda/reach/101",
        params=PARAMS,
        tags={"ps_ray.stage": "train", "git_commit": "abc123"},
    )
    run = store["client"].get_run(tracker.run_id)
    assert run.data.params == FLAT
    assert run.info.run_name == "ps/panda/reach/101" and run.info.status == "RUNNING"
    assert run.data.tags[TRIAL_KEY_TAG] == "ps/panda/reach/101"
    assert run.data.tags["ps_ray.stage"] == "train" and run.data.tags["git_commit"] == "abc123"

    for step in range(3):
        tracker.log_metrics(
            {
                "return": step * 1.5,
                "success": step / 2,
                "none": None,
                "nan": float("nan"),
                "inf": float("inf"),
            },
            step=step * 10,
        )
    assert tracker.pending == 6
    assert store["client"].get_metric_history(tracker.run_id, "return") == []  # buffered
    tracker.flush()
    history = store["client"].get_metric_history(tracker.run_id, "return")
    assert [(m.step, m.value) for m in history] == [(0, 0.0), (10, 1.5), (20, 3.0)]
    assert set(store["client"].get_run(tracker.run_id).data.metrics) == {"return", "success"}

    # a translated stitch's label and a method's options in a name: MLflow allows neither "+", "@"
    # nor "=", nor a task variant's braces and quotes
    tracker.log_metrics({"zero_shot.ps_distilled+anchors@outcome.success": 0.5}, step=0)
    tracker.log_metrics({"transfer.ps_distilled+consolidate_pull=0 co-trained.gain": 0.25}, step=0)
    tracker.log_metrics({'few_shot.reach{"goal_region":"q1"}.success': 0.75}, step=0)
    tracker.flush()
    metrics = store["client"].get_run(tracker.run_id).data.metrics
    assert metrics["zero_shot.ps_distilled-anchors:outcome.success"] == 0.5
    assert metrics["transfer.ps_distilled-consolidate_pull_0 co-trained.gain"] == 0.25
    assert metrics["few_shot.reach__goal_region_:_q1__.success"] == 0.75

    for step in range(2500):  # more than one log_batch call (1000 metrics each)
        tracker.log_metrics({"big": float(step)}, step=step)
    tracker.close()
    assert len(store["client"].get_metric_history(tracker.run_id, "big")) == 2500
    assert store["client"].get_run(tracker.run_id).info.status == "FINISHED"


def test_a_stages_runs_are_children_of_one_stage_run_that_lasts_the_stage_and_holds_its_summary(store):
    exp_id = new_experiment(store, "stages")
    with open_stage(store["uri"], exp_id, "sweep1", "train") as train:
        assert store["client"].get_run(train.run_id).info.status == "RUNNING"  # while the stage runs
        time.sleep(0.3)
        TrialTracker(store["uri"], exp_id, "ps/panda/reach/1", params={}, tags=train.tags).close()
        train.record({"trials": 1, "mean_final_success": 0.75, "nan": float("nan")})
    with pytest.raises(KeyboardInterrupt), open_stage(store["uri"], exp_id, "sweep1", "few_shot") as few_shot:
        TrialTracker(store["uri"], exp_id, "few_shot/ps/panda/reach/1", params={}, tags=few_shot.tags).close()
        raise KeyboardInterrupt  # Ctrl-C during the stage
    assert few_shot.run_id != train.run_id
    runs = {r.info.run_name: r for r in runs_of(store, exp_id)}
    assert sorted(runs) == ["few_shot", "few_shot/ps/panda/reach/1", "ps/panda/reach/1", "train"]
    for parent, child in (("train", "ps/panda/reach/1"), ("few_shot", "few_shot/ps/panda/reach/1")):
        assert runs[child].data.tags[PARENT_TAG] == runs[parent].info.run_id
        assert (
            runs[child].data.tags["ps_ray.stage"] == parent
            and runs[child].data.tags["ps_ray.sweep"] == "sweep1"
        )
        # the stage run is not a trial: counted by no stage, indexed by no report
        assert "ps_ray.stage" not in runs[parent].data.tags and TRIAL_KEY_TAG not in runs[parent].data.tags
    stage = runs["train"].info
    assert stage.status == "FINISHED" and stage.end_time - stage.start_time >= 300  # as long as the stage
    assert runs["train"].data.metrics == {"trials": 1.0, "mean_final_success": 0.75}
    assert runs["few_shot"].info.status == "KILLED"
    with open_stage(store["uri"], exp_id, "sweep1", "few_shot") as again:  # a resume: the same run, open
        assert again.run_id == few_shot.run_id
        assert store["client"].get_run(again.run_id).info.status == "RUNNING"
    assert store["client"].get_run(again.run_id).info.status == "FINISHED"


def test_start_files_are_logged_relative_to_the_sweep_and_old_absolute_runs_still_resume(store, tmp_path):
    root = tmp_path / "sweeps" / "s"
    start = root / "stitched" / "ab.safetensors"
    elsewhere = tmp_path / "anchors.npz"
    params = {"init_policy": str(start), "anchors": str(elsewhere), "lr": "0.001"}
    assert relative_paths(params, root) == {
        "init_policy": "stitched/ab.safetensors",  # inside the sweep folder: relative
        "anchors": str(elsewhere),  # a file outside it stays as given
        "lr": "0.001",
    }
    exp_id = new_experiment(store, "paths")
    TrialTracker(store["uri"], exp_id, "few_shot/x", params=params, tags={}).close()  # an older run
    again = TrialTracker(store["uri"], exp_id, "few_shot/x", params=relative_paths(params, root), tags={})
    assert again.resumed and store["client"].get_run(again.run_id).data.params["init_policy"] == str(start)
    with pytest.raises(ValueError, match="param init_policy="):
        TrialTracker(store["uri"], exp_id, "few_shot/x", params={"init_policy": "other.safetensors"}, tags={})


def test_tracker_resume_reuses_run_and_keys_separate_runs(store):
    exp = new_experiment(store, "tracker-resume")
    first = TrialTracker(store["uri"], exp, "ps/panda/reach/1", params=PARAMS, tags={})
    first.log_metrics({"return": 1.0}, step=1)
    first.close("KILLED")

    again = TrialTracker(store["uri"], exp, "ps/panda/reach/1", params=PARAMS, tags={"git_commit": "new"})
    assert again.run_id == first.run_id and again.resumed
    run = store["client"].get_run(again.run_id)
    assert run.info.status == "RUNNING" and run.data.tags["git_commit"] == "new"
    again.log_metrics({"return": 2.0}, step=2)
    again.close()
    history = store["client"].get_metric_history(again.run_id, "return")
    assert [(m.step, m.value) for m in history] == [(1, 1.0), (2, 2.0)]

    other = TrialTracker(store["uri"], exp, "ps/panda/reach/2", params=PARAMS, tags={})
    assert other.run_id != first.run_id and not other.resumed
    other.close()
    assert len(runs_of(store, exp)) == 2
    with pytest.raises(ValueError, match="already has run .* param seed='101', not '7'"):
        TrialTracker(store["uri"], exp, "ps/panda/reach/1", params={**PARAMS, "seed": 7}, tags={})


def test_a_restarted_trial_never_logs_a_step_twice(store):
    """A trial killed after logging steps 1-3 and restarted from its checkpoint at step 1
    re-reports steps 2 and 3: the run keeps their first record and goes on from step 4."""
    exp = new_experiment(store, "tracker-restart")
    first = TrialTracker(store["uri"], exp, "t", params={}, tags={}, once_per_step=True)
    for step in (1, 2, 3):
        first.log_metrics({"success": step / 10}, step=step)
    first.flush()  # then the kill: no close
    again = TrialTracker(store["uri"], exp, "t", params={}, tags={}, once_per_step=True)
    for step in (2, 3, 4):
        again.log_metrics({"success": step}, step=step)
    again.close()
    history = store["client"].get_metric_history(again.run_id, "success")
    assert sorted((m.step, m.value) for m in history) == [(1, 0.1), (2, 0.2), (3, 0.3), (4, 4.0)]


def test_tracker_artifacts(store, tmp_path):
    exp = new_experiment(store, "tracker-artifacts")
    tracker = TrialTracker(store["uri"], exp, "k", params={}, tags={})
    (tmp_path / "metrics.csv").write_text("a,b\n1,2\n")
    policy = tmp_path / "policy"
    policy.mkdir()
    (policy / "weights.safetensors").write_bytes(b"\0" * 16)
    tracker.log_artifact(tmp_path / "metrics.csv")
    tracker.log_artifact(policy)
    tracker.log_artifact(tmp_path / "metrics.csv", artifact_path="logs")
    tracker.log_dict({"spec": {"seed": 1}}, "config/resolved.json")
    with pytest.raises(FileNotFoundError, match="no artifact to log at"):
        tracker.log_artifact(tmp_path / "missing")
    tracker.close()
    root = artifact_dir(store, tracker.run_id)
    assert root.is_relative_to((store["root"] / "artifacts-tracker-artifacts").resolve())
    files = sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())
    assert files == ["config/resolved.json", "logs/metrics.csv", "metrics.csv", "policy/weights.safetensors"]


def test_spec_key_and_lookup():
    assert trial_key({"method": "ps", "robot": "panda", "task": "reach", "seed": 3}) == "ps/panda/reach/3"
    assert (
        trial_key({"method": "ps", "robot": {"name": "panda"}, "task": "push", "seed": 3})
        == "ps/panda/push/3"
    )
    locked = trial_key(
        {"method": "ps", "robot": {"name": "panda", "locked_joints": [1]}, "task": "reach", "seed": 3}
    )
    assert locked == 'ps/panda{"locked_joints":[1]}/reach/3'
    long = trial_key({"method": "ps", "robot": {"name": "panda", "x": "y" * 100}, "task": "reach", "seed": 3})
    assert long.startswith("ps/panda#") and len(long) < 40
    result = {"a": {"b": 1}, "c/d": 2, "e": 3}
    assert lookup(result, "a/b") == 1 and lookup(result, "c/d") == 2 and lookup(result, "e") == 3
    assert lookup(result, "a/zz") is None and lookup(result, "zz") is None


# ------------------------------------------------------------------------- Tune


def _spec_key(trial) -> str:
    return trial_key(trial.config["spec"])


def _spec_params(trial) -> dict[str, str]:
    return flatten_params(trial.config["spec"])


def _trainable(config):
    from ray import tune

    spec = config["spec"]
    marker = Path(config["marker"])
    for i in range(1, 4):
        tune.report({"score": i * spec["seed"], "eval": {"success": i / 3, "skipped": 1}, "junk": 7})
        if spec["seed"] == 2 and i == 2 and not marker.exists():
            marker.write_text("failed once")
            raise RuntimeError("planned failure")
    (marker.parent / f"summary-{spec['seed']}.txt").write_text("done")


def _summary_file(trial) -> list[Path]:
    return [Path(trial.config["marker"]).parent / f"summary-{trial.config['spec']['seed']}.txt"]


def _tuner(tmp_path: Path, callback: MLflowTuneCallback, name: str):
    from ray import tune

    space = {
        "spec": {"method": "ps", "robot": "panda", "task": "reach", "seed": tune.grid_search([1, 2])},
        "marker": str(tmp_path / f"{name}.marker"),
    }
    return tune.Tuner(
        _trainable,
        param_space=space,
        tune_config=tune.TuneConfig(max_concurrent_trials=2),
        run_config=tune.RunConfig(
            name=name, storage_path=str(tmp_path / "tune"), callbacks=[callback], verbose=0
        ),
    )


def test_tune_callback_one_run_per_trial_across_restore_and_rerun(store, tmp_path, ray_local):
    from ray import cloudpickle, tune

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import tests/

    exp = new_experiment(store, "tune")
    callback = MLflowTuneCallback(
        store["uri"],
        exp,
        metric_keys=["score", "eval/success", "absent"],
        key_fn=_spec_key,
        params_fn=_spec_params,
        tags={"ps_ray.stage": "train"},
        flush_every=2,
        artifacts_fn=_summary_file,
    )
    pickle.loads(pickle.dumps(callback))  # Tuner.restore unpickles it from the experiment state
    grid = _tuner(tmp_path, callback, "sweep").fit()
    assert sorted(r.error is not None for r in grid) == [False, True]

    def by_key() -> dict:
        runs = runs_of(store, exp)
        keys = [r.data.tags[TRIAL_KEY_TAG] for r in runs]
        assert len(keys) == len(set(keys)), f"more than one run per trial key: {keys}"
        return {r.data.tags[TRIAL_KEY_TAG]: r for r in runs}

    runs = by_key()
    assert set(runs) == {"ps/panda/reach/1", "ps/panda/reach/2"}
    ok, failed = runs["ps/panda/reach/1"], runs["ps/panda/reach/2"]
    assert ok.info.status == "FINISHED" and failed.info.status == "FAILED"
    assert ok.data.params == {"method": "ps", "robot": "panda", "task": "reach", "seed": "1"}
    assert set(ok.data.metrics) == {"score", "eval/success"}
    assert ok.data.tags["ps_ray.stage"] == "train"
    history = store["client"].get_metric_history(ok.info.run_id, "score")
    assert [(m.step, m.value) for m in history] == [(1, 1.0), (2, 2.0), (3, 3.0)]
    assert [m.step for m in store["client"].get_metric_history(failed.info.run_id, "score")] == [1, 2]
    assert (artifact_dir(store, ok.info.run_id) / "summary-1.txt").is_file()

    # driver restart: a new driver-side callback object (unpickled), the errored trial resumes
    path = str(tmp_path / "tune" / "sweep")
    assert tune.Tuner.can_restore(path)
    grid = tune.Tuner.restore(path, trainable=_trainable, resume_errored=True).fit()
    assert not grid.errors
    runs = by_key()
    resumed = runs["ps/panda/reach/2"]
    assert resumed.info.run_id == failed.info.run_id and resumed.info.status == "FINISHED"
    steps = [m.step for m in store["client"].get_metric_history(resumed.info.run_id, "score")]
    assert steps == [1, 2, 1, 2, 3]  # no checkpoint: the trial restarted at iteration 1

    # a second sweep with the same keys continues the same runs
    _tuner(tmp_path, callback, "sweep-again").fit()
    runs = by_key()
    assert {k: r.info.run_id for k, r in runs.items()} == {
        "ps/panda/reach/1": ok.info.run_id,
        "ps/panda/reach/2": failed.info.run_id,
    }
    assert len(store["client"].get_metric_history(ok.info.run_id, "score")) == 6


def test_a_checkpoint_flushes_the_trials_metrics(store):
    """A driver killed after a checkpoint must not lose the results before it: the resumed trial
    re-reports only the steps after the checkpoint. So a checkpoint writes what is buffered, even
    when neither flush_every nor flush_secs is due."""
    from ray.tune.experiment import Trial

    exp = new_experiment(store, "checkpoint-flush")
    callback = MLflowTuneCallback(
        store["uri"],
        exp,
        metric_keys=["score"],
        key_fn=_spec_key,
        params_fn=_spec_params,
        flush_every=1000,
        flush_secs=1e9,
        step_key="iteration",
    )
    trial = Trial(
        "__fake", config={"spec": {"method": "ps", "robot": "panda", "task": "reach", "seed": 9}}, stub=True
    )
    for i in (1, 2, 3):
        callback.on_trial_result(0, [trial], trial, {"iteration": i, "score": float(i)})
    run_id = callback.run_id(trial)
    assert store["client"].get_metric_history(run_id, "score") == []  # buffered, not due
    callback.on_checkpoint(0, [trial], trial, checkpoint=None)
    history = store["client"].get_metric_history(run_id, "score")
    assert [(m.step, m.value) for m in history] == [(1, 1.0), (2, 2.0), (3, 3.0)]


def test_a_populations_members_each_get_a_run_of_their_own_that_ends_at_their_stop(store):
    """Each member of a population trial logs its own columns (``eval_c01_success`` as
    ``eval_success``) into a run of its own, nested under the trial's; a member that stopped logs
    nothing more but its final figures, at the step it stopped."""
    from ray.tune.experiment import Trial

    from ps_ray.pipeline.tune_tracking import MemberRun

    exp = new_experiment(store, "population")
    keys = ["ablation/panda/reach/1", "ablation/panda/reach/2"]
    members = [
        MemberRun(key=k, name=f"member {k}", params={"seed": k[-1]}, prefix=f"c0{i}_")
        for i, k in enumerate(keys)
    ]
    callback = MLflowTuneCallback(
        store["uri"],
        exp,
        metric_keys=["env_steps", "eval_success", "best_eval_success", "final_success"],
        key_fn=lambda trial: "population/ablation/2xabc",
        params_fn=lambda trial: {},
        step_key="env_steps",
        once_per_step=True,
        members_fn=lambda trial: members,
    )
    trial = Trial("__fake", config={}, stub=True)
    # member 2 stops at 100 env steps: its columns leave the rows, its final figures come last
    rows = [
        {"env_steps": 100, "eval_success": 0.2, "best_eval_success": 0.2},
        {"env_steps": 200, "eval_success": 0.5, "best_eval_success": 0.5},
        {"env_steps": 300, "eval_success": 0.95, "best_eval_success": 0.95, "final_success": 0.85},
    ]
    rows[0].update(eval_c00_success=0.2, eval_c01_success=0.9)
    rows[1].update(eval_c00_success=0.5)
    rows[2].update(eval_c00_success=0.95, final_c00_success=0.9, final_c00_env_steps=300)
    rows[2].update(final_c01_success=0.85, final_c01_env_steps=100)
    for row in rows:
        callback.on_trial_result(0, [trial], trial, row)
    callback.on_trial_complete(0, [trial], trial)
    runs = {r.data.tags[TRIAL_KEY_TAG]: r for r in runs_of(store, exp)}
    parent = runs.pop("population/ablation/2xabc")
    assert set(runs) == set(keys) and {r.data.tags[PARENT_TAG] for r in runs.values()} == {parent.info.run_id}

    def history(key: str, metric: str) -> list:
        return [(m.step, m.value) for m in store["client"].get_metric_history(runs[key].info.run_id, metric)]

    assert history(keys[0], "eval_success") == [(100, 0.2), (200, 0.5), (300, 0.95)]
    assert history(keys[0], "final_success") == [(300, 0.9)]
    assert history(keys[1], "eval_success") == [(100, 0.9)] and history(keys[1], "final_success") == [
        (100, 0.85)
    ]
    assert history(keys[1], "env_steps") == [(100, 100.0)]
    assert "best_eval_success" not in runs[keys[0]].data.metrics  # the trial's, not a member's
    assert runs[keys[1]].info.run_name == f"member {keys[1]}" and runs[keys[1]].info.status == "FINISHED"


ENSURE_WHEN_TOLD = """
import sys, time
from pathlib import Path
from ps_ray.store.tracking import ensure_experiment
go = Path(sys.argv[2])
Path(sys.argv[4]).touch()  # imported, ready
while not go.exists():
    time.sleep(0.01)
print(ensure_experiment(sys.argv[1], "shared", Path(sys.argv[3])))
"""


@pytest.mark.e2e
def test_processes_that_open_a_new_store_at_once_all_get_its_one_experiment(tmp_path):
    """A sweep's driver and an analyst's `mlflow ui` or script may make the same sqlite store at
    the same moment: each gets the one experiment, none an error."""
    uri = f"sqlite:///{tmp_path / 'store' / 'mlflow.db'}"
    go = tmp_path / "go"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", ENSURE_WHEN_TOLD, uri, str(go), str(tmp_path / "artifacts"), str(ready)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for ready in (tmp_path / f"ready{i}" for i in range(4))
    ]
    deadline = time.time() + 120
    while not all((tmp_path / f"ready{i}").exists() for i in range(4)) and time.time() < deadline:
        time.sleep(0.1)
    go.touch()  # all four make the store at once
    outs = [p.communicate(timeout=120) for p in procs]
    assert [p.returncode for p in procs] == [0] * 4, [err[-800:] for _, err in outs]
    (experiment,) = MlflowClient(uri).search_experiments(filter_string="name = 'shared'")
    assert {out.strip().splitlines()[-1] for out, _ in outs} == {experiment.experiment_id}


def test_a_row_run_lasts_its_rows_work_and_keeps_its_files_but_a_killed_writers_temp_file(store, tmp_path):
    from ray.tune.experiment import Trial

    from ps_ray.pipeline.tune_tracking import ROW_ENDED, ROW_STARTED, RowRunsCallback

    exp = new_experiment(store, "rows")
    folder = tmp_path / "pair"
    folder.mkdir()
    for name in ("stitched.safetensors", "episodes.csv", ".episodes.csv.x1.tmp"):
        (folder / name).write_text("x")
    callback = RowRunsCallback(
        store["uri"],
        exp,
        row_key="pair_key",
        metric_keys=["success_mean"],
        params_fn=lambda key: {},
        tags={},
        name_fn=lambda key: f"title of {key}",
        artifacts_key="pair_files",
    )
    trial = Trial("__fake", config={}, stub=True)
    row = {"pair_key": "p1", "success_mean": 0.5, "pair_files": str(folder), ROW_STARTED: 1000.0}
    callback.on_trial_result(0, [trial], trial, {**row, ROW_ENDED: 1003.25, "timestamp": 1003})
    (run,) = [r for r in runs_of(store, exp) if r.data.tags.get(TRIAL_KEY_TAG) == "p1"]
    assert run.info.run_name == "title of p1" and run.data.metrics == {"success_mean": 0.5}
    assert (run.info.start_time, run.info.end_time) == (1_000_000, 1_003_250)
    artifacts = {a.path for a in store["client"].list_artifacts(run.info.run_id)}
    assert artifacts == {"stitched.safetensors", "episodes.csv"}  # not the dead writer's temp file


def test_a_models_name_is_its_runs_title_in_the_characters_mlflow_takes():
    from ps_ray.pipeline.policy_models import model_name

    name = model_name("panda/push friction=0.1 · ps+consolidate_pull=0.5 · 101 · i16")
    assert name == "panda-push-friction-0-1-ps-consolidate_pull-0-5-101-i16"
    assert not set("/:.%\"' ") & set(name)
