"""Zero-shot matrix and few-shot fine-tuning of a trained sweep, as Tune trials into MLflow."""

from __future__ import annotations

import json
from pathlib import Path

import mlflow
import numpy as np
import pandas as pd
import pytest
import torch
import yaml

from ps_ray.analysis.results import curves as curves_of
from ps_ray.nets.policy_file import load_policy
from ps_ray.pipeline.few_shot import curves, run_few_shot
from ps_ray.pipeline.sweep import run_sweep
from ps_ray.pipeline.zero_shot import run_zero_shot
from ps_ray.pipeline.zero_shot_table import summary
from ps_ray.plan.catalogue import trained
from ps_ray.plan.zero_shot import matrix
from ps_ray.specs.sweep import load_sweep
from ps_ray.stitching.pair_table import pairs_from_table
from ps_ray.stitching.zoo import ModuleZoo
from ps_ray.store.layout import sweep_layout
from ps_ray.store.signature import read_signature
from tests.plan_checks import assert_stages_launched_their_plans


@pytest.fixture(scope="module")
def trained_matrix(tmp_path_factory, ray_local, tiny_train):
    tmp_path = tmp_path_factory.mktemp("matrix")
    path = tmp_path / "matrix.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "name": "matrix",
                "methods": ["ablation"],
                "robots": ["panda", "panda_l3"],
                "tasks": [{"name": "reach", "goal_region": "q1"}, {"name": "reach", "goal_region": "q3"}],
                "seeds": [1],
                "interface_dims": [8],
                "train": tiny_train,
                "population": 2,  # the four sources in two trials of two (docs/cost.md "Populations")
                "max_concurrent": 2,
                "storage": str(tmp_path / "store"),
            }
        )
    )
    spec = load_sweep(path)
    assert not any(r.error for r in run_sweep(spec, progress=False))
    return spec


