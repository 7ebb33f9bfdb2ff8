"""Co-trained grids (docs/transfer.md "Co-trained grids"): the spec's refusals, a held-out cell
never sampled, exported cells that act exactly as the grid does, and a resumed grid."""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from ps_ray.envs.grid import GridEnv
from ps_ray.envs.robots import resolve_robot
from ps_ray.envs.tasks import resolve_task
from ps_ray.specs.grid import GridSpec
from ps_ray.specs.train import TrainSpec
from ps_ray.store.layout import sweep_layout
from tests.small_runs import CELL_TRAIN

ROBOTS, TASKS = ["panda", "panda_far"], ["reach_red", "reach_blue"]
HELD_OUT = "panda_far/reach_blue"
SMALL = dict(CELL_TRAIN, seed=3, anchor_episodes=4)


def grid_args(run_dir, env_steps, *extra):
    flags = [f"--{k.replace('_', '-')}={v}" for k, v in SMALL.items()]
    return [
        sys.executable,
        "-m",
        "ps_ray.cli",
        "grid",
        "--robots",
        *ROBOTS,
        "--tasks",
        *TASKS,
        "--held-out",
        HELD_OUT,
        *flags,
        f"--env-steps={env_steps}",
        "--run-dir",
        str(run_dir),
        *extra,
    ]


@pytest.mark.parametrize(
    "held_out, message",
    [
        (
            ["panda_far/reach_green"],
            "held-out cell 'panda_far/reach_green' is not in the grid; its cells: "
            "panda/reach_red, panda/reach_blue, panda_far/reach_red, panda_far/reach_blue",
        ),
        (["panda_far/reach_blue", "panda/reach_blue"], "leave task 'reach_blue' with no trained cell"),
        (["panda_far/reach_red", "panda_far/reach_blue"], "leave robot 'panda_far' with no trained cell"),
        (["panda_far"], "held-out cell 'panda_far' is not 'robot/task'"),
    ],
)
def test_a_grid_refuses_held_out_cells_outside_it_or_that_leave_a_module_untrained(held_out, message):
    with pytest.raises(ValueError) as caught:
        GridSpec.of(TrainSpec(method="ablation"), ROBOTS, TASKS, held_out)
    assert message in str(caught.value)


def test_a_grid_refuses_cells_of_different_widths():
    with pytest.raises(ValueError, match=r"must share their widths .* panda/push \(15, 8, 7\)"):
        GridSpec.of(TrainSpec(method="ablation"), ["panda"], ["reach_red", "push"])


def test_a_grid_with_hindsight_marker_needs_every_task_said_in_a_marker_s_frame():
    base = TrainSpec(method="ablation", task="push_red", hindsight="marker")
    assert GridSpec.of(base, ["panda"], ["push_red", "push_blue"]).base.hindsight == "marker"
    with pytest.raises(ValueError, match="needs a task said in a marker's frame, got task 'push'"):
        GridSpec.of(base, ["panda"], ["push_red", "push"])


@pytest.mark.e2e
def test_ps_ray_grid_answers_bad_input_in_one_line_and_writes_nothing(tmp_path):
    run_dir = tmp_path / "grid"
    bad = grid_args(run_dir, 200)
    bad[bad.index(HELD_OUT)] = "panda_far/reach_green"
    done = subprocess.run(bad, capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "ps-ray grid: error: held-out cell 'panda_far/reach_green' is not in the grid; its cells: "
        "panda/reach_red, panda/reach_blue, panda_far/reach_red, panda_far/reach_blue"
    ]
    assert not run_dir.exists()


