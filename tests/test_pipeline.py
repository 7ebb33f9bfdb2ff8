"""`ps-ray run sweeps/smoke.yaml` end to end (the README's pipeline), killed in training and
resumed; `ps-ray report` rebuilt idempotently and opened in headless Chromium."""

from __future__ import annotations

import base64
import contextlib
import dataclasses
import hashlib
import json
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import matplotlib.image
import mlflow
import numpy as np
import pandas as pd
import PIL.Image
import pytest

from ps_ray.analysis.browser import find_chromium
from ps_ray.analysis.cost import workload
from ps_ray.specs.names import readable, trial_key
from ps_ray.specs.sweep import load_sweep
from ps_ray.store.checkpoint import latest as latest_checkpoint
from ps_ray.store.layout import SweepLayout
from ps_ray.store.stages import stage_state
from ps_ray.store.tracking import TRIAL_KEY_TAG
from tests.plan_checks import assert_stages_launched_their_plans
from tests.processes import own_ray_env, wait_until_serving

SMOKE = Path(__file__).resolve().parents[1] / "sweeps" / "smoke.yaml"
FIGURES = {
    "training_curves",
    "heatmap_seeds_i16",
    "heatmap_robots_i16",
    "zero_shot",
    "transfer_controls",
    "transfer_gain",
    "few_shot_curves",
} | {f"interface_{c}_i16_{m}" for c in ("seeds", "robots") for m in ("ps", "ablation")}


def _checkpoints(root: Path, since: float, at_least: int) -> bool:
    """A trial folder of this run (started after ``since``) holds ``at_least`` checkpoints. Two
    mean Tune's checkpoint rotation is under way: the new checkpoint is written and the old not
    yet deleted (about 12 ms per rotation at smoke sizes). A folder left so by an earlier run's kill
    does not count."""
    for trial in (root / "tune").glob("*/"):
        with contextlib.suppress(FileNotFoundError):
            if (trial / "params.json").stat().st_mtime < since:
                continue
            if sum(e.name.startswith("checkpoint_") for e in os.scandir(trial)) >= at_least:
                return True
    return False


@dataclasses.dataclass(frozen=True)
class Kill:
    """A moment at which the fixture SIGKILLs `ps-ray run` (driver and the Ray processes it
    started): its name, the sign that it has come (given the sweep folder and when this run
    started), seconds between looks, and a sign that it is near (then looks come every ms)."""

    moment: str
    sign: object
    look: float = 0.2
    near: object = None


KILLS = (
    # during training, in a checkpoint rotation (looked for closely once a first checkpoint exists)
    Kill(
        "checkpoint rotation",
        lambda root, since: _checkpoints(root, since, 2),
        look=0.05,
        near=lambda root, since: _checkpoints(root, since, 1),
    ),
)
# The later stages are killed in no run of this file: a zero-shot batch cut after some of its pairs
# resumes with only the others (tests/test_zero_shot.py), few-shot resumes as the training stage
# does (stage markers, a Tune folder resumed), and a report is rebuilt whole (the `rebuilt`
# fixture below checks it is byte-identical).


def _kill_at(run: subprocess.Popen, root: Path, kill: Kill) -> None:
    """Wait for the kill's sign, then freeze the run's process group (SIGSTOP), confirm the moment
    still holds, and SIGKILL it; a moment that passed while freezing (a rotation can) is waited for again."""
    since = time.time() - 1.0  # the run was started just before (file times are coarse)
    deadline, look = since + 1200, kill.look
    while True:
        assert run.poll() is None, f"the run ended before its {kill.moment} kill"
        assert time.time() < deadline, f"the {kill.moment} moment did not come in time"
        if kill.sign(root, since):
            os.killpg(run.pid, signal.SIGSTOP)
            time.sleep(0.1)  # anything the stop caught mid-step would have shown by now
            if run.poll() is None and kill.sign(root, since):
                break
            os.killpg(run.pid, signal.SIGCONT)
        if kill.near is not None and look > 0.001 and kill.near(root, since):
            look = 0.001
        time.sleep(look)
    os.killpg(run.pid, signal.SIGKILL)
    run.wait()
    assert kill.sign(root, since), f"the {kill.moment} moment passed before the kill"


