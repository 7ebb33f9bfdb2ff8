"""The SAC math in ps_ray/nets/sac.py, which the RLlib learner and the bare-torch loop share."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch.distributions import Normal, TanhTransform, TransformedDistribution

from ps_ray.nets.sac import SACHyper, build_sac_nets, polyak, sac_forward, sac_losses, squashed_sample
from ps_ray.specs.dims import NetDims

DIMS = NetDims(task_dim=6, robot_dim=8, action_dim=7)
GAMMA = 0.98


def test_squashed_log_probability_matches_torch_distributions():
    torch.manual_seed(0)
    mean, log_std = torch.randn(512, 7) * 0.8, torch.randn(512, 7) * 0.3 - 0.5
    action, logp = squashed_sample(mean, log_std)
    reference = TransformedDistribution(Normal(mean, log_std.exp()), [TanhTransform(cache_size=1)])
    expected = reference.log_prob(action.double().clamp(-1 + 1e-9, 1 - 1e-9).float()).sum(-1)
    assert action.abs().max() < 1
    torch.testing.assert_close(logp, expected, atol=2e-3, rtol=1e-4)


def _fwd(q_target_next: float, logp_next: float = 0.0, n: int = 4) -> dict[str, torch.Tensor]:
    zeros = torch.zeros(n, requires_grad=True)
    return {
        "q": zeros,
        "q_twin": zeros,
        "q_target_next": torch.full((n,), q_target_next),
        "logp_next": torch.full((n,), logp_next),
        "logp": torch.zeros(n),
        "q_policy": torch.zeros(n),
        "action": torch.zeros(n, 7),
    }


@pytest.mark.parametrize(
    "reward, q_next, target",
    [
        (-1.0, 100.0, 0.0),  # an impossible positive return is clipped to 0
        (-1.0, -1000.0, -1.0 / (1.0 - GAMMA)),  # and one below -1/(1-gamma) to that bound
        (-1.0, -10.0, -1.0 - GAMMA * 10.0),  # inside the range: untouched
    ],
)
def test_critic_targets_are_clipped_to_the_possible_returns(reward, q_next, target):
    losses = sac_losses(_fwd(q_next), torch.full((4,), reward), torch.tensor(math.log(1e-12)), SACHyper(), 7)
    assert losses["critic"].item() == pytest.approx(2 * target**2, rel=1e-5)  # q = q_twin = 0


def test_the_entropy_bonus_is_added_outside_the_clip():
    # reward 0 and q_next 0 clip to 0; the bonus -gamma * alpha * logp_next = +9.8 is added after
    losses = sac_losses(_fwd(0.0, logp_next=-10.0), torch.zeros(4), torch.tensor(0.0), SACHyper(), 7)
    assert losses["critic"].item() == pytest.approx(2 * (GAMMA * 10.0) ** 2, rel=1e-5)
    unclipped = sac_losses(
        _fwd(0.0, logp_next=-10.0), torch.zeros(4), torch.tensor(0.0), SACHyper(clip_targets=False), 7
    )
    assert unclipped["critic"].item() == pytest.approx(losses["critic"].item())


@pytest.mark.parametrize("method", ["ablation", "ps", "plain"])
def test_each_loss_moves_only_its_own_parameters(method):
    torch.manual_seed(0)
    anchors = np.random.default_rng(0).normal(size=(16, DIMS.task_dim)).astype(np.float32)
    nets = build_sac_nets(method, DIMS, interface_dim=16, hidden=32, anchors=anchors)
    log_alpha = torch.zeros((), requires_grad=True)
    batch = {
        "task_in": torch.randn(32, DIMS.task_dim),
        "robot_in": torch.randn(32, DIMS.robot_dim),
        "actions": torch.rand(32, DIMS.action_dim) * 2 - 1,
        "next_task_in": torch.randn(32, DIMS.task_dim),
        "next_robot_in": torch.randn(32, DIMS.robot_dim),
    }
    groups = {
        "actor": list(nets.actor.parameters()),
        "critic": [*nets.critic.parameters(), *nets.critic_twin.parameters()],
        "alpha": [log_alpha],
        "targets": [*nets.target_critic.parameters(), *nets.target_critic_twin.parameters()],
    }
    for loss_name, moved in (("critic", "critic"), ("actor", "actor"), ("alpha", "alpha")):
        for params in groups.values():
            for p in params:
                p.grad = None
        losses = sac_losses(sac_forward(nets, batch), -torch.rand(32), log_alpha, SACHyper(), 7)
        losses[loss_name].backward()
        for group, params in groups.items():
            grads = [p.grad for p in params if p.grad is not None and p.grad.abs().sum() > 0]
            if group == moved:
                assert grads, f"{loss_name} loss: no gradient reached {group}"
            else:
                assert not grads, f"{loss_name} loss leaked a gradient into {group}"


def test_polyak_moves_each_target_parameter_tau_of_the_way_and_copies_buffers():
    torch.manual_seed(0)
    nets = build_sac_nets("ps", DIMS, interface_dim=16, hidden=32, anchors=np.random.rand(16, DIMS.task_dim))
    with torch.no_grad():
        for p in (*nets.critic.parameters(), *nets.critic_twin.parameters()):
            p.add_(torch.randn_like(p))  # online critics trained away from their targets
        for b in nets.critic.buffers():
            b.add_(1.0)
    before = {k: v.clone() for k, v in nets.state_dict().items()}
    polyak(nets, 0.25)
    after = nets.state_dict()
    params = {name for name, _ in nets.named_parameters()}
    checked = {"parameters": 0, "buffers": 0}
    for online in ("critic", "critic_twin"):
        for key in (k for k in before if k.startswith(online + ".")):
            target = "target_" + key
            checked["parameters" if key in params else "buffers"] += 1
            if key in params:
                want = 0.75 * before[target] + 0.25 * before[key]
                torch.testing.assert_close(after[target], want)
            else:  # normaliser statistics and anchors follow exactly
                torch.testing.assert_close(after[target], before[key])
            torch.testing.assert_close(after[key], before[key])  # the online critic is untouched
    for key in (k for k in before if k.startswith("actor.")):
        torch.testing.assert_close(after[key], before[key])
    assert checked["parameters"] >= 8 and checked["buffers"] >= 2, checked
