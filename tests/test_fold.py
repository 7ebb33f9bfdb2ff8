"""An aligned stitch folded into an ordinary policy (ps_ray.stitching.fold): same actions and Q
values as the aligned stitch, no map left, and a file that can start a training run."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ps_ray.errors import UserError
from ps_ray.nets.policy_file import load_policy, save_policy
from ps_ray.nets.sac import NET_NAMES
from ps_ray.stitching.fold import fold_translation
from ps_ray.stitching.stitch import stitch_policies
from tests.stitch_sources import PUSH, make_nets


def _inputs(n: int = 64, seed: int = 3):
    g = torch.Generator().manual_seed(seed)
    task = 2 * torch.randn(n, PUSH.task_dim, generator=g) + 1
    robot = torch.randn(n, PUSH.robot_dim, generator=g)
    action = torch.rand(n, PUSH.action_dim, generator=g) * 2 - 1
    return task, robot, action


def _outputs(nets, task, robot, action):
    with torch.no_grad():
        out = {"actor": torch.cat(nets.actor(task, robot), -1)}
        out |= {name: getattr(nets, name)(task, robot, action) for name in NET_NAMES[1:]}
    return out


@pytest.mark.parametrize("method", ["ablation", "ps", "plain"])
@pytest.mark.parametrize("kind", ["affine", "orthogonal"])
def test_a_folded_stitch_acts_as_the_aligned_one_with_no_map_left(method, kind, tmp_path):
    task_from, robot_from = make_nets(method, seed=1), make_nets(method, seed=2)
    fit = np.random.default_rng(0).normal(1, 2, size=(300, PUSH.task_dim)).astype(np.float32)
    aligned, signature = stitch_policies(task_from, robot_from, translation=kind, fit_states=fit)
    folded, folded_signature = fold_translation(aligned, signature)
    inputs = _inputs()
    want, got = _outputs(aligned, *inputs), _outputs(folded, *inputs)
    unaligned = _outputs(stitch_policies(task_from, robot_from)[0], *inputs)
    for name in NET_NAMES:
        scale = want[name].abs().max().item()
        assert torch.allclose(got[name], want[name], atol=1e-4 * scale), name
        assert not torch.allclose(unaligned[name], want[name], atol=1e-2 * scale), name  # the map mattered
        assert getattr(folded, name).translate is None
        assert getattr(aligned, name).translate is not None  # the aligned stitch is left as it was
    assert folded_signature.translation == "" and signature.translation == kind
    assert folded_signature == stitch_policies(task_from, robot_from)[1]  # an unaligned stitch's
    # the task module and the rest of the robot module are the aligned stitch's, bit for bit
    for name in NET_NAMES:
        ours, theirs = getattr(folded, name), getattr(aligned, name)
        assert all(torch.equal(v, theirs.task.state_dict()[k]) for k, v in ours.task.state_dict().items())
        robot = theirs.robot.state_dict()
        changed = {k for k, v in ours.robot.state_dict().items() if not torch.equal(v, robot[k])}
        assert changed == {"head.0.weight", "head.0.bias"}, (name, changed)
    # written and read back as any policy file, it still acts as the aligned stitch
    save_policy(tmp_path / "folded.safetensors", folded, folded_signature)
    loaded, loaded_signature = load_policy(tmp_path / "folded.safetensors")
    assert loaded_signature == folded_signature
    assert torch.allclose(_outputs(loaded, *inputs)["actor"], got["actor"])


def test_only_a_stitch_with_a_fitted_map_folds_and_devin_does_not():
    task_from, robot_from = make_nets("ablation", seed=1), make_nets("ablation", seed=2)
    with pytest.raises(UserError, match="only a stitch with a fitted latent map folds .* got .*'none'"):
        fold_translation(*stitch_policies(task_from, robot_from))
    devin_t, devin_r = make_nets("devin", seed=1), make_nets("devin", seed=2)
    fit = np.random.default_rng(0).normal(size=(300, PUSH.task_dim)).astype(np.float32)
    aligned = stitch_policies(devin_t, devin_r, translation="affine", fit_states=fit)
    with pytest.raises(UserError, match="cannot fold a devin stitch's latent map: its latent dropout"):
        fold_translation(*aligned)
