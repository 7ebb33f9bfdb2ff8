"""The RLlib path: round trips of checkpoints and policy files, the normaliser's inputs, the evaluation
episodes, learning to reach."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from ps_ray.data.anchors import anchor_hash
from ps_ray.nets.policy_file import load_policy
from ps_ray.nets.sac import NET_NAMES
from ps_ray.rllib.algo import algo_config
from ps_ray.rllib.episodes import train_batch
from ps_ray.specs.methods import method_spec, spec_json
from ps_ray.specs.train import TrainSpec
from ps_ray.store import checkpoint
from ps_ray.store.signature import Signature, read_signature
from tests.code_paths import PS_CONSOLIDATED
from tests.point_env import POINT_ENV

SMALL = dict(
    env=POINT_ENV,
    hidden=64,
    interface_dim=16,
    learning_starts=200,
    random_episodes=2,
    episodes_per_step=4,
    num_envs=2,
    eval_every=1000,
    batch_size=64,
)


def _outputs(nets, batch) -> dict[str, torch.Tensor]:
    args = (batch["task_in"], batch["robot_in"])
    with torch.no_grad():
        mean, log_std = nets.actor(*args)
        out = {"mean": mean, "log_std": log_std}
        for name in NET_NAMES[1:]:
            out[name] = getattr(nets, name)(*args, batch["actions"])
    return out


def _on_learner(algo, fn):
    """``fn(learner)`` on the (local) learner, through LearnerGroup's public API."""
    return algo.learner_group.foreach_learner(fn).result_or_errors[0].get()


def _learner_module(algo):
    return _on_learner(algo, lambda learner: learner.module["default_policy"])


TARGETS = ("target_critic", "target_critic_twin")


@pytest.fixture(scope="module", params=["ps", "ps+center=standard+norm=layer"])
def trained(ray_local, tmp_path_factory, request):
    spec = TrainSpec(method=request.param, anchors=None, **SMALL)
    anchors = np.random.default_rng(0).uniform(-0.5, 0.5, (16, 2)).astype(np.float32)
    algo = algo_config(spec, anchors).build_algo()
    module = _learner_module(algo)
    initial = {name: [p.detach().clone() for p in getattr(module, name).parameters()] for name in TARGETS}
    for _ in range(4):
        algo.train()
    path = tmp_path_factory.mktemp("ckpt")
    algo.save_checkpoint(str(path))
    checkpoint.seal(path)  # as the run loop does: only a sealed checkpoint is restored
    yield spec, anchors, algo, path, initial
    algo.stop()


def test_training_steps_update_weights_and_targets(trained):
    _, _, algo, _, initial = trained
    assert algo.counters["updates"] > 0
    module = _learner_module(algo)
    for online_name, target_name in zip(("critic", "critic_twin"), TARGETS):
        online, target = getattr(module, online_name), getattr(module, target_name)
        lag = max((o - t).abs().max().item() for o, t in zip(online.parameters(), target.parameters()))
        assert lag > 0, "targets must lag the online critics (Polyak, not a copy)"
        moved = max((t - t0).abs().max().item() for t, t0 in zip(target.parameters(), initial[target_name]))
        assert moved > 0, "targets must follow the online critics (a missing Polyak update leaves them)"


def test_checkpoint_round_trip_restores_every_net_and_the_replay(trained):
    spec, anchors, algo, path, _ = trained
    batch = train_batch(algo.replay.sample(32))
    fresh = algo_config(spec, anchors).build_algo()
    try:
        assert not torch.equal(
            _outputs(_learner_module(fresh), batch)["critic"],
            _outputs(_learner_module(algo), batch)["critic"],
        )
        fresh.load_checkpoint(str(path))
        # Every tensor of actor, critics and target critics (normaliser statistics included) is
        # restored bit for bit ...
        saved, restored = algo.learner_state(), fresh.learner_state()
        assert saved.keys() == restored.keys()
        for key in saved:
            assert saved[key].dtype == restored[key].dtype and torch.equal(saved[key], restored[key]), key
        # ... so actions and Q values agree (computed back to back, same torch settings).
        before, after = _outputs(_learner_module(algo), batch), _outputs(_learner_module(fresh), batch)
        for key in before:
            assert torch.equal(before[key], after[key]), key
        assert fresh.counters == algo.counters
        assert fresh.iteration == algo.iteration == 4
        # Adam's slots and the temperature come back too, so a resumed run steps as it would have.
        saved, restored = (_on_learner(a, lambda learner: learner.training_state()) for a in (algo, fresh))
        assert any(k.startswith("optimizer.") and k.endswith(".exp_avg_sq") for k in saved)
        assert saved.keys() == restored.keys()
        for key in saved:
            assert torch.equal(saved[key], restored[key]), key
        # ps_ray's own files only: nothing in a checkpoint is a pickle.
        assert not [p for p in path.rglob("*") if p.suffix in (".pkl", ".pickle", ".pt")]
        assert fresh.replay.num_transitions == algo.replay.num_transitions > 0
        assert fresh.replay.episodes_added == algo.replay.episodes_added
    finally:
        fresh.stop()