@pytest.fixture(scope="module")
def smoke(tmp_path_factory, cli, planted):
    """The smoke pipeline, SIGKILLed at each of KILLS' moments, rerun after each kill, and finished
    by a last run after hostile pickles were planted wherever Tune, RLlib or ps_ray might look.
    Returns (spec, root, the output of every run in order)."""
    storage = tmp_path_factory.mktemp("pipeline") / "sweeps"
    root = storage / "smoke"
    outs = []
    for number, kill in enumerate(KILLS):
        log = storage.parent / f"run_{number}.log"
        with log.open("w") as sink:  # a file, not a pipe nobody reads while waiting (it would fill)
            run = subprocess.Popen(
                [sys.executable, "-m", "ps_ray.cli", "run", str(SMOKE), "--storage", str(storage)],
                stdout=sink,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                env=own_ray_env(),  # its own Ray: the kill takes every process of the run
            )
            try:
                _kill_at(run, root, kill)
            except AssertionError as e:
                raise AssertionError(f"run {number}: {e}: {log.read_text()[-3000:]}") from None
        outs.append(log.read_text())
    for place in [
        root,
        *root.glob("tune*"),
        *root.glob("tune*/*"),
        *root.glob("tune*/*/check*"),
        root / "anchors",
    ]:
        if place.is_dir():
            planted(place)
    last = cli("run", str(SMOKE), "--storage", str(storage))
    out, _ = last.communicate(timeout=1200)
    assert last.returncode == 0, out[-3000:]
    assert not planted.marker.exists(), "a planted pickle was loaded"
    spec = dataclasses.replace(load_sweep(SMOKE), storage=str(storage))
    return spec, root, [*outs, out]


