"""Consolidation (ps_ray/nets/consolidate.py): a trained relative actor is drawn to the input
reference on replay states while it keeps its actions; nothing else in the policy moves."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from ps_ray.errors import UserError
from ps_ray.nets.consolidate import consolidate
from ps_ray.nets.modular import update_normalizers
from ps_ray.nets.sac import build_sac_nets
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import PRESETS, ConsolidateSpec, RelativeSpec, method_spec
from tests.code_paths import PS_CONSOLIDATED

DIMS = NetDims(task_dim=3, robot_dim=8, action_dim=7)
# the preset that consolidates, and the variant whose projection is on while it trains
CONSOLIDATED = [
    *(name for name, spec in PRESETS.items() if spec.consolidate is not None),
    PS_CONSOLIDATED,
]


def _nets(method: str, seed: int = 0):
    torch.manual_seed(seed)
    anchors = np.random.default_rng(0).uniform(-0.3, 0.3, size=(16, 3)).astype(np.float32)
    nets = build_sac_nets(method, DIMS, interface_dim=16, hidden=32, anchors=anchors)
    update_normalizers(nets, torch.rand(512, 3) * 0.6 - 0.3, torch.randn(512, 8))
    return nets


def _states(spec: ConsolidateSpec, seed: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(spec.rows, 3, generator=g) * 0.6 - 0.3, torch.randn(spec.rows, 8, generator=g)


def test_the_shipped_rows_consolidate_after_training_with_an_actor_only_relative_cut():
    assert CONSOLIDATED, "no method row consolidates"
    for name in CONSOLIDATED:
        spec = method_spec(name)
        assert spec.relative is not None and not spec.relative_critics, name


@pytest.mark.parametrize("method", CONSOLIDATED)
def test_consolidation_draws_the_interface_to_the_reference_and_keeps_the_actions(method):
    nets = _nets(method)
    spec = ConsolidateSpec(updates=300, batch_size=64)
    task, robot = _states(spec)
    held_task, held_robot = _states(ConsolidateSpec(updates=1, batch_size=512), seed=2)  # unseen states
    relative = nets.actor.task.relative
    with torch.no_grad():
        gap_before = relative.reference_gap(nets.actor.task.encode, held_task).item()
        actions_before = torch.tanh(nets.actor(held_task, held_robot)[0])
    critics_before = copy.deepcopy({k: v for k, v in nets.state_dict().items() if not k.startswith("actor.")})

    stats = consolidate(nets.actor, task, robot, spec)

    with torch.no_grad():
        gap_after = relative.reference_gap(nets.actor.task.encode, held_task).item()
        actions_after = torch.tanh(nets.actor(held_task, held_robot)[0])
    assert stats["gap_before"] > 0.1 and stats["gap_after"] < 0.3 * stats["gap_before"]
    assert gap_after < 0.3 * gap_before  # on states it never saw, too
    assert (actions_after - actions_before).abs().mean() < 0.05  # the policy is kept
    after = {k: v for k, v in nets.state_dict().items() if not k.startswith("actor.")}
    assert all(torch.equal(critics_before[k], after[k]) for k in after)  # critics and targets untouched


@pytest.mark.slow
def test_without_the_action_term_the_pull_alone_would_change_the_policy():
    """What keeps the actions is the distillation: the same pull with a frozen robot module and
    no action term moves them (the control for the test above). A projection switched on while
    training (the old row ps_consolidated), so that the pull moves the interface the actor reads."""
    method = PS_CONSOLIDATED
    nets = _nets(method)
    spec = ConsolidateSpec(updates=300, batch_size=64)
    task, robot = _states(spec)
    held_task, held_robot = _states(ConsolidateSpec(updates=1, batch_size=512), seed=2)
    with torch.no_grad():
        before = torch.tanh(nets.actor(held_task, held_robot)[0])
    relative = nets.actor.task.relative
    optimizer = torch.optim.Adam(nets.actor.task.parameters(), lr=spec.lr)
    for chunk in task.split(spec.batch_size):
        loss = relative.reference_gap(nets.actor.task.encode, chunk)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        moved = (torch.tanh(nets.actor(held_task, held_robot)[0]) - before).abs().mean()
    kept = copy.deepcopy(_nets(method))
    consolidate(kept.actor, task, robot, spec)
    with torch.no_grad():
        drift = (torch.tanh(kept.actor(held_task, held_robot)[0]) - before).abs().mean()
    assert drift < 0.5 * moved


def test_consolidation_refuses_bad_settings_and_a_raw_latent():
    with pytest.raises(ValueError, match="updates must be a positive integer, got 0"):
        ConsolidateSpec(updates=0)
    with pytest.raises(ValueError, match="pull must be >= 0, got -1"):
        ConsolidateSpec(pull=-1)
    with pytest.raises(ValueError, match="lr must be positive, got 0"):
        ConsolidateSpec(lr=0)
    with pytest.raises(UserError, match=r"'ablation\+consolidate=true': consolidation needs"):
        method_spec("ablation+consolidate=true")
    ablation = build_sac_nets("ablation", DIMS, interface_dim=16, hidden=32)
    spec = ConsolidateSpec(updates=2, batch_size=4)
    with pytest.raises(ValueError, match="'ablation' has no relative interface"):
        consolidate(ablation.actor, *_states(spec), spec)
    nets = _nets(CONSOLIDATED[0])
    with pytest.raises(ValueError, match="needs 8 states, got 5"):
        consolidate(nets.actor, torch.zeros(5, 3), torch.zeros(5, 8), spec)


def test_the_reference_gap_is_the_weighted_pull_of_the_training_penalty():
    nets = _nets(CONSOLIDATED[0])
    relative = nets.actor.task.relative
    weighted = copy.deepcopy(relative)
    weighted.spec = RelativeSpec(**{**relative.spec.__dict__, "norm_reg": 0.0, "ref_weight": 0.5})
    x = torch.rand(32, 3) * 0.6 - 0.3
    with torch.no_grad():
        gap = relative.reference_gap(nets.actor.task.encode, x)
        penalty = weighted.penalty(nets.actor.task.encode, x)
    assert torch.allclose(penalty, 0.5 * gap, atol=1e-6)
