"""Tests for ps_ray.nets: plain torch, real modules, small batches."""

from __future__ import annotations

import ast
import copy
import dataclasses
from pathlib import Path

import pytest
import torch
from torch import nn

from ps_ray.nets import (
    Actor,
    Critic,
    NetDims,
    RelativeProjection,
    RunningNorm,
    build_actor,
    build_critic,
    count_parameters,
    mlp,
    update_normalizers,
)
from ps_ray.specs.methods import RelativeSpec, method_spec
from tests.code_paths import CODE_PATHS

torch.set_num_threads(1)

PUSH = NetDims(task_dim=15, robot_dim=8, action_dim=7)
REACH = NetDims(task_dim=3, robot_dim=8, action_dim=7)
BATCH = 32


def anchors_for(dims: NetDims, k: int = 128, seed: int = 0) -> torch.Tensor:
    return torch.randn(k, dims.task_dim, generator=torch.Generator().manual_seed(seed))


def inputs(dims: NetDims, batch: int = BATCH, seed: int = 1) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    task = torch.randn(batch, dims.task_dim, generator=g)
    robot = torch.randn(batch, dims.robot_dim, generator=g)
    action = torch.rand(batch, dims.action_dim, generator=g) * 2 - 1
    return task, robot, action


# every method, and ps_distilled also as it is after its run (its deferred projection switched on)
SWITCHED = ":on"
VARIANTS = [*CODE_PATHS, "ps_distilled" + SWITCHED]


def build(
    kind: str, method: str, dims: NetDims = PUSH, interface_dim: int = 128, seed: int = 0, **kw
) -> Actor | Critic:
    torch.manual_seed(seed)
    method, switched = method.removesuffix(SWITCHED), method.endswith(SWITCHED)
    builder = build_actor if kind == "actor" else build_critic
    anchors = anchors_for(dims, interface_dim) if method_spec(method).relative else None
    net = builder(method, dims, interface_dim=interface_dim, anchors=anchors, **kw)
    if switched and kind == "actor":
        net.task.switch_relative_on()
    return net


def run(net: Actor | Critic, task, robot, action):
    return net(task, robot) if isinstance(net, Actor) else (net(task, robot, action),)


def interface(net: Actor | Critic, task, robot, action) -> torch.Tensor:
    return net.interface(task, robot) if isinstance(net, Actor) else net.interface(task, robot, action)


# --- building blocks -------------------------------------------------------------------------------


def test_mlp_layers() -> None:
    net = mlp(5, [7, 9], 3, dropout=0.1, out_act=True)
    kinds = [type(m).__name__ for m in net]
    assert kinds == ["Linear", "ReLU", "Dropout", "Linear", "ReLU", "Dropout", "Linear", "ReLU"]
    assert [type(m).__name__ for m in mlp(5, [], 3)] == ["Linear"]
    assert net(torch.randn(4, 5)).shape == (4, 3)