def test_policy_file_round_trip_keeps_actions_q_and_targets(trained, tmp_path):
    spec, anchors, algo, _, _ = trained
    signature = Signature(
        method=spec.method, interface_dim=16, hidden=64, anchor_hash=anchor_hash(anchors), **algo.replay_dims
    )
    written = algo.export_policy(tmp_path / "policy.safetensors", signature)
    nets, loaded_signature = load_policy(tmp_path / "policy.safetensors")
    assert (
        loaded_signature
        == written
        == dataclasses.replace(signature, settings=spec_json(method_spec(spec.method)))
    )
    assert read_signature(tmp_path / "policy.safetensors")[0].anchor_hash == anchor_hash(anchors)
    batch = train_batch(algo.replay.sample(32))
    expected, got = _outputs(_learner_module(algo), batch), _outputs(nets, batch)
    for key in expected:
        assert torch.equal(expected[key], got[key]), key


@pytest.mark.slow
def test_sac_her_learns_to_reach_with_the_panda(ray_local):
    """Real PyBullet physics, the real RLlib learner, hindsight goals in the normaliser: within 6k
    env steps the greedy policy reaches most goals of the paper's reach task on fresh episodes
    (a one-core run took ~2 min; one saw 0.65 at 5k where the untrained policy reaches none)."""
    spec = TrainSpec(
        method="ablation", task="reach", hidden=64, interface_dim=16, eval_every=10**6, learning_starts=1000
    )
    algo = algo_config(spec).build_algo()
    try:
        untrained = algo.evaluate_greedy(40, final=True)
        evaluations = []
        for budget in (4000, 5000, 6000):
            while algo.counters["env_steps"] < budget:
                algo.train()
            evaluations.append(algo.evaluate_greedy(40, final=True)["success"])
    finally:
        algo.stop()
    # Runs differ, hence the best of three checkpoints (what `ps-ray train` keeps as best_policy).
    assert untrained["success"] <= 0.1, untrained
    assert max(evaluations) >= 0.5, evaluations


def test_training_episodes_get_fresh_goals_and_evaluations_fixed_ones(ray_local):
    """RLlib re-seeds its envs on every num_episodes sample; ps_ray must not replay old goals."""
    spec = TrainSpec(method="ablation", **{**SMALL, "learning_starts": 10**6, "eval_every": 10**6})
    algo = algo_config(spec).build_algo()
    try:
        for _ in range(3):
            algo.train()
        stored = algo.replay.episodes(*algo.replay.live_range())["obs/desired_goal"][:, 0]
        assert len(np.unique(stored.round(6), axis=0)) == algo.replay.num_episodes == 12
        first = [
            ep.get_observations()["desired_goal"][0]
            for ep in algo.collect_episodes(explore=False, random=False, n=2)
        ]
        second = [
            ep.get_observations()["desired_goal"][0]
            for ep in algo.collect_episodes(explore=False, random=False, n=2)
        ]
        np.testing.assert_array_equal(first, second)
    finally:
        algo.stop()


def test_the_final_evaluation_reads_episodes_the_stopping_rule_never_read(ray_local):
    """The periodic evaluations (what the stopping rule reads) repeat one set of episodes; the
    final evaluation, twice as many, repeats another set that shares no episode with it."""
    spec = TrainSpec(method="ablation", **{**SMALL, "learning_starts": 10**6, "eval_every": 10**6})
    algo = algo_config(spec).build_algo()

    def goals(n: int, **final) -> set[tuple[float, ...]]:
        episodes = algo.collect_episodes(explore=False, random=False, n=n, **final)
        return {tuple(ep.get_observations()["desired_goal"][0].round(6)) for ep in episodes}

    try:
        periodic, final = goals(4), goals(8, final=True)
        assert len(periodic) == 4 and len(final) == 8
        assert not periodic & final
        assert goals(8, final=True) == final and goals(4) == periodic
    finally:
        algo.stop()