def _runs(root: Path, stage: str):
    client = mlflow.MlflowClient(f"sqlite:///{root / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("smoke")
    return [
        r for r in client.search_runs([experiment.experiment_id]) if r.data.tags.get("ps_ray.stage") == stage
    ]


def test_a_pipeline_killed_in_training_resumes_without_redoing_finished_work(smoke):
    spec, root, (in_train, last) = smoke
    assert "[1/4] train: starting" in in_train
    assert "[1/4] train: resuming" in last and "[2/4] zero_shot: starting" in last
    assert "[3/4] few_shot: starting" in last
    assert "[4/4] report: starting" in last and "[4/4] report: done" in last
    assert f"report: {root / 'report' / 'index.html'}" in last
    from ps_ray.pipeline.zero_shot import PAIR_KEY
    from ps_ray.store.attempts import FINISHED, attempts, checkpoint_dirs, merged_rows, read_rows

    layout = SweepLayout(root)  # every trial of every stage finished exactly once
    for folder, key, count in [(layout.tune_train, "trial", 16), (layout.tune_few_shot, "trial", 6)]:
        found = attempts(folder, key)
        assert len(found) == count, folder
        for tries in found.values():
            assert sum(bool(read_rows(t)) and bool(read_rows(t)[-1].get(FINISHED)) for t in tries) == 1
    # zero-shot ran its 16 pairs in batches, each pair once
    reported = [
        row[PAIR_KEY]
        for result in layout.tune_zero_shot.glob("*/result.json")
        for row in read_rows(result.parent)
        if PAIR_KEY in row
    ]
    assert len(reported) == len(set(reported)) == 16
    final_best = {}  # trial key -> its best greedy success at the end
    for trial, tries in attempts(layout.tune_train, "trial").items():  # best-so-far never fell
        best = [r["best_eval_success"] for r in merged_rows(tries) if "best_eval_success" in r]
        assert best and best == sorted(best), best
        final_best[trial_key(json.loads(trial)["spec"])] = best[-1]
    train_runs = _runs(root, "train")
    assert len(train_runs) == 16  # one MLflow run per trial, none duplicated
    # every few-shot run names its start and target; a start from a stitched pair names the pair
    few_shot_runs = _runs(root, "few_shot")
    kinds = {r.data.tags["ps_ray.start"] for r in few_shot_runs}
    assert kinds >= {"stitched", "unstitched", "scratch"}
    for run in few_shot_runs:
        target = run.data.tags["ps_ray.target"]
        method, robot, task, seed = target.split("/")[:4]  # named by its target env first
        assert run.info.run_name.startswith(f"{readable(f'{robot}/{task}')} · {method} · {seed}"), run

        assert ("ps_ray.pair" in run.data.tags) == (run.data.tags["ps_ray.start"] == "stitched")
        start = run.data.params["init_policy"]  # the file it started from, inside the sweep folder
        assert start == "null" if run.data.tags["ps_ray.start"] == "scratch" else (root / start).is_file()
    client = mlflow.MlflowClient(f"sqlite:///{root / 'mlflow.db'}")
    for run in train_runs:  # a trial cut short resumed from its checkpoint: no step logged twice
        steps = [m.step for m in client.get_metric_history(run.info.run_id, "env_steps")]
        assert len(steps) == len(set(steps)) and run.data.metrics["env_steps"] >= 400, run.info.run_name
        # MLflow ends on the trial's best-so-far, also for a trial restored from its final checkpoint
        assert run.data.metrics.get("best_eval_success") == final_best[run.data.tags[TRIAL_KEY_TAG]]
    # and the trials cut short by the kill were relaunched from their checkpoints, not from scratch
    relaunched = [  # later attempts of trials whose earlier attempts left a verified checkpoint
        later
        for folders in attempts(root / "tune", "trial").values()
        for i, later in enumerate(folders)
        if i and latest_checkpoint(checkpoint_dirs(folders[:i])) is not None and read_rows(later)
    ]
    assert relaunched and all(read_rows(f)[0]["iteration"] > 1 for f in relaunched)
    # the report covers exactly the trials and stitched pairs an uninterrupted run would have
    from ps_ray.plan.catalogue import trained
    from ps_ray.plan.zero_shot import matrix

    tables = root / "report" / "tables"
    sources = pd.read_csv(tables / "training_sources.csv")["run"]
    assert sorted(sources) == sorted(t.label() for t in spec.trials())  # each once
    expected = {(p.method, p.label) for p in matrix(spec, trained(spec))}  # a row per pair, over its seeds
    zero_shot = pd.read_csv(tables / "zero_shot.csv")
    assert sorted(zip(zero_shot["method"], zero_shot["label"])) == sorted(expected)
    assert (zero_shot["seeds"] == len(spec.seeds)).all()
    assert len(_runs(root, "zero_shot")) == 16
    # one stitched pair per method, its robot source fine-tuned unstitched, and their scratch runs
    assert len(_runs(root, "few_shot")) == 6
    steps = pd.read_csv(tables / "few_shot_steps.csv")
    assert set(steps["start"]) == {"stitched", "unstitched", "scratch"}
    assert f"env steps to {spec.report.few_shot_threshold} [95% CI]" in steps.columns  # the sweep's threshold
    assert len(pd.read_csv(root / "zero_shot.csv")) == 16
    assert all(stage_state(spec, s) == "done" for s in spec.stages)
    # every stage launched the trials its plan lists from the spec alone, as `--check` prices them
    assert_stages_launched_their_plans(spec)
    projected = {load.stage: len(load.trials) for load in workload(spec)}
    assert projected == {
        "anchors_plain": len(_runs(root, "anchors_plain")),
        "train": 16,
        "zero_shot": 2,  # 16 pairs in trials of 8
        "few_shot": 6,
    }


def test_the_terminal_gets_a_compact_view_and_the_log_keeps_tunes_tables(smoke):
    spec, root, outs = smoke
    assert all(len(o.splitlines()) <= 150 for o in outs), [len(o.splitlines()) for o in outs]
    out = "\n".join(outs)
    lines = out.splitlines()
    assert len(lines) <= 150 + 10 * len(KILLS), f"{len(lines)} lines over all runs"
    assert "\x1b[" not in out  # no TTY here: plain lines, no control codes
    assert "Trial status" not in out and "sweep_trial_" not in out
    # Ray's and MLflow's start-up notices went to the driver's log, not the terminal
    for notice in ("Token authentication is enabled", "on the new API stack", "MLflow database tables"):
        assert notice not in out, notice
    # the log keeps them (Ray's token notice is printed only where no token exists yet, so MLflow's
    # database set-up, printed on every fresh store, is the notice checked)
    assert "MLflow database tables" in (root / "logs" / "driver.log").read_text()
    assert any(line.startswith("  zero_shot: ") and " done, " in line for line in lines)
    assert any(line.startswith("  few_shot: 6 done, 0 running, 0 failed, 0 pending") for line in lines)
    assert "Trial status" in (root / "logs" / "tune_zero_shot.log").read_text()
    assert "Trial status" in (root / "few_shot" / "logs" / "tune_few_shot.log").read_text()
    assert any(line.startswith("sweep 'smoke': projected ") and "core-hours" in line for line in lines)
    assert outs[-1].splitlines()[-1].startswith("note: ") and "near zero by design" in lines[-1]


def test_rerunning_a_finished_pipeline_skips_every_stage(cli, smoke):
    spec, root, _ = smoke
    before = (root / "report" / "index.html").stat().st_mtime
    proc = cli("run", str(SMOKE), "--storage", str(root.parent))
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, out[-3000:]
    assert out.count("done earlier, skipped") == 4
    assert (root / "report" / "index.html").stat().st_mtime == before


def test_changed_stage_settings_rerun_that_stage_and_later_ones_only(smoke):
    spec, root, _ = smoke
    changed = dataclasses.replace(spec, few_shot=dataclasses.replace(spec.few_shot, env_steps=2000))
    assert [stage_state(changed, s) for s in spec.stages] == ["done", "done", "new", "new"]
    (root / "stages" / "report.json").rename(root / "stages" / "report.moved")
    try:
        assert stage_state(spec, "report") == "interrupted"  # started, never finished
    finally:
        (root / "stages" / "report.moved").rename(root / "stages" / "report.json")


def test_report_embeds_every_figure_and_table(smoke):
    _, root, _ = smoke
    page = (root / "report" / "index.html").read_text()
    figures = {p.stem: p for p in (root / "report" / "figures").glob("*.png")}
    assert set(figures) == FIGURES
    # ticks are set at 9 pt or more, 12.5 px at the figures' 100 dpi; the page's column (1,200 px)
    # shrinks a wider figure, and none may be so wide that its ticks read under 8 px
    for name, path in figures.items():
        with PIL.Image.open(path) as image:
            assert 12.5 * min(1.0, 1200 / image.size[0]) >= 8, (name, image.size)
    for name, path in figures.items():
        assert (
            f"alt='{name}' src='data:image/png;base64,{base64.b64encode(path.read_bytes()).decode()}'" in page
        )
    for section in (
        "Training",
        "Latent alignment",
        "Zero-shot stitching",
        "Few-shot fine-tuning",
        "Cost: projected and used",
    ):
        assert f">{section}</h2>" in page
    assert "Zero-shot results (Table 1 layout)" in page and "task module &amp; robot module" in page
    assert "near zero by design" in page  # the smoke budget says what it cannot show
    # when it ran and with what; every table scrolls inside the page, with no index column of row
    # numbers and no header row holding only index names
    assert re.search(r"<th>ran</th><td>\d{4}-\d\d-\d\d \d\d:\d\d UTC</td>", page)
    assert re.search(r"<th>libraries</th><td>ps_ray [^<]*, ray 2\.\d+[^<]*, torch ", page)
    assert page.count("<div class='wide'><table class=\"dataframe\">") == page.count(
        '<table class="dataframe">'
    )
    assert "<th></th>" not in page and "<th>    </th>" not in page
    # task variants are named as a reader would, not as JSON
    assert "reach q1" in page and "goal_region" not in page
    # rollout clips: 2 stitched pairs x 2 methods x (stitched, task source, robot source), animated
    gifs = sorted((root / "report" / "clips").glob("*.gif"))
    assert len(gifs) == 12 and page.count("src='data:image/gif;base64,") == 12
    first_frames = {}
    for gif in gifs:
        with PIL.Image.open(gif) as image:
            assert image.n_frames >= 20 and image.size == (240, 180), gif.name
            first_frames[gif.stem] = np.asarray(image.convert("RGB"))
    for pair in ("pair0", "pair1"):  # the same pair starts from the same state under every method
        assert np.array_equal(first_frames[f"{pair}_ps"], first_frames[f"{pair}_ablation"])
    captions = re.findall(r"(did not reach|reached) the goal \(ended ([\d.]+) cm from it\)", page)
    assert len(captions) == 12  # each caption agrees with its final distance (success: < 5 cm)
    assert all((verdict == "reached") == (float(cm) < 5.0) for verdict, cm in captions)
    cost = pd.read_csv(root / "report" / "tables" / "cost.csv", index_col=0)
    assert (cost["attempts (ran)"] >= cost["trials (projected)"]).all()  # a killed attempt is rerun
    assert (cost["core-hours in trials (used)"] > 0).all()
    distances = pd.read_csv(root / "report" / "tables" / "latent_distances.csv", index_col=0)
    assert set(distances["comparison"]) == {"seeds", "robots"}
    # the paper's finding, which holds even at smoke budgets: relative interfaces agree more
    for comparison, part in distances.groupby("comparison"):
        cos = part.set_index("method")["cosine_mean"]
        assert cos["ps"] < cos["ablation"], comparison
    report_runs = _runs(root, "report")
    assert len(report_runs) == 1
    assert report_runs[0].data.metrics["latent.seeds.i16.ps.cosine"] == pytest.approx(
        distances.query("comparison == 'seeds' and method == 'ps'")["cosine_mean"].item()
    )


def test_the_zoo_of_a_sweep_indexes_its_sources_on_one_anchor_set_and_stitches_deterministically(smoke):
    """The smoke folder's module zoo: every trained source and the plain anchor sources; the ps
    sources of one interface width share the sweep's one anchor set; a stitch of two of them
    scores the same fixed episodes however the envs are batched."""
    from ps_ray.stitching.evaluate import evaluate
    from ps_ray.stitching.stitch import stitch_policies
    from ps_ray.stitching.zoo import ModuleZoo

    spec, root, _ = smoke
    zoo = ModuleZoo.from_sweep(root)
    plain = [e for e in zoo if e.key.method == "plain"]
    assert len(zoo) == 16 + 2 and {e.stage for e in plain} == {"plain_source"} and len(plain) == 2
    ps = [e for e in zoo if e.key.method == "ps"]
    assert len(ps) == 8 and len({e.signature.anchor_hash for e in ps}) == 1  # one anchor set per sweep
    task = next(e for e in ps if e.robot == "panda")
    robot = next(e for e in ps if e.robot == "panda_l3" and e.key.seed == task.key.seed)
    nets, signature = stitch_policies(task, robot)
    batched = evaluate((nets, signature), "panda_l3", robot.task, episodes=2, repeats=1, num_envs=2)
    assert batched["success_mean"] in (0.0, 0.5, 1.0)  # two fixed episodes
    alone = evaluate((nets, signature), "panda_l3", robot.task, episodes=2, repeats=1, num_envs=1)
    assert alone["success_mean"] == batched["success_mean"]  # the stitched policy is deterministic


def _digests(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def rebuilt(smoke, planted, tmp_path_factory):
    """`ps-ray report --screenshot` over the finished smoke folder (planted pickles included), run
    with ``python -X importtime``, which lists every module the command imported. Returns (those
    modules, the report's file digests before and after, the screenshot)."""
    _, root, _ = smoke
    before = _digests(root / "report")
    shot = tmp_path_factory.mktemp("screenshot") / "report.png"
    command = ["-m", "ps_ray.cli", "report", str(root), "--screenshot", str(shot)]
    done = subprocess.run(
        [sys.executable, "-X", "importtime", *command],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:]
    assert f"screenshot: {shot}" in done.stdout
    assert not planted.marker.exists(), "a planted pickle was loaded"
    timings = [line for line in done.stderr.splitlines() if line.startswith("import time:")]
    imported = {line.rsplit("|", 1)[-1].strip() for line in timings}
    assert "ps_ray.analysis.report" in imported and "mlflow" in imported
    return imported, (before, _digests(root / "report")), shot


def test_building_and_logging_a_report_never_loads_ray(rebuilt):
    imported, _, _ = rebuilt
    assert not [m for m in imported if m == "ray" or m.startswith("ray.")]


def test_report_command_is_idempotent(smoke, rebuilt):
    _, root, _ = smoke
    _, (built_by_run, rebuilt_by_report), _ = rebuilt
    assert built_by_run == rebuilt_by_report  # the same bytes, file by file
    assert {"index.html", "interfaces.safetensors", "tables/zero_shot.csv"} <= set(built_by_run)
    assert len(_runs(root, "report")) == 1  # the same MLflow run, rebuilt
    client = mlflow.MlflowClient(f"sqlite:///{root / 'mlflow.db'}")
    logged = {a.path for a in client.list_artifacts(_runs(root, "report")[0].info.run_id)}
    assert {"index.html", "figures", "tables", "interfaces.safetensors", "sweep"} <= logged
    (spec_artifact,) = client.list_artifacts(_runs(root, "report")[0].info.run_id, "sweep")
    assert spec_artifact.path == "sweep/sweep.yaml"  # the resolved spec the stages ran


def test_report_of_a_folder_that_is_not_a_sweep_fails_with_one_line(cli, tmp_path):
    proc = cli("report", str(tmp_path))
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 2
    assert (
        out.strip().splitlines()[-1]
        == f"ps-ray report: error: {tmp_path}: not a sweep folder (no sweep.yaml)"
    )


def test_report_opens_in_headless_chromium(smoke, rebuilt, visible_text):
    _, root, _ = smoke
    _, _, shot = rebuilt
    assert find_chromium(), "Chromium is needed for this check (./run.sh test installs it)"
    pixels = matplotlib.image.imread(shot)[..., :3]
    assert pixels.shape[1] == 1280
    ink = (pixels < 0.9).any(-1).mean()
    # plots are coloured, text is not: at the smoke's near-zero successes most bars are short, so
    # the bar is about 25k coloured pixels of the 1280 x 4000 frame (the text alone has none)
    colour = (pixels.max(-1) - pixels.min(-1) > 0.3).mean()
    assert ink > 0.05 and colour > 0.005, (ink, colour)
    top = pixels[:400]
    assert (top < 0.5).any(-1).mean() > 0.002  # the title and overview table are drawn
    assert np.isfinite(pixels).all()
    text = visible_text(root / "report" / "index.html", wait_ms=0)
    assert "`" not in text  # names set as code, not as literal backticks
    # the answer comes first: the headline table opens the page, before any training curve
    assert text.index("Headline per method") < text.index("Greedy success of the sweep's policies during")
    assert text.index("near zero by design") < text.index("Headline per method")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.slow  # a tracking UI served and read in a browser: a cluster service, as the tracking server
def test_mlflow_ui_lists_the_runs_and_the_report_artifact(smoke, visible_text):
    """`mlflow ui` as `ps-ray run` prints it at the end, read in headless Chromium."""
    _, root, outs = smoke
    assert find_chromium(), "Chromium is needed for this check (./run.sh test installs it)"
    (printed,) = [line for line in outs[-1].splitlines() if line.startswith("MLflow: ")]
    command = shlex.split(printed.removeprefix("MLflow: "))
    assert command[:2] == ["mlflow", "ui"] and f"sqlite:///{root.resolve() / 'mlflow.db'}" in command
    port = _free_port()
    server = subprocess.Popen(
        [Path(sys.executable).with_name("mlflow"), *command[1:], "--host", "127.0.0.1", "--port", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        base = f"http://127.0.0.1:{port}"
        wait_until_serving(base, server, "mlflow ui")
        client = mlflow.MlflowClient(f"sqlite:///{root / 'mlflow.db'}")
        experiment = client.get_experiment_by_name("smoke").experiment_id
        runs = client.search_runs([experiment])
        # the page `ps-ray run` prints lands on the runs, not on the GenAI overview
        (page,) = [line.split("then open ")[1] for line in outs[-1].splitlines() if "then open " in line]
        assert page.startswith("http://127.0.0.1:5000/#/experiments/")
        listing = visible_text(page.replace("http://127.0.0.1:5000", base))
        assert f"{len(runs)} matching runs" in listing and "Traces 0" not in listing
        # the list is the stages, each run of a stage nested under its stage's run
        for stage in ("anchors_plain", "train", "zero_shot", "few_shot", "report"):
            assert f"{stage} " in listing, stage
        parents = {r.info.run_id: r.info.run_name for r in runs if "ps_ray.stage_run" in r.data.tags}
        assert sorted(parents.values()) == ["anchors_plain", "few_shot", "train", "zero_shot"]
        # a stage's run lasts its stage (killed and resumed: from its first start to its last end)
        # and closes with its summary; the sweep file's header is the experiment's description
        stage_runs = {r.info.run_name: r for r in runs if "ps_ray.stage_run" in r.data.tags}
        for stage in ("train", "zero_shot", "few_shot"):
            info = stage_runs[stage].info
            wall = json.loads((root / "stages" / f"{stage}.json").read_text())["wall_s"]
            assert info.status == "FINISHED" and info.end_time - info.start_time >= 500 * wall, stage
        assert stage_runs["train"].data.metrics["trials_finished"] == 16
        assert stage_runs["zero_shot"].data.metrics["ps.pairs"] == 8
        assert client.get_experiment(experiment).tags["mlflow.note.content"].startswith("The whole pipeline")
        assert [e.name for e in client.search_experiments()] == ["smoke"]  # no empty Default
        for run in runs:
            if "ps_ray.stage" in run.data.tags and run.data.tags["ps_ray.stage"] != "report":
                assert parents[run.data.tags["mlflow.parentRunId"]] == run.data.tags["ps_ray.stage"]
        report_run = next(r for r in runs if r.data.tags.get("ps_ray.stage") == "report")
        artifacts = visible_text(f"{base}/#/experiments/{experiment}/runs/{report_run.info.run_id}/artifacts")
        for name in ("index.html", "figures", "tables", "runs.json"):
            assert name in artifacts, name
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)


def test_report_of_a_renamed_sweep_folder_fails_with_one_line(cli, tmp_path):
    folder = tmp_path / "renamed"
    folder.mkdir()
    (folder / "sweep.yaml").write_text(SMOKE.read_text())  # the spec names sweep 'smoke'
    proc = cli("report", str(folder))
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 2
    assert out.strip().splitlines()[-1] == (
        f"ps-ray report: error: {folder}: holds sweep 'smoke'; a sweep folder must keep its "
        "sweep's name (rename it back to 'smoke')"
    )
    assert sorted(p.name for p in folder.iterdir()) == ["sweep.yaml"]  # nothing written


def test_no_entry_point_runs_the_pickles_planted_in_the_sweep_folder(smoke, cli, planted, tmp_path):
    """The smoke folder still holds the fixture's hostile pickles (in the sweep folder, every Tune
    folder, trial folder and checkpoint, and the anchors): every command that reads it succeeds
    and none loads them. (`run` and `sweep --resume` are checked by the fixture and test_sweep,
    `report` by the rebuilt fixture.)"""
    from ps_ray.specs.names import spec_text
    from ps_ray.stitching.zoo import ModuleZoo

    spec, root, _ = smoke
    assert list(root.glob("tune/*/checkpoint_*/*.pkl")), "the fixture planted pickles beside the policies"
    zoo = ModuleZoo.from_sweep(root)
    ps = sorted((e for e in zoo if e.key.method == "ps" and e.stage == "train"), key=lambda e: str(e.key))
    task_from = next(e for e in ps if e.robot == "panda")
    robot_from = next(e for e in ps if e.robot == "panda_l3" and e.task != task_from.task)
    storage = str(root.parent)
    commands = [
        ("zero-shot", str(SMOKE), "--storage", storage, "--resume"),
        ("few-shot", str(SMOKE), "--storage", storage, "--resume"),
        (
            "stitch",
            "--sweep",
            str(root),
            "--task-from",
            str(task_from.key),
            "--robot-from",
            str(robot_from.key),
        )
        + ("--episodes", "2", "--repeats", "1", "--save", str(tmp_path / "stitched.safetensors")),
        ("render", "--policy", str(robot_from.path), "--robot", "panda_l3")
        + ("--task", spec_text(robot_from.task), "--png", str(tmp_path / "last.png")),
    ]
    for args in commands:
        proc = cli(*args)
        out, _ = proc.communicate(timeout=600)
        assert proc.returncode == 0, (args[0], out[-3000:])
        if args[0] == "zero-shot":  # a finished matrix is not evaluated again, not even chance
            assert "chance on" not in out and "ps " in out.splitlines()[-1], out[-3000:]
    assert (tmp_path / "stitched.safetensors").exists() and (tmp_path / "last.png").exists()
    assert not planted.marker.exists(), "a planted pickle was loaded"