def test_running_norm_standardises_clips_and_round_trips() -> None:
    g = torch.Generator().manual_seed(0)
    mean, std = torch.tensor([3.0, -2.0, 10.0]), torch.tensor([0.5, 2.0, 4.0])
    data = torch.randn(20_000, 3, generator=g) * std + mean
    norm = RunningNorm(3, clip=5.0)
    for chunk in data.split(1000):  # incremental updates must equal one full-batch estimate
        norm.update(chunk)
    assert norm.count.item() == 20_000
    # merged in float64, stored in float32 (what survives an RLlib checkpoint exactly)
    assert norm.mean.dtype == norm.var.dtype == torch.float32
    torch.testing.assert_close(norm.mean, data.double().mean(0).float(), rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(norm.var, data.double().var(0, unbiased=False).float(), rtol=1e-5, atol=1e-6)
    out = norm(data)
    assert out.dtype == data.dtype
    torch.testing.assert_close(out.mean(0), torch.zeros(3), rtol=0, atol=2e-2)
    torch.testing.assert_close(out.std(0), torch.ones(3), rtol=0, atol=2e-2)
    far = norm(mean + 100 * std)
    assert torch.equal(far, torch.full((3,), 5.0))
    assert torch.equal(norm(mean - 100 * std), torch.full((3,), -5.0))

    restored = RunningNorm(3)
    restored.load_state_dict(copy.deepcopy(norm.state_dict()))
    assert set(norm.state_dict()) == {"count", "mean", "var"}
    assert torch.equal(restored(data[:10]), norm(data[:10]))
    assert not list(norm.parameters())


def test_running_norm_eps_and_identity_before_update() -> None:
    norm = RunningNorm(2, eps=1e-2)
    x = torch.tensor([[0.3, -1.0]])
    assert torch.equal(norm(x), x)  # count 0: mean 0, var 1
    norm.update(torch.tensor([[1.0, 2.0], [1.0, 2.0]]))  # constant features: std 0 -> eps
    torch.testing.assert_close(norm(torch.tensor([[1.01, 2.0]])), torch.tensor([[1.0, 0.0]]))
    with pytest.raises(ValueError, match="last dim"):
        norm.update(torch.zeros(4, 3))


# --- relative projection ---------------------------------------------------------------------------


def test_relative_invariant_to_orthogonal_transform_and_scale() -> None:
    torch.manual_seed(0)
    encoder = mlp(6, [32], 10)
    q, _ = torch.linalg.qr(torch.randn(10, 10, dtype=torch.float64))
    q = q.float()
    assert not torch.allclose(q, torch.eye(10))
    scale = 3.7
    rotated = lambda x: scale * encoder(x) @ q  # noqa: E731 - same latent up to isometry + scale
    projection = RelativeProjection(torch.randn(20, 6))
    x = torch.randn(BATCH, 6)
    plain, moved = projection(encoder, x), projection(rotated, x)
    assert plain.shape == (BATCH, 20)
    assert not torch.allclose(encoder(x), rotated(x))  # absolute latents differ...
    torch.testing.assert_close(moved, plain, rtol=0, atol=1e-5)  # ...relative ones do not


def test_relative_supports_leading_dims_and_rejects_bad_input() -> None:
    encoder = mlp(4, [8], 5)
    projection = RelativeProjection(torch.randn(6, 4))
    x = torch.randn(3, 7, 4)
    out = projection(encoder, x)
    assert out.shape == (3, 7, 6)
    torch.testing.assert_close(out[1], projection(encoder, x[1]))
    with pytest.raises(ValueError, match="anchor dim"):
        projection(encoder, torch.randn(2, 5))
    with pytest.raises(ValueError, match="matrix"):
        RelativeProjection(torch.randn(4))


def _encoder_grad(anchor_grad: bool, detach_anchor_path: bool = False) -> torch.Tensor:
    torch.manual_seed(0)
    encoder = nn.Linear(4, 6)
    x, anchors = torch.randn(8, 4), torch.randn(5, 4)
    if detach_anchor_path:  # reference: anchors embedded as constants
        z_a = nn.functional.normalize(encoder(anchors).detach(), dim=-1)
        out = nn.functional.normalize(encoder(x), dim=-1) @ z_a.T
    else:
        out = RelativeProjection(anchors, RelativeSpec(anchor_grad=anchor_grad))(encoder, x)
    (out * torch.arange(out.numel()).reshape(out.shape)).sum().backward()
    return encoder.weight.grad.clone()


def test_anchor_grad_controls_gradient_through_anchor_embeddings() -> None:
    with_anchor_path = _encoder_grad(anchor_grad=True)
    without = _encoder_grad(anchor_grad=False)
    batch_path_only = _encoder_grad(anchor_grad=False, detach_anchor_path=True)
    torch.testing.assert_close(without, batch_path_only)  # no gradient from the anchor path
    assert (with_anchor_path - batch_path_only).abs().max() > 1e-3  # anchor path adds gradient


def test_anchor_grad_does_not_change_values() -> None:
    actor = build("actor", "ps")
    frozen = build("actor", "ps", anchor_grad=False)
    task, robot, _ = inputs(PUSH)
    torch.testing.assert_close(actor(task, robot), frozen(task, robot), rtol=0, atol=1e-6)


# --- modular networks ------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["actor", "critic"])
@pytest.mark.parametrize("method", VARIANTS)
def test_gradients_reach_every_parameter(method: str, kind: str) -> None:
    net = build(kind, method)
    net.train()
    task, robot, action = inputs(PUSH)
    update_normalizers(net, task, robot)
    outputs = run(net, task, robot, action)
    g = torch.Generator().manual_seed(3)
    loss = sum((out * torch.randn(out.shape, generator=g)).sum() for out in outputs)
    loss.backward()
    for name, param in net.named_parameters():
        assert param.requires_grad
        assert param.grad is not None, name
        assert torch.isfinite(param.grad).all(), name
        assert param.grad.abs().sum() > 0, name


@pytest.mark.parametrize("dims", [PUSH, REACH], ids=["push", "reach"])
@pytest.mark.parametrize("interface_dim", [3, 16, 128])
@pytest.mark.parametrize("method", VARIANTS)
def test_interface_dims_build_and_run(method: str, interface_dim: int, dims: NetDims) -> None:
    actor = build("actor", method, dims, interface_dim)
    critic = build("critic", method, dims, interface_dim)
    task, robot, action = inputs(dims)
    expected_width = {"devin": 16, "plain": 256}.get(method, interface_dim)
    assert actor.latent_dim == critic.latent_dim == expected_width
    assert actor.interface(task, robot).shape == (BATCH, expected_width)
    if method.endswith(SWITCHED):  # the relative interface, not the raw latent it replaced
        assert not torch.equal(actor.interface(task, robot), actor.task.encode(task))
    assert critic.interface(task, robot, action).shape == (BATCH, expected_width)
    mean, log_std = actor(task, robot)
    assert mean.shape == log_std.shape == (BATCH, dims.action_dim)
    assert critic(task, robot, action).shape == (BATCH,)


def test_switching_on_a_projection_needs_a_deferred_one() -> None:
    with pytest.raises(ValueError, match="method 'ps' has no deferred relative projection"):
        build("actor", "ps").task.switch_relative_on()
    with pytest.raises(ValueError, match="deferred relative interface needs consolidation"):
        dataclasses.replace(method_spec("ps_distilled"), consolidate=None)


def test_ps_interface_is_cosine_vector() -> None:
    actor = build("actor", "ps")
    task, robot, _ = inputs(PUSH)
    z = actor.interface(task * 10, robot)
    assert z.shape == (BATCH, 128)
    assert z.abs().max() <= 1 + 1e-6
    # an anchor's own relative vector has cosine 1 with itself
    self_sim = actor.interface(actor.anchors, robot[:1].expand(128, -1)).diagonal()
    torch.testing.assert_close(self_sim, torch.ones(128))


@pytest.mark.parametrize("kind", ["actor", "critic"])
def test_ps_anchor_errors(kind: str) -> None:
    builder = build_actor if kind == "actor" else build_critic
    with pytest.raises(ValueError, match=r"needs anchors of shape \(128, 15\)"):
        builder("ps", PUSH)
    with pytest.raises(ValueError, match=r"anchors have shape \(64, 15\), expected \(128, 15\)"):
        builder("ps", PUSH, anchors=torch.zeros(64, 15))
    with pytest.raises(ValueError, match=r"anchors have shape \(128, 3\), expected \(128, 15\)"):
        builder("ps", PUSH, anchors=torch.zeros(128, 3))
    builder("ablation", PUSH, anchors=torch.zeros(5, 5))  # ignored by non-relative methods
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        builder("nope", PUSH)


def test_log_std_clamped_and_devin_dropout_only_in_train_mode() -> None:
    actor = build("actor", "devin")
    task, robot, _ = inputs(PUSH)
    with torch.no_grad():
        for p in actor.robot.head[-1].parameters():
            p.mul_(1e4)
        actor.train()
        _, log_std = actor(task, robot)
        assert log_std.min() >= -9 and log_std.max() <= 2
        assert not torch.equal(actor(task, robot)[0], actor(task, robot)[0])  # dropout on the latent
        actor.eval()
        assert torch.equal(actor(task, robot)[0], actor(task, robot)[0])
        torch.testing.assert_close(actor.interface(task, robot), actor.task(task))  # dropout is past the cut


def test_update_normalizers_routes_inputs() -> None:
    task, robot, action = inputs(PUSH)
    task, robot = task * 3 + 1, robot * 2 - 4
    for kind in ("actor", "critic"):
        modular, plain = build(kind, "ps"), build(kind, "plain")
        update_normalizers(nn.ModuleList([modular, plain]), task, robot)
        torch.testing.assert_close(modular.task.norm.mean, task.double().mean(0).float())
        torch.testing.assert_close(modular.robot.norm.mean, robot.double().mean(0).float())
        torch.testing.assert_close(
            plain.task.norm.mean, torch.cat([task, robot], -1).double().mean(0).float()
        )
        assert plain.robot.norm is None
        # the PS anchors go through the same input normalisation as the batch
        anchors = modular.anchors
        manual = nn.functional.normalize(modular.task.body(modular.task.norm(anchors)), dim=-1)
        z = nn.functional.normalize(modular.task.body(modular.task.norm(task)), dim=-1) @ manual.T
        torch.testing.assert_close(modular.task(task), z, rtol=0, atol=1e-6)
    critic = build("critic", "ablation")
    assert critic.robot.norm.dim == PUSH.robot_dim  # the critic's action is not normalised


# --- sizes -----------------------------------------------------------------------------------------


def linear(i: int, o: int) -> int:
    return i * o + o


def expected_counts(method: str, dims: NetDims, d: int = 128, h: int = 256) -> dict[str, int]:
    t, r, a = dims.task_dim, dims.robot_dim, dims.action_dim
    if method == "plain":
        return {
            "actor.task": linear(t + r, h) + linear(h, h),
            "actor.robot": linear(h, h) + linear(h, 2 * a),
            "critic.task": linear(t + r + a, h) + linear(h, h),
            "critic.robot": linear(h, h) + linear(h, 1),
        }
    d = 16 if method == "devin" else d
    task = linear(t, h) + linear(h, h) + linear(h, d)
    trunk = linear(d + h // 2, h) + linear(h, h)
    return {
        "actor.task": task,
        "actor.robot": linear(r, h // 2) + trunk + linear(h, 2 * a),
        "critic.task": task,
        "critic.robot": linear(a + r, h // 2) + trunk + linear(h, 1),
    }


@pytest.mark.parametrize("dims", [PUSH, REACH], ids=["push", "reach"])
@pytest.mark.parametrize("method", CODE_PATHS)
def test_parameter_counts(method: str, dims: NetDims) -> None:
    actor, critic = build("actor", method, dims), build("critic", method, dims)
    got = {
        "actor.task": count_parameters(actor.task),
        "actor.robot": count_parameters(actor.robot),
        "critic.task": count_parameters(critic.task),
        "critic.robot": count_parameters(critic.robot),
    }
    print(f"{method} task_dim={dims.task_dim}: {got}")
    assert got == expected_counts(method, dims)


def test_ps_push_counts_match_authors_minus_batchnorm() -> None:
    # docs/authors_code.md §3: task 102,814; actor robot 136,350; critic robot 133,919, each including the
    # 2·n affine parameters of its input BatchNorm1d(n), which RunningNorm replaces by buffers.
    actor, critic = build("actor", "ps"), build("critic", "ps")
    assert count_parameters(actor.task) == count_parameters(critic.task) == 102_814 - 2 * 15
    assert count_parameters(actor.robot) == 136_350 - 2 * 8
    assert count_parameters(critic.robot) == 133_919 - 2 * 15


def test_nets_import_no_ray() -> None:
    for path in Path(__file__).parents[1].joinpath("ps_ray", "nets").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            assert not any(n == "ray" or n.startswith("ray.") for n in names), path
