"""What reaches the terminal (ps_ray.store.terminal): Ray's and MLflow's notices go to a log file."""

from __future__ import annotations

import io
import logging
import time
from pathlib import Path

from ps_ray.pipeline.progress import PLAIN_EVERY_S, StageProgress, eta_s
from ps_ray.store.attempts import START_STEPS, STOPPED_FILE, identity
from ps_ray.store.terminal import VERBOSE_ENV, others_to


def test_notices_go_to_the_log_and_every_handler_gets_its_stream_back(tmp_path, monkeypatch):
    monkeypatch.delenv(VERBOSE_ENV, raising=False)
    shared = logging.StreamHandler(io.StringIO())  # one handler on two loggers
    before = shared.stream
    for name in ("ray", "mlflow"):
        logging.getLogger(name).addHandler(shared)
    try:
        with others_to(tmp_path / "logs" / "driver.log") as terminal:
            logging.getLogger("ray").warning("a ray notice")
            print("printed inside")
            terminal.write("")  # the real stdout stays reachable for ps_ray's own lines
        assert shared.stream is before and before.getvalue() == ""
        text = (tmp_path / "logs" / "driver.log").read_text()
        assert "a ray notice" in text and "printed inside" in text
    finally:
        for name in ("ray", "mlflow"):
            logging.getLogger(name).removeHandler(shared)


def test_verbose_leaves_everything_on_the_terminal(tmp_path, monkeypatch):
    monkeypatch.setenv(VERBOSE_ENV, "1")
    with others_to(tmp_path / "driver.log"):
        pass
    assert not (tmp_path / "driver.log").exists()


def test_the_eta_counts_work_not_trials():
    # two long trials half way after an hour, two waiting: three trials' work left, one per hour
    assert eta_s(3600, [(0.0, 0.5, 1.0), (0.0, 0.5, 1.0)], pending=2) == 3 * 3600
    # the steps a resumed trial brought from its checkpoint are not this run's pace
    assert eta_s(3600, [(0.5, 0.75, 1.0)], pending=0) == 3600  # a quarter in an hour, a quarter left
    # a trial a scheduler stopped (or that failed) at a tenth ran a tenth, and has nothing left
    assert eta_s(3600, [(0.0, 0.1, 0.1), (0.0, 0.1, 1.0)], pending=1) == 3600 * 1.9 / 0.2
    # trials without a budget count whole when they end; nothing ended: no estimate yet
    assert eta_s(60, [(1.0, 1.0, 1.0), (0.0, 1.0, 1.0), (0.0, 0.0, 1.0)], pending=1) == 60 * 2
    assert eta_s(60, [(0.0, 0.0, 1.0)], pending=3) is None
    # 100 env steps of 150k after 31 s of start-up: too early to tell (not 158 hours)
    assert eta_s(31, [(0.0, 100 / 150_000, 1.0), (0.0, 0.0, 1.0)], pending=10) is None
    assert eta_s(600, [(0.0, 0.2, 1.0), (0.0, 0.2, 1.0)], pending=10) == 600 * 11.6 / 0.4


def _trial(storage, n: int):
    """A real Tune trial record (not run): its config names the grid value ``{"n": n}``."""
    from ray.train._internal.storage import StorageContext
    from ray.tune.experiment import Trial

    context = StorageContext(storage_path=str(storage), experiment_dir_name="stage", trial_dir_name=f"t{n}")
    trial = Trial("train", config={"trial": {"n": n}}, stub=True, storage=context)
    Path(trial.path).mkdir(parents=True)
    return trial


def _eta_ratio(view: StageProgress) -> float:
    """The view's ETA over its elapsed time (its clock started an hour ago)."""
    clock = view.status().rsplit("ETA ", 1)[1].split(":")
    return sum(int(part) * 60**i for i, part in enumerate(reversed(clock))) / 3600


def test_the_live_view_counts_work_a_trial_will_never_do_as_not_left(tmp_path):
    """Four trials of 1,000 env steps, one not made yet by Tune: a trial the scheduler stops at
    200 steps has no work left, and one retried after a failure is counted once."""
    from ray.tune.experiment import Trial

    view = StageProgress("train", total=4, key="trial", budgets={identity({"n": n}): 1000 for n in range(4)})
    view.started = time.time() - 3600
    stopped, retried, waiting = trials = [_trial(tmp_path, n) for n in range(3)]

    def result(trial, steps):
        trial.update_last_result({"env_steps": steps})
        view.on_trial_result(0, trials, trial, trial.last_result)

    for trial in (stopped, retried):
        trial.set_status(Trial.RUNNING)
        view.on_trial_start(0, trials, trial)
        result(trial, 100)
    result(stopped, 200)
    (Path(stopped.path) / STOPPED_FILE).write_text("{}")  # what the search's scheduler leaves
    stopped.set_status(Trial.TERMINATED)
    view.on_trial_complete(0, trials, stopped)
    result(retried, 600)
    # 0.1 + 0.5 of a trial's work in the hour; left: 0.4, the waiting one, the one not made
    assert abs(_eta_ratio(view) - 2.4 / 0.6) < 0.01, view.status()
    assert "1 done" not in view.status() and "1 stopped early" in view.status()

    retried.set_status(Trial.ERROR)
    view.on_trial_error(0, trials, retried)
    retried.set_status(Trial.PENDING)  # Tune retries it from its checkpoint
    view.on_trial_start(0, trials, retried)
    assert abs(_eta_ratio(view) - 2.4 / 0.6) < 0.01, view.status()