def test_the_grid_env_steps_each_cell_in_its_own_physics():
    env = GridEnv([{"robot": "panda", "task": "reach_red"}, {"robot": "panda_far", "task": "reach_red"}])
    obs, info = env.reset(seed=5)
    assert list(obs) == ["c00", "c01"] and env.action_space.shape == (14,)
    action = np.zeros(14, np.float32)
    action[:7] = 1.0  # only the first cell's arm moves
    for _ in range(5):
        after, *_ = env.step(action)
    assert not np.allclose(after["c00"]["robot_state"], obs["c00"]["robot_state"])
    np.testing.assert_allclose(after["c01"]["robot_state"], obs["c01"]["robot_state"], atol=1e-3)
    env.close()


@pytest.fixture(scope="module")
def trained_grid(tmp_path_factory, ray_local):
    """A small ablation grid, trained 300 env steps per cell, then resumed to 500 (joining the
    session's Ray)."""
    run_dir = tmp_path_factory.mktemp("grid") / "run"
    first = subprocess.run(grid_args(run_dir, 300), capture_output=True, text=True)
    assert first.returncode == 0, first.stderr[-3000:]
    second = subprocess.run(grid_args(run_dir, 500), capture_output=True, text=True)
    assert second.returncode == 0, second.stderr[-3000:]
    return run_dir, first.stdout, second.stdout


@pytest.mark.e2e
def test_a_grid_resumes_from_its_checkpoint_and_refuses_another_grid(trained_grid):
    run_dir, _, second = trained_grid
    assert "resumed at 300 env steps per cell" in second
    rows = (run_dir / "metrics.csv").read_text().splitlines()
    steps = [int(r.split(",")[1]) for r in rows[1:]]
    assert steps == list(range(50, 501, 50))  # each step once, across the resume
    assert rows[0].endswith("eval_c00_success,eval_c01_success,eval_c02_success")
    other = grid_args(run_dir, 500)
    other[other.index(HELD_OUT)] = "panda/reach_red"
    done = subprocess.run(other, capture_output=True, text=True)
    assert done.returncode == 2
    assert "holds another grid (changed: held_out); use another --run-dir" in done.stderr


@pytest.mark.e2e
def test_a_resumed_grid_ends_with_the_weights_of_one_never_stopped(trained_grid, tmp_path):
    """Trained to 300 env steps per cell and resumed to 500, or trained to 500 at once: the same
    cell policies, bit for bit (the checkpoint keeps torch's generator; writing a checkpoint's cell
    files draws nothing from it)."""
    from safetensors.torch import load_file

    run_dir, _, _ = trained_grid
    straight = subprocess.run(grid_args(tmp_path / "straight", 500), capture_output=True, text=True)
    assert straight.returncode == 0, straight.stderr[-3000:]
    cells = sorted(p.name for p in (run_dir / "cells").iterdir())
    assert cells == sorted(p.name for p in (tmp_path / "straight" / "cells").iterdir())
    for cell in cells:
        resumed, uninterrupted = (
            load_file(d / "cells" / cell / "policy.safetensors") for d in (run_dir, tmp_path / "straight")
        )
        assert resumed.keys() == uninterrupted.keys()
        assert all(torch.equal(resumed[k], uninterrupted[k]) for k in resumed), cell


def test_a_held_out_cell_is_never_built_stepped_or_replayed(trained_grid, ray_local):
    """The trained grid's folders, and a grid algorithm's own envs and replays: trained cells only."""
    from ps_ray.rllib.grid_train import GridRun

    run_dir, _, _ = trained_grid
    assert sorted(p.name for p in (run_dir / "cells").iterdir()) == [
        "panda-reach_blue",
        "panda-reach_red",
        "panda_far-reach_red",
    ]
    grid = GridSpec.from_mapping(json.loads((run_dir / "grid.json").read_text()))
    run = GridRun(grid, [None, None])
    try:
        run.step()
        run.step()
        envs = [grid_env for grid_env in run.algo.env_runner.env.unwrapped.envs]
        stepped = [(e.robot_spec, e.task_spec) for g in envs for e in g.unwrapped.envs]
        trained = [("panda", "reach_red"), ("panda", "reach_blue"), ("panda_far", "reach_red")]
        assert stepped == [(resolve_robot(r), resolve_task(t)) for r, t in trained]
        assert {k: r.episodes_added for k, r in run.algo.replays.items()} == {"c00": 2, "c01": 2, "c02": 2}
        module = run.algo.env_runner.module
        # (task index, robot index) of each view: reach_blue (1) never meets panda_far (1)
        pairs = {
            (int(c.actor.task is module.actor_tasks["1"]), int(c.actor.robot is module.actor_robots["1"]))
            for c in module.cells
        }
        assert pairs == {(0, 0), (1, 0), (0, 1)}
    finally:
        run.stop()


