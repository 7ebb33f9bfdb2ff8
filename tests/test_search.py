"""A sweep's hyperparameter search: Tune's random search draws the settings, Tune's ASHA stops
trials on the greedy success curve, and a killed search resumes without repeating a trial."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest
import yaml

from ps_ray.specs.search import SearchSpec
from ps_ray.specs.sweep import load_sweep
from ps_ray.specs.train import SpecError
from ps_ray.store.attempts import FINISHED, STOPPED_FILE, attempts, read_rows
from ps_ray.store.layout import sweep_layout

# Two settings: one learns reach within the budget, one (a learning rate of 1e-9) cannot. Seed 0
# draws them as [learns, cannot], so the learner sets the rung's bar first.
SPACE = {"lr": {"choice": [0.003, 1e-9]}}
CAP = 3000


def write(tmp_path: Path, name: str = "search", **search) -> Path:
    data = {
        "name": name,
        "stages": ["train"],
        "methods": ["plain"],
        "robots": ["panda"],
        "tasks": ["reach"],
        "seeds": [1],
        "train": {
            "env_steps": CAP,
            "hidden": 32,
            "batch_size": 64,
            "learning_starts": 200,
            "random_episodes": 2,
            "eval_every": 2,
            "eval_episodes": 4,
            "checkpoint_every": 4,
        },
        "search": {
            "space": SPACE,
            "samples": 2,
            "seed": 0,
            "metric": "best_eval_success",
            "grace_env_steps": 2000,
            "reduction_factor": 2,
            **search,
        },
        "max_concurrent": 1,
        "storage": str(tmp_path / "store"),
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_draws_are_the_same_every_time_and_inside_the_space(tmp_path):
    space = {
        "lr": {"loguniform": [1e-4, 1e-2]},
        "tau": {"uniform": [0.001, 0.05]},
        "critic_warmup_updates": {"randint": [64, 128]},
        "target_entropy": {"choice": [-7, -2]},
    }
    spec = load_sweep(write(tmp_path, space=space, samples=20))
    again = load_sweep(write(tmp_path, space=space, samples=20))
    assert spec.trials() == again.trials()  # a resumed search finds the trials it started
    for trial in spec.trials():
        assert 1e-4 <= trial.lr <= 1e-2 and 0.001 <= trial.tau <= 0.05
        assert 64 <= trial.critic_warmup_updates < 128 and isinstance(trial.critic_warmup_updates, int)
        assert trial.target_entropy in (-7, -2)
    assert len({t.lr for t in spec.trials()}) == 20
    names = [name for name, _ in spec.named_trials()]
    assert names == [f"search{i:02d}" for i in range(20)]
    other = load_sweep(write(tmp_path, space=space, samples=20, seed=1))
    assert other.trials() != spec.trials()


@pytest.mark.parametrize(
    "search, message",
    [
        ({"space": {"seed": {"choice": [1, 2]}}}, "search.space: 'seed' cannot be searched; valid: hidden"),
        ({"space": {"lr": {"normal": [0, 1]}}}, "unknown distribution 'normal'; valid: choice, uniform"),
        ({"space": {"lr": {"uniform": [0.01, 0.001]}}}, "must be [low, high] with low < high"),
        ({"space": {"lr": {"loguniform": [0, 0.1]}}}, "loguniform needs a positive low"),
        ({"space": {"lr": 0.001}}, "search.space.lr must be one distribution"),
        ({"space": {"gamma": {"choice": [0.9, 1.5]}}}, "gamma must be in (0, 1), got 1.5"),
        (
            {"space": SPACE, "scheduler": "hyperband"},
            "unknown search.scheduler 'hyperband'; valid: asha, none",
        ),
        ({"space": SPACE, "metric": "reward"}, "unknown search.metric 'reward'; valid: eval_success"),
        ({"space": SPACE, "reduction_factor": 1}, "search.reduction_factor must be >= 2, got 1"),
        ({"space": SPACE, "samples": 0}, "search.samples must be a positive integer"),
        ({"space": SPACE, "budget": 3}, "unknown key 'budget'; valid keys: space, samples"),
    ],
)
def test_a_bad_search_is_refused_in_one_line_naming_it(tmp_path, search, message):
    path = write(tmp_path)
    data = yaml.safe_load(path.read_text())
    data["search"] = search
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError) as error:
        load_sweep(path)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert str(error.value).startswith(str(path))


def test_a_search_is_refused_beside_stitching_stages_and_a_setting_set_twice(tmp_path):
    path = write(tmp_path)
    data = yaml.safe_load(path.read_text())
    with pytest.raises(
        SpecError, match="stage 'zero_shot' cannot follow a search.*valid stages with a search: train, report"
    ):
        load_sweep(write(tmp_path), ["stages=[train, zero_shot]"])
    data["train"]["lr"] = 0.001
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError, match="search.space.lr is also set in 'train'; set it in one place"):
        load_sweep(path)


def test_the_rungs_and_nominal_cost_are_asha_s():
    search = SearchSpec(space=SPACE, grace_env_steps=30_000, reduction_factor=3)
    assert search.rungs(150_000) == [30_000, 90_000]  # 270k is past the cap
    # 12 trials to 30k, 4 on to 90k, 4/3 on to 150k
    assert search.nominal_env_steps(12, 150_000) == pytest.approx(12 * 30e3 + 4 * 60e3 + 4 / 3 * 60e3)
    assert SearchSpec(space=SPACE, scheduler="none").nominal_env_steps(12, 150_000) == 12 * 150_000


def test_check_lists_each_drawn_setting_and_prices_the_search(tmp_path, cli):
    proc = cli("sweep", str(write(tmp_path, samples=3)), "--check")
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0, out
    assert "plain/panda/reach/1  3000 env steps  search00: lr=0.003" in out
    assert "search01: lr=1e-09" in out and "search02: lr=1e-09" in out
    assert "search: 3 settings drawn by Tune's random search (seed 0), each on 1 trial(s) of the sweep" in out
    # ASHA at 2,000: 3 trials to it, 1.5 on to 3,000 -> 7,500 of 9,000
    assert "bottom 1/2 at 2,000 env steps: nominally 7,500 env steps, 83% of the full budgets" in out


def _trial_folders(path: Path) -> dict[str, list[Path]]:
    """Each drawn setting's attempt folders, by its name."""
    stage = sweep_layout(load_sweep(path)).root / "tune"
    found = {}
    for folders in attempts(stage, "trial").values():
        label = json.loads((folders[-1] / "params.json").read_text())["trial"]["label"]
        found[label] = folders
    return found


