"""Marker selectivity reads which marker an actor's action follows."""

import torch
from torch import nn

from ps_ray.analysis.selectivity import marker_selectivity
from ps_ray.nets.modular import build_actor
from ps_ray.specs.dims import NetDims

RED, BLUE = slice(0, 3), slice(3, 6)
DIMS = NetDims(task_dim=9, robot_dim=9, action_dim=4)


def _actor_blind_to(columns: slice):
    torch.manual_seed(0)
    actor = build_actor("ablation", DIMS, interface_dim=16, hidden=32)
    first = next(m for m in actor.task.modules() if isinstance(m, nn.Linear))
    with torch.no_grad():
        first.weight[:, columns] = 0.0
    return actor


def test_an_actor_that_cannot_see_a_marker_does_not_follow_it():
    scenes = torch.rand(64, 9)
    red_reader = _actor_blind_to(BLUE)
    seen = marker_selectivity(red_reader, scenes, named=RED, other=BLUE)
    assert seen.named > 0 and seen.other == 0.0 and seen.ratio == float("inf")
    # the same actor judged as a reach_blue policy follows nothing of its own marker
    flipped = marker_selectivity(red_reader, scenes, named=BLUE, other=RED)
    assert flipped.named == 0.0 and flipped.ratio == 0.0
    assert flipped.other == seen.named


def test_an_untrained_actor_follows_both_markers_alike():
    torch.manual_seed(1)
    actor = build_actor("ablation", DIMS, interface_dim=16, hidden=32)
    seen = marker_selectivity(actor, torch.rand(256, 9), named=RED, other=BLUE)
    assert 0.5 < seen.ratio < 2.0