def test_each_exported_cell_acts_exactly_as_the_grid_and_shares_its_modules(trained_grid, ray_local):
    from ps_ray.nets.policy_file import load_policy
    from ps_ray.rllib.grid_module import GridSACModule
    from ps_ray.rllib.grid_sac import GridSAC

    run_dir, _, _ = trained_grid
    grid = GridSpec.from_mapping(json.loads((run_dir / "grid.json").read_text()))
    cells = {
        name: load_policy(run_dir / "cells" / name / "policy.safetensors")[0]
        for name in ("panda-reach_red", "panda-reach_blue", "panda_far-reach_red")
    }
    # shared modules are exported identically: reach_red's task module in both panda and panda_far cells
    red_panda, red_far = cells["panda-reach_red"], cells["panda_far-reach_red"]
    for a, b in zip(red_panda.actor.task.state_dict().values(), red_far.actor.task.state_dict().values()):
        assert torch.equal(a, b)
    # and the grid's own module, rebuilt from the checkpoint, acts as the exported files do
    from ps_ray.rllib.algo import grid_algo_config

    algo = grid_algo_config(grid, [None, None]).build_algo()
    try:
        algo.load_checkpoint(str(run_dir / "checkpoint"))
        module: GridSACModule = algo.env_runner.module
        env = GridEnv([grid.cell_spec(c).env_config for c in grid.cells])
        obs, _ = env.reset(seed=11)
        batch = {k: {n: torch.as_tensor(v[None]) for n, v in o.items()} for k, o in obs.items()}
        with torch.no_grad():
            grid_actions = module.forward_inference({"obs": batch})["actions"][0]
            exported = []
            for key, name in zip(env.keys, ["panda-reach_red", "panda-reach_blue", "panda_far-reach_red"]):
                from ps_ray.nets.obs import split_obs

                mean, _ = cells[name].actor(*split_obs(batch[key]))
                exported.append(torch.tanh(mean)[0])
        assert torch.equal(grid_actions, torch.cat(exported))
        assert isinstance(algo, GridSAC)
        env.close()
    finally:
        algo.stop()


def test_what_co_training_adds_is_paired_with_the_same_pairs_trained_alone():
    import pandas as pd

    from ps_ray.analysis.transfer import co_training_numbers

    rows = []
    for seed, co, alone in ((1, 0.8, 0.1), (2, 0.7, 0.0), (3, 0.9, 0.2)):
        target = dict(pairing="same_seed", seed=seed, robot_seed=seed, robot="panda_far", task="reach_blue")
        rows += [dict(target, method="ablation co-trained", success_mean=co)]
        rows += [dict(target, method="ablation", success_mean=alone)]
        # another target of the alone sources, which no grid held out: not compared
        rows += [dict(target, task="reach_red", method="ablation", success_mean=0.5)]
    numbers = co_training_numbers(pd.DataFrame(rows))
    assert len(numbers) == 1 and numbers.iloc[0]["pairs"] == 3
    assert numbers.iloc[0]["co-trained minus alone (paired over seeds)"].startswith("+0.70 [")
    assert numbers.iloc[0]["co-trained minus alone (paired over seeds)"].endswith("3/3 seeds up")