@pytest.mark.slow
def test_asha_stops_the_settings_that_do_not_learn_and_a_killed_search_resumes_without_repeats(tmp_path, cli):
    """The learner runs to its end; the search is killed as the second trial starts; the resumed
    search's scheduler knows the learner's curve, so it stops the other at the first rung, and the
    learner is not run again; a second resume finds nothing left to run."""
    path = write(tmp_path)
    proc = cli("sweep", str(path), own_ray=True, start_new_session=True)
    deadline = time.time() + 400
    while time.time() < deadline:
        found = _trial_folders(path) if (sweep_layout(load_sweep(path)).root / "tune").is_dir() else {}
        rows = read_rows(found["search00"][0]) if "search00" in found else []
        if rows and rows[-1].get(FINISHED) and "search01" in found:
            break
        time.sleep(0.5)
    else:
        pytest.fail("the first trial did not finish in time")
    os.killpg(proc.pid, signal.SIGKILL)  # the driver and everything it started
    proc.wait()
    learner_rows = (found["search00"][0] / "result.json").read_text()

    resumed = cli("sweep", str(path), "--resume")
    out, _ = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, out[-3000:]
    assert "2/2 trials finished" in out
    after = _trial_folders(path)
    assert len(after["search00"]) == 1  # not run again
    assert (after["search00"][0] / "result.json").read_text() == learner_rows
    assert read_rows(after["search00"][0])[-1]["best_eval_success"] >= 0.5  # it learned
    # every row after the first update carries the entropy temperature and the policy's entropy
    learning = [r for r in read_rows(after["search00"][0]) if r["env_steps"] > 400 and not r.get(FINISHED)]
    assert learning and all(0 < r["alpha"] < 1 and isinstance(r["entropy"], float) for r in learning)
    marked = [f for f in after["search01"] if (f / STOPPED_FILE).is_file()]  # the setting that cannot learn
    assert len(marked) == 1
    mark = json.loads((marked[0] / STOPPED_FILE).read_text())
    assert 2000 <= mark["env_steps"] < CAP  # stopped at the rung, before the budget
    assert mark["best_eval_success"] < read_rows(after["search00"][0])[-1]["best_eval_success"]
    # a second resume has nothing left to run: stopped trials count as done
    again = cli("sweep", str(path), "--resume")
    out, _ = again.communicate(timeout=300)
    assert again.returncode == 0 and "2/2 trials finished" in out, out[-2000:]
    assert {n: len(f) for n, f in _trial_folders(path).items()} == {n: len(f) for n, f in after.items()}
    # the report's search table: each setting, how it ended, best first
    import pandas as pd

    from ps_ray.analysis.report import build_report

    page = build_report(load_sweep(path), progress=False, log_to_mlflow=False)
    table = pd.read_csv(page.parent / "tables" / "search_trials.csv")
    assert list(table["setting"]) == ["search00", "search01"]  # best first
    assert table["ended"][0] == "ran its budget" and table["env_steps"][0] == CAP
    assert all(e.startswith("stopped by ASHA at 2,") for e in table["ended"][1:])
    assert (page.parent / "figures" / "search_curves.png").stat().st_size > 10_000
