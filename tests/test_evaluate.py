"""Batched zero-shot evaluation on real envs: fixed seeds, the authors' touching denominator."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ps_ray.envs import make
from ps_ray.nets.obs import split_obs
from ps_ray.nets.policy import GreedyPolicy
from ps_ray.nets.sac import build_sac_nets
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import uses_anchors
from ps_ray.stitching.evaluate import EpisodeRecord, evaluate, summarize

torch.set_num_threads(1)

PUSH = NetDims(15, 8, 7)


def nets_for(method: str, dims: NetDims = PUSH, seed: int = 0):
    torch.manual_seed(seed)
    anchors = np.random.default_rng(seed).normal(size=(8, dims.task_dim)) if uses_anchors(method) else None
    return build_sac_nets(method, dims, interface_dim=8, hidden=16, anchors=anchors)


def lean_if_goal_ahead(obs: dict) -> np.ndarray:
    """Scripted, batch-independent: lean the shoulder forward (and over the object) when the goal
    lies at x > 0, else stand still; some episodes touch the object, others do not."""
    actions = np.zeros((len(obs["desired_goal"]), 7), np.float32)
    actions[:, 1] = obs["desired_goal"][:, 0] > 0
    return actions


def reference_rollouts(seeds: list[int]) -> list[tuple[bool, bool, bool]]:
    """(success, touched, initially successful) per seed, one env, written out by hand."""
    env, out = make("panda", "push"), []
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        initially, touched = info["initially_successful"], info["touching"]
        for t in range(50):
            obs, _, _, _, info = env.step(lean_if_goal_ahead({k: v[None] for k, v in obs.items()})[0])
            touched |= info["touching"] and t < 49  # checked before each of the 50 actions
        out.append((info["is_success"], touched, initially))
    env.close()
    return out


def record(
    repeat: int, success: bool, touched: bool, initially: bool, contact: bool = False
) -> EpisodeRecord:
    return EpisodeRecord(repeat, 0, success, touched, contact, initially, *((0.0,) * 3,) * 4)


def test_summary_excludes_initially_successful_episodes_from_touching():
    records = [
        record(0, True, True, False, True),
        record(0, False, True, False),
        record(0, True, False, True),
        record(0, False, False, False),
        record(1, True, True, False),
        record(1, True, False, False),
        record(1, True, True, True),
        record(1, False, False, True),
    ]
    out = summarize(records)
    assert out["success_per_repeat"] == [0.5, 0.75]
    assert out["touching_per_repeat"] == pytest.approx([2 / 3, 1 / 2])  # not 2/4 and 2/4
    assert out["contact_per_repeat"] == pytest.approx([1 / 3, 0.0])
    assert out["initially_successful_per_repeat"] == [1, 2]
    assert out["success_mean"] == pytest.approx(0.625) and out["success_std"] == pytest.approx(0.125)
    assert out["touching_mean"] == pytest.approx(7 / 12) and out["touching_std"] == pytest.approx(1 / 12)
    # a repeat whose episodes all started successful has no touching rate; it is left out
    only_initial = summarize([record(0, True, False, True), record(1, False, True, False)])
    assert math.isnan(only_initial["touching_per_repeat"][0]) and only_initial["touching_mean"] == 1.0


@pytest.mark.e2e
def test_end_to_end_rates_match_a_hand_rollout_with_initially_successful_episodes():
    episodes, repeats, seed = 20, 2, 0
    result = evaluate(
        lean_if_goal_ahead, "panda", "push", episodes=episodes, repeats=repeats, seed=seed, num_envs=3
    )
    for r in range(repeats):
        ref = reference_rollouts([seed + r * episodes + j for j in range(episodes)])
        eligible = [touched for _, touched, initially in ref if not initially]
        assert 0 < len(eligible) < episodes  # some episodes start successful
        assert result["success_per_repeat"][r] == np.mean([s for s, _, _ in ref])
        assert result["touching_per_repeat"][r] == np.mean(eligible)
        assert result["initially_successful_per_repeat"][r] == episodes - len(eligible)
        # the plain average over all episodes differs: the denominator matters here
        naive = np.mean([touched for _, touched, _ in ref])
        assert 0 < naive < 1 and naive != pytest.approx(result["touching_per_repeat"][r])


@pytest.mark.e2e
def test_every_policy_sees_the_same_episodes_and_num_envs_changes_nothing():
    ps = evaluate(nets_for("ps"), "panda", "push", episodes=3, repeats=2, seed=7, num_envs=2)
    plain = evaluate(nets_for("plain", seed=1), "panda", "push", episodes=3, repeats=2, seed=7, num_envs=4)
    keys = ("repeat", "seed", "goal", "start", "initially_successful")
    starts = lambda res: [tuple(r[k] for k in keys) for r in res["records"]]  # noqa: E731
    assert starts(ps) == starts(plain)
    assert [r["seed"] for r in ps["records"]] == [7, 8, 9, 10, 11, 12]
    other = evaluate(nets_for("ps"), "panda", "push", episodes=3, repeats=2, seed=8, num_envs=2)
    assert starts(other)[:5] != starts(ps)[:5] and starts(other)[0][2:] == starts(ps)[1][2:]
    # the digest a stitched pair and its controls are checked by (ps_ray.pipeline.zero_shot)
    assert ps["episodes_digest"] == plain["episodes_digest"] != other["episodes_digest"]
    one = evaluate(lean_if_goal_ahead, "panda", "push", episodes=5, repeats=1, seed=3, num_envs=1)
    four = evaluate(lean_if_goal_ahead, "panda", "push", episodes=5, repeats=1, seed=3, num_envs=4)
    assert one["records"] == four["records"]


@pytest.mark.parametrize(
    "method, translation",
    [
        ("ps", None),
        ("ps+center=standard+norm=layer", None),
        ("ps+center=mean+norm=layer", None),
        ("ablation", None),
        ("devin", None),
        ("plain", None),
        ("ps+center=standard+norm=layer", "affine"),
        ("ablation", "orthogonal"),
        ("ps_distilled", None),  # its projection still off, as while training
        ("ps_distilled", "switched"),
    ],
)
@pytest.mark.filterwarnings("error::torch.jit.TracerWarning")
def test_fast_actions_match_the_actor(method, translation):
    nets = nets_for(method)
    if translation == "switched":
        nets.actor.task.switch_relative_on()
        translation = None
    if translation:  # a translated stitch of the policy with another seed of it
        from ps_ray.nets.from_signature import signature_of
        from ps_ray.stitching.stitch import stitch_policies

        sig = signature_of(nets, method, 8, 16)
        other = nets_for(method, seed=0)
        states = np.random.default_rng(0).normal(size=(256, PUSH.task_dim)).astype(np.float32)
        nets, _ = stitch_policies((nets, sig), (other, sig), translation=translation, fit_states=states)
        with torch.no_grad():  # far from the identity, so a path that skipped it would show
            nets.actor.translate.weight.normal_(generator=torch.Generator().manual_seed(1))
    env = make("panda", "push")
    obs = [env.reset(seed=s)[0] for s in range(5)]
    env.close()
    batch = {k: np.stack([o[k] for o in obs]) for k in obs[0]}
    with torch.no_grad():
        mean, _ = nets.actor.eval()(*split_obs(batch))
    want = torch.tanh(mean).numpy()  # the actor's own forward
    np.testing.assert_allclose(GreedyPolicy(nets.actor, fast=True)(batch), want, atol=1e-6)
    np.testing.assert_array_equal(GreedyPolicy(nets.actor)(batch), want)
    single = {k: v[0] for k, v in batch.items()}  # one observation, no batch axis
    np.testing.assert_allclose(GreedyPolicy(nets.actor)(single), want[0], atol=1e-6)


def test_refuses_a_policy_that_does_not_fit_the_env_and_bad_counts():
    with pytest.raises(ValueError, match="action_dim 7 vs env 8"):
        evaluate(nets_for("ps"), "panda", "pick_cube", episodes=1, repeats=1)
    with pytest.raises(ValueError, match="task_dim 15 vs env 3"):
        evaluate(nets_for("ablation"), "panda", "reach", episodes=1, repeats=1)
    with pytest.raises(ValueError, match="episodes must be a positive integer"):
        evaluate(lean_if_goal_ahead, "panda", "push", episodes=0)


def test_progress_line_per_repeat(capsys):
    evaluate(lean_if_goal_ahead, "panda", "push", episodes=2, repeats=3, num_envs=2, verbose=True)
    lines = [line for line in capsys.readouterr().out.splitlines() if "repeat" in line]
    assert [line.split("repeat ")[1][:3] for line in lines] == ["1/3", "2/3", "3/3"]


@pytest.mark.e2e
def test_envs_lent_again_give_the_episodes_of_new_ones(monkeypatch):
    """Evaluation keeps its envs between calls; a push env lent again, after other episodes and
    after an evaluation of another task, gives the records a new env gives (physics included)."""
    from ps_ray.stitching import evaluate as evaluation

    policy = GreedyPolicy(nets_for("ablation").actor, fast=True)
    first = evaluate(policy, "panda", "push", episodes=4, repeats=1, num_envs=2, seed=3)
    evaluate(policy, "panda", "push", episodes=4, repeats=1, num_envs=2, seed=40)
    evaluate(lambda obs: np.ones((len(obs["robot_state"]), 7)), "panda", "reach", episodes=2, repeats=1)
    again = evaluate(policy, "panda", "push", episodes=4, repeats=1, num_envs=2, seed=3)
    monkeypatch.setattr(evaluation, "_ENVS", evaluation.EnvPool())
    fresh = evaluate(policy, "panda", "push", episodes=4, repeats=1, num_envs=2, seed=3)
    assert again["records"] == first["records"] == fresh["records"]
    assert len({r["end_effector"] for r in first["records"]}) == 4  # the episodes differ


def test_the_env_pool_keeps_the_envs_of_the_last_target_only():
    """An env holds ~90 MB: the pool keeps the envs of the most recent target (a pair's stitch and
    its controls share them) and closes the rest; a negative target count is refused."""
    from ps_ray.specs.names import EnvPart
    from ps_ray.stitching.evaluate import EnvPool

    pool = EnvPool()
    red, blue = (EnvPart("panda"), EnvPart("reach_red")), (EnvPart("panda"), EnvPart("reach_blue"))
    with pool.lend(*red, 2) as first:
        pass
    with pool.lend(*red, 2) as again:
        assert again == first  # the same env objects, lent again
    with pool.lend(*blue, 2):
        pass
    assert all(env.sim.client is None for env in first)  # closed: another target came
    with pool.lend(*red, 2) as new:
        assert all(env.sim.client is not None for env in new) and not set(map(id, new)) & set(map(id, first))
    with pytest.raises(ValueError, match="0 or more targets"):
        EnvPool(-1)