def test_a_zero_shot_batch_s_eta_counts_its_pairs_scored(tmp_path):
    """A zero-shot trial scores a batch of pairs, one result each: its ETA counts pairs."""
    from ray.tune.experiment import Trial

    view = StageProgress(
        "zero_shot", total=1, key="trial", budgets={identity({"n": 0}): 4}, work="training_iteration"
    )
    view.started = time.time() - 3600
    (trial,) = trials = [_trial(tmp_path, 0)]
    trial.set_status(Trial.RUNNING)
    view.on_trial_start(0, trials, trial)
    for scored in (1, 2):
        trial.update_last_result({"training_iteration": scored})
        view.on_trial_result(0, trials, trial, trial.last_result)
    # work counts from the first result seen (a resumed trial's carries earlier work): one pair
    # scored in the hour, two left
    assert abs(_eta_ratio(view) - 0.5 / 0.25) < 0.01, view.status()


def test_the_plain_view_prints_a_line_while_no_trial_reports(tmp_path, capsys):
    """Without a terminal (CI, `ray job` logs) a line every PLAIN_EVERY_S, even when the trials
    report once in many minutes; its clock moves."""
    from ray.tune.experiment import Trial

    view = StageProgress("zero_shot", total=2)
    trials = [_trial(tmp_path, n) for n in range(2)]
    trials[0].set_status(Trial.RUNNING)
    view.on_trial_start(0, trials, trials[0])
    first = capsys.readouterr().out
    assert first.strip().startswith("zero_shot: 0 done, 1 running, 0 failed, 1 pending")
    view.on_step_end(0, trials)
    assert capsys.readouterr().out == ""  # printed less than PLAIN_EVERY_S ago
    view.started -= 90
    view.last_plain -= PLAIN_EVERY_S
    view.last_step -= 1
    view.on_step_end(0, trials)
    later = capsys.readouterr().out
    assert "elapsed 1:30" in later and later.replace("1:30", "0:00") == first


def test_the_eta_counts_a_trial_s_own_steps_from_its_first_result_not_its_checkpoint_s(tmp_path):
    """Two trials of 1,000 env steps after an hour, each at its first result: a fresh one at 300
    steps, one resumed from a checkpoint at 500 and now at 600 (its rows say what it restored)."""
    from ray.tune.experiment import Trial

    view = StageProgress("train", total=2, key="trial", budgets={identity({"n": n}): 1000 for n in range(2)})
    view.started = time.time() - 3600
    fresh, resumed = trials = [_trial(tmp_path, n) for n in range(2)]
    for trial, start, steps in ((fresh, 0, 300), (resumed, 500, 600)):
        trial.set_status(Trial.RUNNING)
        view.on_trial_start(0, trials, trial)
        trial.update_last_result({"env_steps": steps, START_STEPS: start})
        view.on_trial_result(0, trials, trial, trial.last_result)
    # 0.3 + 0.1 of a trial's work in the hour, 0.7 + 0.4 left
    assert abs(_eta_ratio(view) - 1.1 / 0.4) < 0.01, view.status()


def test_a_grid_s_eta_counts_each_cell_s_env_steps_against_its_budget(tmp_path):
    """A grid reports one cell's env steps (its cells step in lockstep): the live view counts them
    against each cell's budget, so an hours-long grid shows an ETA while it runs."""
    from ray.tune.experiment import Trial

    from ps_ray.pipeline.training_trials import env_step_budget
    from ps_ray.plan import grid as grid_plan
    from ps_ray.specs.sweep import load_sweep

    spec = load_sweep(Path(__file__).parents[1] / "sweeps" / "push_family.yaml")
    grids = grid_plan.plan(spec)
    assert [env_step_budget(g) for g in grids] == [spec.trials()[0].env_steps] * 3 == [150_000] * 3
    budgets = {identity({"n": 0}): env_step_budget(grids[0])}
    view = StageProgress("grid", total=1, key="trial", budgets=budgets)
    view.started = time.time() - 3600
    (trial,) = trials = [_trial(tmp_path, 0)]
    trial.set_status(Trial.RUNNING)
    view.on_trial_start(0, trials, trial)
    for steps in (50_000, 100_000):  # resumed at a third; a third more in the hour, a third left
        trial.update_last_result({"env_steps": steps})
        view.on_trial_result(0, trials, trial, trial.last_result)
    assert abs(_eta_ratio(view) - 1.0) < 0.01, view.status()
