"""A population of sources trained in one learner (docs/cost.md "Populations"): each member draws
its own source's scenes, stops on its own and is exported as an ordinary source; its spec's
refusals; a resumed population keeps what its stopped members were."""

import json

import numpy as np
import pytest
import torch

from ps_ray.envs.grid import GridEnv
from ps_ray.rllib.population_train import member_streaks
from ps_ray.specs.population import PopulationSpec
from ps_ray.specs.reset_seeds import run_block
from ps_ray.specs.train import SpecError, TrainSpec
from ps_ray.store.run_layout import cell_policy_file, cell_result_file, cell_spec_file
from tests.point_env import POINT_ENV
from tests.small_runs import CELL_TRAIN

SMALL = dict(CELL_TRAIN, eval_every=1, env_steps=150)


def member(robot: str, task: str, seed: int, **changes) -> TrainSpec:
    return TrainSpec.from_mapping({**SMALL, "robot": robot, "task": task, "seed": seed, **changes})


MEMBERS = (member("panda", "reach_red", 5), member("panda_far", "reach_blue", 6))


@pytest.mark.parametrize(
    "members, message",
    [
        ((), "a population needs at least one member"),
        ((MEMBERS[0], MEMBERS[0]), "a population's members repeat one"),
        (
            (MEMBERS[0], member("panda", "reach_blue", 5, hidden=64)),
            "may differ only in robot, task, seed; ablation/panda/reach_blue/5/i8 differs from "
            "ablation/panda/reach_red/5/i8 in hidden",
        ),
        ((MEMBERS[0], member("panda", "push", 5)), "must share their widths"),
        ((member("panda", "reach_red", 5, method="ps_distilled"),), "consolidates its actor"),
    ],
)
def test_a_population_refuses_members_that_cannot_stack(members, message):
    with pytest.raises(SpecError, match=message.replace("(", r"\(")):
        PopulationSpec(members)


def test_a_population_spec_round_trips_and_its_key_names_its_members():
    population = PopulationSpec(MEMBERS)
    again = PopulationSpec.from_mapping(json.loads(json.dumps(population.to_dict())))
    assert again == population
    assert population.run_key.startswith("population/ablation/i8/2x")
    other = PopulationSpec((MEMBERS[0], member("panda_far", "reach_blue", 7)))
    assert other.run_key != population.run_key
    budget = PopulationSpec(tuple(member(m.robot, m.task, m.seed, env_steps=999) for m in MEMBERS))
    assert budget.identity() == population.identity()  # a budget may change on resume


def test_each_member_resets_from_its_own_source_s_block():
    offsets = [run_block(m.seed).start for m in MEMBERS]
    env = GridEnv([m.env_config for m in MEMBERS], seed_offsets=offsets)
    assert [env.cell_seed(40, i) for i in range(2)] == [5 * 1_000_003 + 40, 6 * 1_000_003 + 40]
    obs, _ = env.reset(seed=40)
    from ps_ray.envs.core import make

    for key, spec, offset in zip(env.keys, MEMBERS, offsets):
        alone, _ = make(**spec.env_config).reset(seed=40 + offset)
        for name, value in alone.items():
            np.testing.assert_array_equal(obs[key][name], value)
    assert GridEnv([m.env_config for m in MEMBERS]).cell_seed(40, 1) == 81  # a grid's: seed * n + i