def test_zero_shot_matrix_of_a_sweep(trained_matrix, tmp_path):
    spec = trained_matrix
    # trained as two population trials of two sources; the zoo and the training curves hold
    # each source as one trained alone
    sources = sorted(t.label() for t in spec.trials())
    assert len(list(sweep_layout(spec).tune_train.glob("*/params.json"))) == 2
    zoo = ModuleZoo.from_sweep(sweep_layout(spec).root)
    assert sorted(str(e.key) for e in zoo) == sources and {e.stage for e in zoo} == {"train"}
    assert sorted(curves_of(sweep_layout(spec).tune_train)["run"].unique()) == sources
    found = matrix(spec, trained(spec))
    by_key = {pair.key: pair for pair in found}
    # task module of (region X, arm A) with robot module of (region Y != X, arm B != A)
    assert len(found) == 4
    for pair in found:
        assert pair.task["name"] == "reach" and pair.robot in ("panda", "panda_l3")
        assert pair.task != pair.robot_from_task  # the task module's task, not the robot module's
        assert pair.task_from.split("/")[1] == pair.task_from_robot != pair.robot

    table = run_zero_shot(spec, episodes=4, repeats=2, progress=False)
    assert len(table) == 4 and set(table["method"]) == {"ablation"}
    assert (sweep_layout(spec).root / "zero_shot.csv").exists()
    assert summary(table).loc["ablation", "pairs"] == 4
    # every pair carries its controls: the robot source as it is, the task source on the target
    # robot and the oracle trained on the target pair (all four pairs of the grid were trained)
    for _, row in table.iterrows():
        robot_key, task_key = row["robot_from"].split("/"), row["task_from"].split("/")
        assert row["robot_source"] == row["robot_from"] and row["task_source"] == row["task_from"]
        assert row["oracle"] == "/".join([robot_key[0], robot_key[1], task_key[2], *robot_key[3:]])
        best = max(row["robot_source_success"], row["task_source_success"])
        assert row["best_unstitched"] == best
        # chance: the target env's own figure, the same for every pair on that env
        assert row["best_control"] == max(best, row["chance_success"])
        assert row["transfer_gain"] == pytest.approx(row["success_mean"] - row["best_control"])
        # reach halves hold one target per scene: no task-blind floor, no wrong target, no fit
        assert np.isnan(row["task_blind_success"]) and np.isnan(row["wrong_target_mean"])
        assert row["gain_over_chance"] == pytest.approx(row["transfer_gain"]) and row["fit_env_steps"] == 0
    assert table.groupby(["robot", "task"])["chance_success"].nunique().eq(1).all()
    # the table keeps each pair's record: its sources' and controls' files, which few-shot reads
    written = pd.read_csv(sweep_layout(spec).root / "zero_shot.csv")
    for column in (
        "task_from_path",
        "robot_from_path",
        "robot_source_path",
        "task_source_path",
        "oracle_path",
    ):
        # inside the sweep folder, relative to it: a copied sweep folder still finds its files
        assert all(
            not Path(path).is_absolute() and (sweep_layout(spec).root / path).is_file()
            for path in written[column]
        )
    assert written["robot_source_path"].tolist() == written["robot_from_path"].tolist()
    assert pairs_from_table(sweep_layout(spec).root / "zero_shot.csv") == found

    client = mlflow.MlflowClient(f"sqlite:///{sweep_layout(spec).root / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("matrix")
    found_runs = [
        r for r in client.search_runs([experiment.experiment_id]) if "ps_ray.trial_key" in r.data.tags
    ]
    stages = [r.data.tags["ps_ray.stage"] for r in found_runs]
    # one run per stitched pair, its controls' figures among its metrics; one per population
    # trial and, nested under it, one per source it trained, as a source trained alone has
    assert stages.count("zero_shot") == 4 and stages.count("train") == 2 + 4
    populations = {
        r.info.run_id: r for r in found_runs if r.data.tags["ps_ray.trial_key"].startswith("population/")
    }
    for run in populations.values():  # the settings its members share, and their keys
        assert "seed" not in run.data.params and len(run.data.params["members"].split(", ")) == 2
    members = [r for r in found_runs if r.data.tags.get("mlflow.parentRunId") in populations]
    assert sorted(r.data.tags["ps_ray.trial_key"] for r in members) == sorted(
        t.label() for t in spec.trials()
    )
    for run in members:  # its own figures, spec and files
        assert 0 <= run.data.metrics["final_success"] <= 1 and run.data.params["seed"] == "1"
        assert "ps_ray.model" in run.data.tags  # its policy a logged model, as a source's
        names = {a.path for a in client.list_artifacts(run.info.run_id)}
        assert len({n for n in names if n.startswith("policy_c")}) == 1 and any(
            n.startswith("spec_c") for n in names
        )
    # each stitched pair's run links to the training runs of its two sources
    train_runs = {
        r.data.tags["ps_ray.trial_key"]: r.info.run_id
        for r in found_runs
        if r.data.tags["ps_ray.stage"] == "train"
    }
    for run in (r for r in found_runs if r.data.tags["ps_ray.stage"] == "zero_shot"):
        tags = run.data.tags
        assert {"oracle_success", "chance_success", "transfer_gain"} <= set(run.data.metrics)
        assert tags["ps_ray.task_module_run"] == train_runs[tags["ps_ray.task_module"]]
        assert tags["ps_ray.robot_module_run"] == train_runs[tags["ps_ray.robot_module"]]
        assert tags["ps_ray.task_module"] != tags["ps_ray.robot_module"]
        assert (tags["ps_ray.device"], tags["ps_ray.cpus"]) == ("cpu", "1")
        # named by its target first, its description linking its sources' runs by their names
        pair = by_key[tags["ps_ray.trial_key"]]
        assert run.info.run_name == pair.title and run.info.run_name.startswith(f"{pair.robot.short}/reach q")
        task_run = client.get_run(tags["ps_ray.task_module_run"])
        page = f"#/experiments/{experiment.experiment_id}/runs/{task_run.info.run_id}"
        link = f"[{task_run.info.run_name}]({page})"
        assert link in tags["mlflow.note.content"]
        # it lasts as long as its pair's evaluation, not the few ms of its bookkeeping
        assert run.info.end_time - run.info.start_time > 250
        # its artifacts: the stitched policy, loadable, and the per-episode outcomes of the stitch
        # beside its controls on the same episodes, which the run's figures summarise
        folder = Path(client.download_artifacts(run.info.run_id, "", str(tmp_path / run.info.run_id)))
        episodes = pd.read_csv(folder / "episodes.csv")
        assert len(episodes) == 4 * 2 and episodes["seed"].is_unique
        assert episodes["success"].mean() == pytest.approx(run.data.metrics["success_mean"])
        for role in ("robot_source", "task_source", "oracle"):
            assert episodes[f"{role}_success"].mean() == pytest.approx(run.data.metrics[f"{role}_success"])
        stitched = folder / "stitched.safetensors"
        meta = read_signature(stitched)[1]
        assert (meta["stitched_task_from"], meta["stitched_robot_from"]) == (pair.task_from, pair.robot_from)
        assert load_policy(stitched)[0].actor is not None  # a whole policy, loadable as any other
    # the stage's run lasted the stage and holds its summary
    (stage_run,) = [
        r for r in client.search_runs([experiment.experiment_id]) if r.info.run_name == "zero_shot"
    ]
    assert stage_run.info.status == "FINISHED" and stage_run.data.metrics["ablation.pairs"] == 4
    assert stage_run.data.metrics["ablation.success"] == pytest.approx(table["success_mean"].mean())
    zero_shot_runs = [r for r in found_runs if r.data.tags["ps_ray.stage"] == "zero_shot"]
    assert stage_run.info.end_time >= max(r.info.end_time for r in zero_shot_runs)
    assert stage_run.info.start_time <= min(r.info.start_time for r in zero_shot_runs)
    assert [e.name for e in client.search_experiments()] == ["matrix"]  # no empty Default beside it


def test_batches_are_even_and_fill_whole_rounds_of_concurrent_trials():
    from ps_ray.specs.stage_settings import ZeroShotSpec

    settings = ZeroShotSpec(pairs_per_trial=8)
    assert settings.batch_sizes(40, 2) == [7, 7, 7, 7, 6, 6]  # 3 full rounds, not 8+8 | 8+8 | 8
    assert settings.batch_sizes(16, 2) == [8, 8] and settings.batch_sizes(7, 3) == [3, 2, 2]
    assert settings.batch_sizes(1800, None) == [8] * 225  # a cluster: as Tune places them
    assert settings.batch_sizes(1, 4) == [1] and settings.batch_sizes(0, 2) == []


def test_pairs_run_in_batches_and_a_resume_keeps_each_pair_whatever_batch_it_ran_in(trained_matrix):
    """Batching changes how many Tune trials start, never a pair's figures; a resumed matrix
    evaluates only the pairs that have no result row, whether their batch was cut by a kill after
    its first pair or never started."""
    import shutil

    from ps_ray.pipeline.zero_shot import PAIR_KEY
    from ps_ray.store.attempts import RESULT_FILE, attempts, read_rows

    spec, root = trained_matrix, sweep_layout(trained_matrix).root
    folder = root / "tune_zero_shot"
    if not folder.exists():  # this test alone: the matrix first
        run_zero_shot(spec, episodes=4, repeats=2, progress=False)
    figures = lambda: pd.read_csv(root / "zero_shot.csv").drop(columns="episodes_per_s")  # noqa: E731
    batched = figures()
    # 4 pairs, at most 8 per trial, on 2 slots: two trials of two, not one lone trial of four
    found = attempts(folder, "batch")
    assert sorted(len(json.loads(k)) for k in found) == [2, 2]

    # one batch as a kill leaves it: its first pair reported, its second not: a resume runs the
    # second alone, and one batch never started (its folder gone) runs its two pairs again
    cut, lost_batch = (tries[0] for tries in found.values())
    result = cut / RESULT_FILE
    first, second = (row[PAIR_KEY] for row in read_rows(cut))
    result.write_text(result.read_text().splitlines(keepends=True)[0] + '{"pair_key": "half a li')
    lost = [row[PAIR_KEY] for row in read_rows(lost_batch)]
    shutil.rmtree(lost_batch)
    run_zero_shot(spec, episodes=4, repeats=2, resume=True, progress=False)
    before = {t for tries in found.values() for t in tries}
    new = [json.loads(k) for k, tries in attempts(folder, "batch").items() for t in tries if t not in before]
    # the three pairs without a row, in new batches; the cut one's first pair not run again
    assert sorted(p["key"] for b in new for p in b) == sorted([*lost, second])
    assert [row[PAIR_KEY] for row in read_rows(cut)] == [first]
    pd.testing.assert_frame_equal(figures(), batched)  # batching never changes a pair's figures
    client = mlflow.MlflowClient(f"sqlite:///{root / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("matrix")
    runs = client.search_runs([experiment.experiment_id], "tags.`ps_ray.stage` = 'zero_shot'")
    assert len(runs) == 4  # still one MLflow run per pair, found again on each run
    # a driver killed after the last pair reported, before its stage run closed: the resume that
    # finds nothing left to run closes it, with its summary
    (stage_run,) = client.search_runs([experiment.experiment_id], "tags.`ps_ray.stage_run` = 'zero_shot'")
    client.update_run(stage_run.info.run_id, status="RUNNING")
    run_zero_shot(spec, episodes=4, repeats=2, resume=True, progress=False)
    closed = client.get_run(stage_run.info.run_id)
    assert closed.info.status == "FINISHED" and closed.data.metrics["pairs"] == 4


def test_a_sweep_with_a_damaged_policy_file_is_refused_before_any_trial_starts(trained_matrix, tmp_path):
    """A population member's file damaged in its trial's furthest checkpoint: the zoo reads the
    trial from the one before, as it reads a source alone; damaged in every checkpoint: one line
    naming the furthest, before Ray starts or the stage folder is made."""
    import dataclasses
    import shutil

    from ps_ray.errors import UserError
    from ps_ray.stitching.zoo import ModuleZoo

    copy = tmp_path / "copy"
    shutil.copytree(sweep_layout(trained_matrix).root, copy / trained_matrix.name)
    shutil.rmtree(copy / trained_matrix.name / "tune_zero_shot", ignore_errors=True)
    spec = dataclasses.replace(trained_matrix, storage=str(copy))
    trial = next(
        t for t in (copy / spec.name / "tune").glob("*/") if list(t.glob("checkpoint_*/policy_c01.*"))
    )
    (last,) = trial.glob("checkpoint_*")  # Tune keeps one; two are left by a kill in its rotation
    shutil.copytree(last, trial / "checkpoint_000000")
    policies = sorted(trial.glob("checkpoint_*/policy_c01.safetensors"))
    for number, policy in enumerate(reversed(policies)):
        with open(policy, "r+b") as f:
            f.seek(100)
            f.write(b"damaged")
        if number == 0:  # the furthest checkpoint damaged: the member is read from the one before
            zoo = ModuleZoo.from_sweep(copy / spec.name)
            used = {entry.path.parent for entry in zoo if entry.path.parent.parent == trial}
            assert used == {policies[-2].parent}
    policy = policies[-1]
    with pytest.raises(
        UserError, match=f"{policy.parent}: not a usable ps_ray checkpoint .policy_c01.safetensors"
    ):
        run_zero_shot(spec, episodes=4, repeats=2, progress=False)
    assert not (copy / spec.name / "tune_zero_shot").exists()


def test_a_grid_s_held_out_cell_is_stitched_from_its_modules_beside_its_controls(trained_matrix, tmp_path):
    """The grid stage on the trained matrix (a copy): one grid holds out (panda_l3, q3); the
    zero-shot table gets its held-out pair (both modules from the grid, scored beside the grid's
    own cells, the oracle trained alone and chance) beside the four pairs of the sources trained
    alone, and its MLflow run links to the grid's run."""
    import dataclasses
    import shutil

    from ps_ray.analysis.transfer import co_training_numbers
    from ps_ray.pipeline.grid import run_grids
    from ps_ray.specs.grid import GridSettings

    copy = tmp_path / "copy"
    shutil.copytree(sweep_layout(trained_matrix).root, copy / trained_matrix.name)
    for made_here in ("tune_zero_shot", "mlartifacts", "mlflow.db"):  # a copy keeps no MLflow store
        shutil.rmtree(copy / trained_matrix.name / made_here, ignore_errors=True)
        (copy / trained_matrix.name / made_here).unlink(missing_ok=True)
    q3 = '{"goal_region": "q3", "name": "reach"}'
    grid = GridSettings(held_out=(f"panda_l3/{q3}",))
    spec = dataclasses.replace(
        trained_matrix, storage=str(copy), stages=("train", "grid", "zero_shot"), grid=grid
    )
    (copy / spec.name / "sweep.yaml").write_text(yaml.safe_dump(spec.to_dict(), sort_keys=True))  # moved
    assert not any(r.error for r in run_grids(spec, progress=False))
    table = run_zero_shot(spec, episodes=3, repeats=1, progress=False)
    assert (table["method"] == "ablation").sum() == 4
    (row,) = [r for _, r in table.iterrows() if r["method"] == "ablation co-trained"]
    held = f"held_out=panda_l3/{q3}"
    assert (row["robot"], row["task"]) == ("panda_l3", q3)
    assert row["task_from"].endswith(held) and row["robot_from"].endswith(held)
    assert row["robot_source"] == row["robot_from"] and row["task_source"] == row["task_from"]
    assert row["oracle"] == 'ablation/panda_l3/reach{"goal_region":"q3"}/1/i8'  # trained alone
    assert row["best_control"] == max(
        row["robot_source_success"], row["task_source_success"], row["chance_success"]
    )
    assert row["transfer_gain"] == pytest.approx(row["success_mean"] - row["best_control"])
    assert co_training_numbers(table)["pairs"].tolist() == [1]  # beside the same pair trained alone
    # the grid and zero-shot stages launched the trials their plans list from the spec alone
    assert_stages_launched_their_plans(spec, dataclasses.replace(spec.zero_shot, episodes=3, repeats=1))
    client = mlflow.MlflowClient(f"sqlite:///{copy / spec.name / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("matrix")
    (grid_run,) = client.search_runs([experiment.experiment_id], "tags.`ps_ray.stage` = 'grid'")
    assert grid_run.data.tags["ps_ray.trial_key"] == f"grid/ablation/1/i8/{held}"
    (pair_run,) = [
        r
        for r in client.search_runs([experiment.experiment_id], "tags.`ps_ray.stage` = 'zero_shot'")
        if r.data.tags["ps_ray.task_module"] == row["task_from"]
    ]
    assert pair_run.data.tags["ps_ray.task_module_run"] == grid_run.info.run_id


def test_few_shot_trials_start_from_stitched_weights_beside_unstitched_and_scratch_runs(trained_matrix):
    spec = trained_matrix
    results = run_few_shot(
        spec,
        env_steps=300,
        collect_steps=200,
        max_pairs=1,
        critic_warmup_updates=20,
        halves=True,
        progress=False,
    )
    assert not any(r.error for r in results)
    # a stage run a kill left open is closed by the resume that finds every trial finished
    client = mlflow.MlflowClient(f"sqlite:///{sweep_layout(spec).root / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("matrix").experiment_id
    (stage_run,) = client.search_runs([experiment], "tags.`ps_ray.stage_run` = 'few_shot'")
    client.update_run(stage_run.info.run_id, status="RUNNING")
    settings = dict(env_steps=300, collect_steps=200, max_pairs=1, critic_warmup_updates=20, halves=True)
    assert len(run_few_shot(spec, resume=True, progress=False, **settings)) == len(results)
    closed = client.get_run(stage_run.info.run_id)
    assert closed.info.status == "FINISHED" and closed.data.metrics["trials_finished"] == len(results)
    by_kind = {r.config["trial"]["kind"]: r.config["trial"] for r in results}
    assert sorted(by_kind) == ["robot_module", "scratch", "stitched", "task_module", "unstitched"]
    first = matrix(spec, trained(spec))[0]
    start = by_kind["stitched"]["spec"]["init_policy"]
    assert start and Path(start).exists()
    assert read_signature(start)[1]["task_from"] == first.task_from
    # the halves: one module of the pair kept as it is, the other fresh, in the same target env
    stitched = load_policy(start)[0].actor
    for kind, kept, fresh in (("robot_module", "robot", "task"), ("task_module", "task", "robot")):
        trial = by_kind[kind]
        assert trial["spec"]["task"] == by_kind["stitched"]["spec"]["task"]
        assert read_signature(trial["spec"]["init_policy"])[1]["start"] == kind
        half = load_policy(trial["spec"]["init_policy"])[0].actor
        ours, theirs = getattr(half, kept).state_dict(), getattr(stitched, kept).state_dict()
        assert all(torch.equal(ours[k], theirs[k]) for k in theirs)
        assert not torch.equal(*(next(getattr(a, fresh).parameters()) for a in (half, stitched)))
    # the unstitched start is the pair's robot source as it is, in the same target env
    assert by_kind["unstitched"]["spec"]["init_policy"] == first.robot_from_path
    assert by_kind["unstitched"]["spec"]["task"] == by_kind["stitched"]["spec"]["task"]
    # starts from trained weights fit their critics first; scratch has nothing to fit them to
    assert by_kind["stitched"]["spec"]["critic_warmup_updates"] == 20
    assert by_kind["scratch"]["spec"]["critic_warmup_updates"] == 0
    for points in curves(results).values():
        assert points and points[-1][0] >= 300


def test_an_aligned_start_is_the_zero_shot_stage_s_aligned_stitch_with_its_map_folded_in(
    trained_matrix, tmp_path
):
    """few_shot.translation: the stitch the zero-shot stage aligned (affine) and kept starts a run,
    its map folded into the robot module, so it acts as the stitch that was scored; a translation
    the zero-shot stage did not fit is refused before any start is written."""
    import dataclasses
    import shutil

    from ps_ray.errors import UserError
    from ps_ray.stitching.pair_files import STITCHED_FILE, pair_folder

    copy = tmp_path / "copy"
    shutil.copytree(sweep_layout(trained_matrix).root, copy / trained_matrix.name)
    for made_here in ("tune_zero_shot", "mlartifacts", "mlflow.db", "few_shot"):  # no MLflow store
        shutil.rmtree(copy / trained_matrix.name / made_here, ignore_errors=True)
        (copy / trained_matrix.name / made_here).unlink(missing_ok=True)
    spec = dataclasses.replace(trained_matrix, storage=str(copy))
    table = run_zero_shot(spec, episodes=3, repeats=1, translate={"ablation": ["affine"]}, progress=False)
    assert sorted(table["method"].unique()) == ["ablation", "ablation+affine"]
    settings = dict(env_steps=300, collect_steps=200, max_pairs=1, critic_warmup_updates=20)
    with pytest.raises(UserError, match="few_shot.translation 'affine@outcome': the zero-shot stage kept no"):
        run_few_shot(spec, translation="affine@outcome", progress=False, **settings)
    assert not sweep_layout(spec).stitched.exists()  # nothing written
    results = run_few_shot(
        spec, translation="affine", scratch=False, unstitched=False, progress=False, **settings
    )
    assert not any(r.error for r in results)
    by_kind = {r.config["trial"]["kind"]: r.config["trial"] for r in results}
    assert sorted(by_kind) == ["aligned", "stitched"]
    assert by_kind["aligned"]["key"].startswith("aligned+affine/")
    start = by_kind["aligned"]["spec"]["init_policy"]
    meta = read_signature(start)[1]
    assert (meta["start"], meta["translation"]) == ("aligned", "affine")
    (scored,) = [
        p
        for p in pairs_from_table(sweep_layout(spec).zero_shot_table)
        if p.translation == "affine"
        and (p.task_from, p.robot_from) == (meta["task_from"], meta["robot_from"])
    ]
    kept = load_policy(pair_folder(sweep_layout(spec).tune_zero_shot, scored.key) / STITCHED_FILE)
    folded, unaligned = load_policy(start), load_policy(by_kind["stitched"]["spec"]["init_policy"])
    assert kept[1].translation == "affine" and folded[1].translation == ""
    g = torch.Generator().manual_seed(0)
    task_in = torch.randn(32, folded[1].task_dim, generator=g)
    robot_in = torch.randn(32, folded[1].robot_dim, generator=g)
    with torch.no_grad():
        want, got, plain = (torch.cat(n[0].actor(task_in, robot_in), -1) for n in (kept, folded, unaligned))
    assert torch.allclose(got, want, atol=1e-4 * want.abs().max().item())
    assert not torch.allclose(plain, want, atol=1e-2 * want.abs().max().item())
    for points in curves(results).values():
        assert points and points[-1][0] >= 300