@pytest.mark.parametrize("method", ["ps", "ps+hindsight_norm=false"])
def test_the_task_normaliser_sees_the_hindsight_goals_training_reads(ray_local, method):
    """On the marker family every real goal is the zero offset; the goals training reads are
    mostly later achieved goals (~0.2 m away). The learner's task normaliser must cover them: after
    20 episodes, under 1% of training samples have a clipped goal component. With
    ``hindsight_norm=false`` (the normaliser before that fix, for before/after studies) most do."""
    from ps_ray.envs.goals import GOAL_DIM

    spec = TrainSpec(
        method=method,
        **{**SMALL, "env": None, "task": "reach_red", "learning_starts": 10**6, "eval_every": 10**6},
    )
    anchors = np.random.default_rng(0).uniform(-0.1, 0.2, (16, 9)).astype(np.float32)
    algo = algo_config(spec, anchors).build_algo()
    try:
        for _ in range(5):
            algo.train()
        assert algo.replay.num_episodes == 20
        batch = train_batch(algo.replay.sample(4096))
        norm = _learner_module(algo).actor.task.norm
        with torch.no_grad():
            goal = norm(batch["task_in"])[:, -GOAL_DIM:]
        clipped = (goal.abs() >= norm.clip).any(dim=1).float().mean().item()
        if method == "ps":
            assert clipped < 0.01, clipped
        else:
            assert clipped > 0.5, clipped
        real = algo.replay.episodes(0, 20)["obs/desired_goal"]
        assert np.abs(real).max() == 0.0  # what the normaliser would otherwise have seen
    finally:
        algo.stop()


def _run_state(
    spec: TrainSpec, iterations: int, export_to: Path | None = None
) -> tuple[dict[str, torch.Tensor], np.ndarray]:
    """A run's learner state and actions after ``iterations`` steps; with ``export_to``, a policy
    file written there after every step (as `ps-ray train` writes its best policy)."""
    algo = algo_config(spec).build_algo()
    signature = Signature(method=spec.method, interface_dim=16, hidden=64, anchor_hash="", **algo.replay_dims)
    try:
        for _ in range(iterations):
            algo.train()
            if export_to is not None:
                algo.export_policy(export_to / "policy.safetensors", signature)
        return algo.learner_state(), algo.replay.episodes(*algo.replay.live_range())["actions"]
    finally:
        algo.stop()


def test_a_seed_repeats_its_run_bit_for_bit(ray_local):
    """Warm-up random actions, exploration, replay sampling and updates all follow the seed: two
    runs of one spec end with equal weights, and another seed with other ones."""
    spec = TrainSpec(method="ablation", **{**SMALL, "learning_starts": 100})
    first, first_actions = _run_state(spec, 3)
    again, again_actions = _run_state(spec, 3)
    other, other_actions = _run_state(dataclasses.replace(spec, seed=spec.seed + 1), 3)
    assert len(first_actions) == 12  # 2 warm-up episodes of random actions, then policy episodes
    np.testing.assert_array_equal(first_actions, again_actions)
    for key, value in first.items():
        assert torch.equal(value, again[key]), key
    assert not np.array_equal(first_actions, other_actions)
    assert any(not torch.equal(value, other[key]) for key, value in first.items())


def test_writing_policy_files_does_not_change_the_run(ray_local, tmp_path):
    """Building nets to write (or read) a policy file draws no initial weights from the run's
    random stream: a run that wrote a file after every step ends as one that wrote none, so a
    sweep's trial and `ps-ray train` (which also writes each new best policy) train alike."""
    spec = TrainSpec(method="ablation", **{**SMALL, "learning_starts": 100})
    quiet, quiet_actions = _run_state(spec, 3)
    written, written_actions = _run_state(spec, 3, export_to=tmp_path)
    assert (tmp_path / "policy.safetensors").exists()
    np.testing.assert_array_equal(quiet_actions, written_actions)
    for key, value in quiet.items():
        assert torch.equal(value, written[key]), key