@pytest.mark.e2e
def test_a_ps_grid_stage_without_a_train_stage_makes_and_uses_its_anchor_set(tmp_path):
    """`ps-ray run` of a sweep that co-trains `ps` grids and trains nothing alone: the grid stage
    makes the sweep's anchor set itself, and every exported cell's relative projection reads it."""
    import yaml

    from ps_ray.data.anchor_file import load_anchor_set
    from ps_ray.specs.sweep import load_sweep, task_input_dim
    from ps_ray.stitching.zoo import ModuleZoo

    train = {
        k: v for k, v in SMALL.items() if k not in ("method", "seed", "interface_dim", "anchor_episodes")
    }
    path = tmp_path / "ps_grid.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "name": "ps_grid",
                "stages": ["grid"],
                "methods": ["ps"],
                "robots": ROBOTS,
                "tasks": TASKS,
                "seeds": [3],
                "interface_dims": [8],
                "train": {**train, "env_steps": 200},
                "anchors": {"policy": "random", "episodes": 16},
                "grid": {"held_out": [HELD_OUT]},
                "storage": str(tmp_path / "sweeps"),
            }
        )
    )
    done = subprocess.run(
        [sys.executable, "-m", "ps_ray.cli", "run", str(path)], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    spec = load_sweep(path)
    anchor_set = load_anchor_set(sweep_layout(spec).anchor_set(task_input_dim(TASKS[0]), 8))
    cells = ModuleZoo.from_sweep(sweep_layout(spec).root).select(grid=HELD_OUT)
    assert sorted(f"{e.key.robot}/{e.key.task}" for e in cells) == [
        "panda/reach_blue",
        "panda/reach_red",
        "panda_far/reach_red",
    ]
    assert {e.signature.anchor_hash for e in cells} == {anchor_set.hash}
    # the folder records its spec, as a trained sweep's does: zero-shot, few-shot and report take it
    recorded = yaml.safe_load(sweep_layout(spec).spec_file.read_text())
    assert recorded == spec.to_dict()


@pytest.mark.e2e
def test_a_consolidating_grid_distils_its_cells_together_onto_the_relative_cut(tmp_path):
    """ps_distilled in a grid: trained on the raw latent as the ablation, then every cell
    consolidated at once; the exported cells carry the relative cut (projection on), still share
    their modules, and keep the grid's actions (a small action error)."""
    from ps_ray.nets.policy_file import load_policy

    run_dir = tmp_path / "grid"
    method = "--method=ps_distilled+consolidate_updates=40+consolidate_batch_size=64"
    done = subprocess.run(
        grid_args(run_dir, 300, method, "--anchor-episodes=20"), capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads((run_dir / "result.json").read_text())
    assert result["consolidation_gap_after"] < 0.5 * result["consolidation_gap_before"]
    assert result["consolidation_bc"] < 0.05
    cells = {}
    for name in ("panda-reach_red", "panda-reach_blue", "panda_far-reach_red"):
        cells[name], signature = load_policy(run_dir / "cells" / name / "policy.safetensors")
        assert signature.projection_off is False and cells[name].actor.task.projection is not None
    red_panda, red_far, blue_panda = (
        cells[n] for n in ("panda-reach_red", "panda_far-reach_red", "panda-reach_blue")
    )
    for a, b in zip(red_panda.actor.task.state_dict().values(), red_far.actor.task.state_dict().values()):
        assert torch.equal(a, b)  # reach_red's task module, consolidated once for both its cells
    for a, b in zip(
        red_panda.actor.robot.state_dict().values(), blue_panda.actor.robot.state_dict().values()
    ):
        assert torch.equal(a, b)  # panda's robot module, for both of its tasks
    # resumed when finished, it is not consolidated again
    again = subprocess.run(
        grid_args(run_dir, 300, method, "--anchor-episodes=20"), capture_output=True, text=True
    )
    assert again.returncode == 0, again.stderr[-3000:]
    assert (
        json.loads((run_dir / "result.json").read_text())["consolidation_gap_after"]
        == result["consolidation_gap_after"]
    )