def test_a_stopped_member_s_env_is_stepped_no_more_and_the_others_step_as_beside_it():
    """A frozen cell (a stopped member) repeats its latest observation and info through steps and
    resets however it is driven; the live cell's episodes, rewards and episode end are exactly
    those it has beside a cell still stepped; freezing every cell is refused."""
    offsets = [run_block(m.seed).start for m in MEMBERS]
    both, frozen = (GridEnv([m.env_config for m in MEMBERS], seed_offsets=offsets) for _ in range(2))
    rng = np.random.default_rng(0)
    both.reset(seed=3)
    held, held_info = frozen.reset(seed=3)
    frozen.freeze([0])
    for episode in range(2):
        if episode:
            ours, _ = both.reset(seed=4)
            theirs, info = frozen.reset(seed=4)
            for name, value in ours["c01"].items():
                np.testing.assert_array_equal(theirs["c01"][name], value)
            assert info["c00"] is held_info["c00"]
        for step in range(both.max_episode_steps):
            action = rng.uniform(-1, 1, both.action_space.shape).astype(np.float32)
            ours, reward, _, ours_end, _ = both.step(action)
            theirs, live_reward, _, theirs_end, info = frozen.step(action)
            for name, value in ours["c01"].items():
                np.testing.assert_array_equal(theirs["c01"][name], value)
            for name, value in held["c00"].items():  # full-scale actions would move it
                np.testing.assert_array_equal(theirs["c00"][name], value)
            assert live_reward == frozen.envs[1].unwrapped.compute_reward(
                theirs["c01"]["achieved_goal"], theirs["c01"]["desired_goal"], None
            )
            assert theirs_end == ours_end == (step == both.max_episode_steps - 1)
    with pytest.raises(ValueError, match=r"cells \[0, 1\] cannot be frozen in a grid of 2"):
        frozen.freeze([0, 1])


def test_each_member_stops_after_its_own_evaluations_in_a_row():
    row = {"eval_c00_success": 0.9, "eval_c01_success": 0.4}
    assert member_streaks([1, 1], row, 0.9, 2) == ([2, 0], [0])
    assert member_streaks([2, 0], {"eval_c01_success": 0.95}, 0.9, 2) == ([2, 1], [])  # c00 not evaluated
    assert member_streaks([2, 1], {"eval_c00_success": 1.0, "eval_c01_success": 1.0}, 0.9, 2) == ([3, 2], [1])