def test_a_run_can_start_from_given_weights(ray_local, tmp_path):
    """Few-shot fine-tuning starts from the stitched weights, not a fresh initialisation."""
    from ps_ray.nets.from_signature import nets_state
    from ps_ray.nets.policy_file import save_policy
    from ps_ray.nets.sac import build_sac_nets
    from ps_ray.rllib.loop import TrainingRun, prepare_anchors, read_inputs
    from ps_ray.specs.dims import NetDims

    anchors = np.random.default_rng(1).uniform(-0.5, 0.5, (16, 2)).astype(np.float32)
    nets = build_sac_nets("ps", NetDims(2, 2, 2), interface_dim=16, hidden=64, anchors=anchors)
    signature = Signature(
        method="ps",
        interface_dim=16,
        hidden=64,
        anchor_hash=anchor_hash(anchors),
        task_dim=2,
        robot_dim=2,
        action_dim=2,
    )
    save_policy(tmp_path / "start.safetensors", nets, signature)
    spec = TrainSpec(method="ps", init_policy=str(tmp_path / "start.safetensors"), **SMALL)
    anchor_set = prepare_anchors(spec, tmp_path, read_inputs(spec))
    assert anchor_set.hash == signature.anchor_hash
    run = TrainingRun(spec, anchor_set)
    try:
        loaded = run.algo.learner_state()
        for key, value in nets_state(nets).items():
            assert torch.equal(loaded[key], value), key
    finally:
        run.stop()


def test_training_settings_come_from_the_train_spec_alone():
    import dataclasses

    from ps_ray.rllib.sac_her import TRAIN_SETTINGS, ModularSACConfig

    defaults = TrainSpec()
    fresh = ModularSACConfig()  # its defaults are TrainSpec's, not a second copy
    assert {name: getattr(fresh, name) for name in TRAIN_SETTINGS} == {
        name: getattr(defaults, name) for name in TRAIN_SETTINGS
    }
    changed = {"eval_every": 3, "eval_episodes": 7, "updates_per_step": 0.25, "learning_starts": 50}
    config = algo_config(dataclasses.replace(defaults, method="ablation", **changed))
    assert {name: getattr(config, name) for name in changed} == changed
    assert (config.train_batch_size, config.gamma, config.tau) == (256, 0.98, 0.005)
    with pytest.raises(TypeError):  # an unknown setting is not silently stored
        ModularSACConfig().training(eval_interval=5)


def test_every_train_setting_is_documented_in_the_help(cli):
    import dataclasses

    out, _ = cli("train", "--help").communicate(timeout=120)
    for f in dataclasses.fields(TrainSpec):
        assert f.metadata["help"], f.name
        flag = f"--{f.name.replace('_', '-')}"
        assert flag in out and f"(default {getattr(TrainSpec(), f.name)})" in " ".join(out.split()), flag


@pytest.mark.parametrize(
    "method",
    [
        PS_CONSOLIDATED,
        "ps_distilled",
    ],
)
def test_a_consolidated_actor_reaches_the_env_runners_that_act_and_evaluate(ray_local, method):
    """Consolidation changes the learner's actor outside an RLlib update; the env runner that
    collects episodes and runs the final evaluation must act with it, not with the actor before
    (for ps_distilled: with its relative projection switched on)."""
    spec = TrainSpec(method=method, anchors=None, **SMALL)
    anchors = np.random.default_rng(0).uniform(-0.5, 0.5, (16, 2)).astype(np.float32)
    algo = algo_config(spec, anchors).build_algo()
    try:
        for _ in range(3):
            algo.train()
        runner = algo.env_runner_group.local_env_runner
        before = {k: v.clone() for k, v in runner.module.actor.state_dict().items()}
        # 100 of the default 2,000 updates: enough to move the actor, which is all this checks
        stats = algo.consolidate_actor(dataclasses.replace(method_spec(method).consolidate, updates=100))
        assert stats["gap_after"] < stats["gap_before"]
        assert runner.module.actor.task.projection is not None
        learner_actor = _learner_module(algo).actor.state_dict()
        acting = runner.module.actor.state_dict()
        assert any(not torch.equal(before[k], acting[k]) for k in acting)
        for key, value in learner_actor.items():
            assert torch.equal(acting[key], value), key
    finally:
        algo.stop()