@pytest.mark.e2e
def test_members_draw_their_sources_scenes_stop_on_their_own_and_resume_as_they_stopped(tmp_path):
    from ps_ray.nets.policy_file import load_policy
    from ps_ray.rllib.loop import TrainingRun, start_local_ray
    from ps_ray.rllib.population_train import PopulationRun
    from ps_ray.rllib.private import runner_envs

    start_local_ray()
    population = PopulationSpec(MEMBERS)
    run = PopulationRun(population, [None, None])
    alone = TrainingRun(MEMBERS[1], None)
    for _ in range(3):
        run.step()
        alone.step()
    # member 1's training episodes start where its source's alone do (same reset seeds)
    ours, theirs = run.algo.replays["c01"].episodes(0, 3), alone.algo.replay.episodes(0, 3)
    for name in ("achieved_goal", "desired_goal", "robot_state"):
        np.testing.assert_array_equal(ours[f"obs/{name}"][:, 0], theirs[f"obs/{name}"][:, 0])
    assert not np.array_equal(
        ours["obs/achieved_goal"][:, 0], run.algo.replays["c00"].episodes(0, 3)["obs/achieved_goal"][:, 0]
    )
    # a member that stops: its env is frozen (stepped no more) and nothing of its goes to its replay
    run.algo.stopped = frozenset({"c00"})
    assert [env.frozen for env in runner_envs(run.algo.env_runner)] == [{0}]
    before = {key: replay.num_transitions for key, replay in run.algo.replays.items()}
    run.step()
    assert run.algo.replays["c00"].num_transitions == before["c00"]
    assert run.algo.replays["c01"].num_transitions > before["c01"]
    alone.stop()
    run.stop()

    # on the point env, each member stops at its own target: finally evaluated and exported then,
    # its file kept while the population trains on; the run ends once every member has stopped
    settings = dict(
        env=POINT_ENV, learning_starts=200, random_episodes=2, episodes_per_step=4, batch_size=64,
        updates_per_step=0.5, eval_every=5, eval_episodes=20, target_success=0.3, target_evals=2,
        env_steps=40_000, hidden=64, checkpoint_every=1000,
    )  # fmt: skip
    points = [TrainSpec.from_mapping({**SMALL, **settings, "seed": seed}) for seed in (1, 2)]
    stopping = PopulationSpec(tuple(points))
    run = PopulationRun(stopping, [None, None])
    rows, first_stop = [], tmp_path / "first_stop"
    for tick in run.ticks():
        rows.append(tick.row)
        if run.stopped and not first_stop.exists():  # a stop is checkpointed at once
            assert tick.checkpoint or run.done  # done: the last tick saves it
            first_stop.mkdir()
            run.save(first_stop)
            at_first_stop = (dict(run.stopped), list(run.streaks), run.env_steps)
            if len(run.stopped) == 1:  # its env is stepped no more; the other member's goes on
                assert [env.frozen for env in runner_envs(run.algo.env_runner)] == [set(run.stopped)]
    assert run.converged and run.env_steps < 40_000
    for index in range(2):  # the step its own evaluations met the target twice in a row
        evals = [
            (r["env_steps"], r[f"eval_c0{index}_success"])
            for r in rows
            if r.get(f"eval_c0{index}_success") is not None
        ]
        met = next(steps for (_, a), (steps, b) in zip(evals, evals[1:]) if a >= 0.3 and b >= 0.3)
        assert run.stopped[index]["env_steps"] == met
    assert run.env_steps == max(f["env_steps"] for f in run.stopped.values())
    folder = tmp_path / "checkpoint"
    folder.mkdir()
    run.save(folder)
    final = run.final_eval()
    live = run.algo.cell_nets()
    run.stop()
    for index, spec in enumerate(stopping.members):
        nets, signature = load_policy(folder / cell_policy_file(index))
        assert (signature.method, signature.interface_dim, signature.robot_dim) == ("ablation", 8, 2)
        assert TrainSpec.from_mapping(json.loads((folder / cell_spec_file(index)).read_text())) == spec
        result = json.loads((folder / cell_result_file(index)).read_text())
        assert result == run.stopped[index] and final[f"c0{index}_success"] == result["success"]
        # a stopped member is updated no more: its actor is as its file holds it, however long
        # the others trained on
        assert all(torch.equal(a, b) for a, b in zip(nets.actor.parameters(), live[index].actor.parameters()))
    # resumed from the first stop's checkpoint: the stop and the member's file as they were
    early = PopulationRun(stopping, [None, None])
    early.restore(first_stop)
    assert (early.stopped, early.streaks, early.env_steps) == at_first_stop
    assert [env.frozen for env in runner_envs(early.algo.env_runner)] == [
        set(early.stopped) if len(early.stopped) == 1 else set()
    ]
    for index in early.stopped:
        assert (first_stop / cell_policy_file(index)).read_bytes() == (
            folder / cell_policy_file(index)
        ).read_bytes()
    early.stop()
    # resumed: done, nothing trained, each member's file and figures as it stopped
    files = {i: (folder / cell_policy_file(i)).read_bytes() for i in range(2)}
    resumed = PopulationRun(stopping, [None, None])
    resumed.restore(folder)
    assert resumed.done and resumed.stopped == run.stopped
    assert list(resumed.ticks())[-1].row["env_steps"] == run.env_steps
    again = tmp_path / "again"
    again.mkdir()
    resumed.save(again)
    resumed.stop()
    assert {i: (again / cell_policy_file(i)).read_bytes() for i in range(2)} == files


def test_a_sweep_s_population_groups_its_sources_in_trials_of_k_and_prices_each_member():
    import dataclasses

    from ps_ray.analysis.cost import project, trial_seconds, workload
    from ps_ray.plan import train
    from ps_ray.specs.sweep import SweepSpec
    from tests.test_cost import RATES

    solo = SweepSpec(
        name="many",
        methods=("ablation", "plain"),
        robots=("panda", "panda_l3"),
        tasks=({"name": "reach", "goal_region": "q1"}, {"name": "reach", "goal_region": "q3"}),
        seeds=(1, 2, 3),
        train={"env_steps": 2000, "learning_starts": 1000},
    )
    spec = dataclasses.replace(solo, population=5)
    trials = train.plan(spec)
    # a method's twelve sources in trials of up to five, in the sweep's order; methods never mixed
    assert [len(t.members) for t in trials] == [5, 5, 2, 5, 5, 2]
    assert all(len({m.spec.method for m in t.members}) == 1 for t in trials)
    assert [m.spec for t in trials for m in t.members] == [t.spec for t in train.plan(solo)]
    leftover = train.plan(dataclasses.replace(solo, population=11))  # one left over trains alone
    assert [len(t.sources) for t in leftover] == [11, 1, 11, 1] and leftover[1] == train.plan(solo)[11]
    # the same work, priced member by member, in six trials instead of 24: each trial's start once
    ours, theirs = workload(spec)[0], workload(solo)[0]
    assert (ours.env_steps, ours.updates, ours.eval_steps) == (
        theirs.env_steps,
        theirs.updates,
        theirs.eval_steps,
    )
    assert len(ours.trials) == 6 and ours.members == (5, 5, 2, 5, 5, 2)
    saved = sum(trial_seconds(theirs, RATES)) - sum(trial_seconds(ours, RATES))
    assert saved == pytest.approx((24 - 6) * RATES.trial_s)
    assert project(spec, rates=RATES).core_s == pytest.approx(project(solo, rates=RATES).core_s - saved)