def test_a_deferred_relative_method_trains_as_the_ablation_bit_for_bit(ray_local):
    """ps_distilled's projection is off until consolidation: its training is the ablation's, so its
    learning speed is the ablation's by construction. Same seed, same updates: equal weights."""
    anchors = np.random.default_rng(0).uniform(-0.5, 0.5, (16, 2)).astype(np.float32)
    states = {}
    for method, given in (("ablation", None), ("ps_distilled", anchors)):
        algo = algo_config(TrainSpec(method=method, anchors=None, **SMALL), given).build_algo()
        try:
            for _ in range(3):
                algo.train()
            states[method] = {k: v.clone() for k, v in _learner_module(algo).state_dict().items()}
        finally:
            algo.stop()
    deferred = {k for k in states["ps_distilled"] if ".relative." in k or k.endswith("relative_on")}
    assert deferred == {"actor.task.relative.anchors", "actor.task.relative_on"}
    assert not states["ps_distilled"]["actor.task.relative_on"]
    shared = {k: v for k, v in states["ps_distilled"].items() if k not in deferred}
    assert shared.keys() == states["ablation"].keys()
    for key, value in shared.items():
        assert torch.equal(value, states["ablation"][key]), key


def test_a_critic_warm_up_moves_the_critics_and_leaves_the_actor_and_temperature(ray_local):
    """Few-shot's sound start: for ``critic_warmup_updates`` updates only the critics learn, then
    the actor follows; the count survives a checkpoint (it is the critic optimiser's step)."""
    spec = TrainSpec(method="ablation", anchors=None, critic_warmup_updates=10_000, **SMALL)
    algo = algo_config(spec, None).build_algo()
    try:
        before = {k: v.clone() for k, v in algo.learner_state().items()}
        for _ in range(3):
            algo.train()
        after = algo.learner_state()
        assert algo.counters["updates"] > 0
        moved = lambda prefix: any(  # noqa: E731  (weights; input statistics follow the data)
            not torch.equal(after[k], before[k]) for k in before if k.startswith(prefix) and ".norm." not in k
        )
        assert moved("critic.") and moved("critic_twin.")
        assert not moved("actor.") and _log_alpha(algo) == pytest.approx(np.log(SPEC_ALPHA))
        done = _on_learner(algo, lambda learner: learner.updates_done("default_policy"))
        assert done == algo.counters["updates"]
    finally:
        algo.stop()
    plain = TrainSpec(method="ablation", anchors=None, **SMALL)
    algo = algo_config(plain, None).build_algo()
    try:
        for _ in range(3):
            algo.train()
        assert _log_alpha(algo) != pytest.approx(np.log(SPEC_ALPHA))  # without it, alpha learns
    finally:
        algo.stop()


SPEC_ALPHA = TrainSpec().initial_alpha


def _log_alpha(algo) -> float:
    return _on_learner(algo, lambda learner: float(learner.curr_log_alpha["default_policy"].detach()))


def test_a_checkpoint_holding_the_whole_replay_buffer_restores_into_a_run_with_segments(ray_local, tmp_path):
    """Checkpoints written before replay segments (replay.npz inside) resume; the next checkpoint
    names segments instead, and a run restored from either samples the same transitions."""
    from ps_ray.rllib.loop import TrainingRun
    from ps_ray.store import replay

    spec = TrainSpec(method="ablation", **SMALL)
    whole, segmented, again = (
        TrainingRun(spec),
        TrainingRun(spec, replay_store=tmp_path / "segments"),
        TrainingRun(spec, replay_store=tmp_path / "segments"),
    )
    try:
        whole.step()
        whole.step()
        whole.save(tmp_path / "old")
        assert (tmp_path / "old" / "replay.npz").is_file()
        segmented.restore(tmp_path / "old")
        segmented.save(tmp_path / "new")
        assert not (tmp_path / "new" / "replay.npz").exists()
        assert (tmp_path / "new" / replay.MANIFEST_FILE).is_file() and list(
            (tmp_path / "segments").glob("*.npz")
        )
        again.restore(tmp_path / "new")
        held = whole.algo.replay.live_range()
        assert held[1] > 0 and segmented.algo.replay.live_range() == again.algo.replay.live_range() == held
        samples = [run.algo.replay.sample(32) for run in (whole, segmented, again)]
        for key in samples[0]:
            assert np.array_equal(samples[0][key], samples[1][key]) and np.array_equal(
                samples[0][key], samples[2][key]
            )
    finally:
        for run in (whole, segmented, again):
            run.stop()