@pytest.mark.parametrize(
    "changes, message",
    [
        (
            {"search": {"space": {"lr": {"choice": [0.001, 0.0003]}}, "samples": 2}},
            "a search ranks each drawn setting",
        ),
        ({"methods": ["ps_distilled"]}, "method ps_distilled consolidates its actor"),
        ({"resources": {"train": {"compile": True}}}, "a population's batched update runs uncompiled"),
    ],
)
def test_a_sweep_refuses_a_population_it_cannot_form(changes, message):
    from ps_ray.specs.sweep import SweepSpec

    data = {
        "name": "x",
        "methods": ["ablation"],
        "robots": ["panda"],
        "tasks": ["reach"],
        "seeds": [1],
        "population": 2,
    }
    with pytest.raises(SpecError, match=message):
        SweepSpec.from_mapping({**data, **changes})


def test_a_population_on_a_gpu_updates_its_members_for_about_the_price_of_one():
    """On a GPU node a population gets the GPU layout, and its K members' updates cost what one
    source's does while launches bound them (K x the GPU's busy time under the launch time); on
    a CPU its updates are K sources' updates."""
    import dataclasses

    from ps_ray.analysis.cost import workload
    from ps_ray.analysis.hardware import DEFAULT_GPU_RATES, GPU_CLUSTER, GPU_LAYOUT
    from ps_ray.analysis.placement import placed, trial_time
    from ps_ray.specs.resources import StageResources
    from ps_ray.specs.sweep import SweepSpec
    from tests.test_cost import RATES

    data = {"name": "x", "methods": ["ablation"], "robots": ["panda"], "tasks": ["reach"], "seeds": [1, 2]}
    population, notes = placed(SweepSpec.from_mapping({**data, "population": 2}), GPU_CLUSTER)
    assert population["train"] == GPU_LAYOUT and "docs/cluster.md's layout" in notes[0]

    load = workload(SweepSpec.from_mapping(data))[0]
    updates_only = dataclasses.replace(RATES, trial_s=0.0, env_step_s=0.0, eval_step_s=0.0)

    def seconds(r: StageResources, k: int) -> float:
        return trial_time(load.trials[0], load, updates_only, DEFAULT_GPU_RATES, r, 1.0, k)

    one = seconds(GPU_LAYOUT, 1)
    assert 8 * DEFAULT_GPU_RATES.busy_s / GPU_LAYOUT.gpu < DEFAULT_GPU_RATES.launch_s  # launch-bound
    assert seconds(GPU_LAYOUT, 8) == pytest.approx(one)
    assert seconds(GPU_LAYOUT, 64) > one  # busy-bound: 64 x busy / share > launch
    cpu = StageResources(cpu=1)
    assert seconds(cpu, 8) == pytest.approx(8 * seconds(cpu, 1))


def test_the_population_module_s_batched_pass_is_the_grid_s_loop_and_leaves_a_stopped_member_be():
    """The population trial's module runs its members as one batched pass: each member's outputs
    and gradients are what the co-trained grid's loop over cells gives it (same noise); a member
    left out of the batch (stopped) gets no gradient and changes no other's."""
    from ps_ray.nets.sac import sac_forward
    from ps_ray.rllib.algo import population_algo_config
    from ps_ray.rllib.population_module import STACKED, PopulationSACModule

    config = population_algo_config(PopulationSpec(MEMBERS), [None, None])
    env = GridEnv(**config.env_config)
    torch.manual_seed(0)
    module = PopulationSACModule(
        observation_space=env.observation_space,
        action_space=env.action_space,
        model_config=config.model_config,
    )
    rng = torch.Generator().manual_seed(1)
    widths = {"task_in": module.dims.task_dim, "robot_in": module.dims.robot_dim}
    widths |= {"next_task_in": module.dims.task_dim, "next_robot_in": module.dims.robot_dim}
    widths |= {"actions": module.dims.action_dim}
    batch = {
        f"{key}/{c}": torch.randn(16, w, generator=rng) for key in module.keys for c, w in widths.items()
    }
    batch |= {f"{key}/rewards": -torch.ones(16) for key in module.keys}
    noise = tuple(torch.randn(2, 16, module.dims.action_dim, generator=rng) for _ in range(2))

    def grads(members_batch, members_noise):
        module.zero_grad(set_to_none=True)
        fwd = module.forward_members(members_batch, members_noise)
        (fwd[STACKED + "q"].sum() + fwd[STACKED + "q_policy"].sum()).backward()
        return fwd, {n: p.grad.clone() for n, p in module.named_parameters() if p.grad is not None}

    fwd, batched = grads(batch, noise)
    module.zero_grad(set_to_none=True)
    for index, (key, cell) in enumerate(zip(module.keys, module.cells)):
        own = sac_forward(cell, {k.split("/")[1]: v for k, v in batch.items() if k.startswith(key)},
                          (noise[0][index], noise[1][index]))  # fmt: skip
        for name in ("q", "q_twin", "q_target_next", "logp", "q_policy"):
            torch.testing.assert_close(fwd[STACKED + name][index], own[name], rtol=1e-5, atol=1e-6)
        (own["q"].sum() + own["q_policy"].sum()).backward()
    for name, parameter in module.named_parameters():
        if parameter.grad is not None:
            torch.testing.assert_close(batched[name], parameter.grad, rtol=1e-4, atol=1e-6, msg=name)
    assert set(batched) == {n for n, p in module.named_parameters() if p.grad is not None}

    stopped = {k: v for k, v in batch.items() if not k.startswith(module.keys[0])}  # member 0 left
    _, rest = grads(stopped, (noise[0][1:], noise[1][1:]))
    assert rest and not any(name.split(".")[1] == "0" for name in rest)  # tables keyed by member
    for name, grad in rest.items():
        torch.testing.assert_close(grad, batched[name], rtol=1e-4, atol=1e-6, msg=name)


@pytest.mark.e2e
def test_a_population_trains_alike_with_its_members_batched_or_looped(ray_local):
    """The batched update (a GPU's default) and the grid's loop (a CPU's) draw each member's noise
    in the same order from the same stream: two real trainings of one population, one batched and
    one looped, end with the same weights to float rounding (after 20 updates; later, episodes
    acted on by weights a rounding apart part in PyBullet, as any two builds' would)."""
    from ray.rllib.core import DEFAULT_MODULE_ID

    from ps_ray.rllib.algo import population_algo_config

    def trained(batched: bool) -> list[torch.Tensor]:
        config = population_algo_config(PopulationSpec(MEMBERS), [None, None])
        config.rl_module(model_config={**config.model_config, "batched_update": batched})
        algo = config.build_algo()
        try:
            chosen = algo.learner_group.foreach_learner(
                lambda learner: learner.module[DEFAULT_MODULE_ID].batched_update
            )
            assert chosen.result_or_errors[0].get() is batched
            start = [p.detach().clone() for view in algo.cell_nets() for p in view.parameters()]
            for _ in range(2):
                algo.train()
            assert algo.counters["updates"] == 20
            weights = [p.detach().clone() for view in algo.cell_nets() for p in view.parameters()]
            assert any(not torch.equal(a, b) for a, b in zip(start, weights))
            return weights
        finally:
            algo.stop()

    looped, batched = trained(False), trained(True)
    for a, b in zip(looped, batched, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
