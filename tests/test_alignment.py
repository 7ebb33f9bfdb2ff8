"""Alignment beyond the paper: latent translation, retrieval scores, collapse flag
and the relative-projection variants."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from ps_ray.analysis.alignment import chance_mrr, collapsed, retrieval, spread
from ps_ray.nets.from_signature import signature_of
from ps_ray.nets.modular import build_actor, update_normalizers
from ps_ray.nets.policy_file import load_policy, save_policy
from ps_ray.nets.relative import RelativeProjection, input_reference
from ps_ray.nets.sac import NET_NAMES, build_sac_nets
from ps_ray.nets.translation import fit_translation
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import PRESETS, RelativeSpec, method_spec, uses_anchors
from ps_ray.stitching.stitch import stitch_policies
from tests.code_paths import CODE_PATHS

RNG = np.random.default_rng(0)
PUSH = NetDims(15, 8, 7)


def latents(n: int = 400, d: int = 16, seed: int = 0) -> np.ndarray:
    """Anisotropic, off-centre, correlated latents (like a ReLU network's)."""
    g = np.random.default_rng(seed)
    return g.normal(size=(n, d)) @ g.normal(size=(d, d)) * g.uniform(0.2, 3, d) + g.normal(size=d)


# -- translation ----------------------------------------------------------------------------------
def test_translation_recovers_a_known_orthogonal_map():
    x = latents()
    q, _ = np.linalg.qr(np.random.default_rng(1).normal(size=(16, 16)))
    y = 2.5 * x @ q + 4.0  # rotation/reflection, isotropic scale, offset
    weight, bias, _ = fit_translation(x, y, "orthogonal")
    assert np.abs(x @ weight + bias - y).max() < 1e-4
    # fitted on part of the states, it maps states it has not seen
    weight, bias, _ = fit_translation(x[:200], y[:200], "orthogonal")
    assert np.abs(x[200:] @ weight + bias - y[200:]).max() < 1e-4


def test_translation_recovers_a_known_affine_map_between_widths():
    x = latents(d=16)
    a, b = np.random.default_rng(2).normal(size=(16, 8)), np.random.default_rng(3).normal(size=8)
    for kind in ("affine", "affine_lstsq"):
        weight, bias, ridge = fit_translation(x[:300], x[:300] @ a + b, kind)
        assert weight.shape == (16, 8)
        assert np.abs(x[300:] @ weight + bias - (x[300:] @ a + b)).max() < 1e-4
        assert ridge <= 1e-6  # nothing to regularise: cross-validation picks the weakest ridge


def low_rank_latents(n: int, seed: int, d: int = 128, rank: int = 48, noise: float = 0.05) -> np.ndarray:
    """Latents as trained ones are: 128 wide, of effective rank 48 (one fixed subspace), noisy."""
    scales = np.random.default_rng(10).uniform(0.2, 2, (rank, 1))
    basis = np.random.default_rng(9).normal(size=(rank, d)) * scales
    g = np.random.default_rng(seed)
    return g.normal(size=(n, rank)) @ basis / np.sqrt(rank) + noise * g.normal(size=(n, d)) + 1.0


def test_the_ridge_fit_predicts_held_out_latents_at_as_many_rows_as_unknowns():
    """129 unknowns per output (128 weights and an offset) from 129 noisy rows of rank-48 latents:
    the point where plain least squares interpolates the noise (its held-out error peaks). The
    map cannot be identified outside the latents' subspace, so predictions on held-out latents of
    the same subspace are what is checked: the cross-validated ridge stays within 2% of the
    target's variance; plain least squares, the old fit, is many times worse there."""
    a = np.random.default_rng(5).normal(size=(128, 128)) / np.sqrt(128)
    b = np.random.default_rng(6).normal(size=128)
    x = low_rank_latents(129, seed=0)
    y = x @ a + b + 0.05 * np.random.default_rng(7).normal(size=x.shape)
    x_new = low_rank_latents(1000, seed=1)
    y_new = x_new @ a + b

    def held_out_error(kind: str) -> float:
        weight, bias, _ = fit_translation(x, y, kind)
        return float(np.mean((x_new @ weight + bias - y_new) ** 2) / y_new.var(axis=0).sum() * 128)

    ridge, plain = held_out_error("affine"), held_out_error("affine_lstsq")
    assert ridge < 0.02 and plain > 5 * ridge
    chosen = fit_translation(x, y, "affine").ridge
    assert 0 < chosen < 1  # the strength the fit chose is returned, to be recorded with the stitch


def test_orthogonal_translation_cannot_fit_a_shear():
    x = latents()
    shear = np.eye(16) + np.triu(np.random.default_rng(4).normal(size=(16, 16)), 1)
    weight, bias, _ = fit_translation(x, x @ shear, "orthogonal")
    assert np.abs(x @ weight + bias - x @ shear).max() > 0.1


def test_unknown_translation_is_named():
    with pytest.raises(ValueError, match="unknown translation 'rotate'; expected one of"):
        fit_translation(latents(), latents(), "rotate")


def _nets(method: str, seed: int = 0):
    torch.manual_seed(seed)
    anchors = np.random.default_rng(0).normal(size=(8, 15)).astype(np.float32)
    nets = build_sac_nets(
        method, PUSH, interface_dim=8, hidden=16, anchors=anchors if uses_anchors(method) else None
    )
    update_normalizers(nets, 2 * torch.randn(256, 15) + 1, torch.randn(256, 8))
    return nets.eval(), signature_of(nets, method, 8, 16)


def _rotated(nets, q: torch.Tensor):
    """A copy whose task modules output the latent rotated by q (z -> z q) and whose robot
    modules take it back: the same policy behind an exactly recoverable misalignment."""
    other = copy.deepcopy(nets)
    width = q.shape[0]
    with torch.no_grad():
        for name in NET_NAMES:
            net = getattr(other, name)
            last = net.task.body[-1]
            last.weight.copy_(q.T @ last.weight)
            last.bias.copy_(last.bias @ q)
            if net.task.relative is None:  # a relative vector is unchanged by the rotation
                first = net.robot.head[0]
                first.weight[:, :width] = first.weight[:, :width] @ q
    return other


@pytest.mark.e2e
@pytest.mark.parametrize("method", ["ablation", "devin", "ps", "ps+center=mean+norm=layer"])
def test_translated_stitch_undoes_a_rotated_task_module(method, tmp_path):
    """Stitching A's task module onto B's robot module, where B is A behind a rotation of the
    latent: without translation the raw-latent methods break, with it every method gives A's
    outputs back; the fitted map travels in the policy file and its signature."""
    a, sig = _nets(method)
    q = torch.linalg.qr(
        torch.randn(a.actor.latent_dim, a.actor.latent_dim, generator=torch.Generator().manual_seed(5))
    )[0]
    b = _rotated(a, q)
    states = (2 * torch.randn(512, 15) + 1).numpy()
    task, robot = torch.randn(32, 15), torch.randn(32, 8)
    with torch.no_grad():
        want = a.actor(task, robot)[0]
        torch.testing.assert_close(b.actor(task, robot)[0], want, atol=1e-4, rtol=1e-4)
        untranslated, _ = stitch_policies((a, sig), (b, sig))
        translated, tsig = stitch_policies((a, sig), (b, sig), translation="orthogonal", fit_states=states)
        if not uses_anchors(method):
            assert (untranslated.actor.eval()(task, robot)[0] - want).abs().max() > 1e-2
        torch.testing.assert_close(translated.eval().actor(task, robot)[0], want, atol=1e-4, rtol=1e-4)
    assert tsig.translation == "orthogonal" and tsig.method == method
    loaded, loaded_sig = load_policy(save_policy(tmp_path / "t.safetensors", translated, tsig))
    assert loaded_sig == tsig
    with torch.no_grad():
        torch.testing.assert_close(loaded.eval().actor(task, robot)[0], want, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("kind", ["orthogonal", "affine"])
def test_translated_self_stitch_of_plain_keeps_the_policy(kind):
    """Plain's bottom half also sees the robot state: the fit draws robot states from the robot
    source's normaliser; a self-stitch fits the identity and keeps every net's output."""
    nets, sig = _nets("plain")
    states = (2 * torch.randn(512, 15) + 1).numpy()
    stitched, _ = stitch_policies((nets, sig), (nets, sig), translation=kind, fit_states=states)
    task, robot, action = torch.randn(32, 15), torch.randn(32, 8), torch.rand(32, 7) * 2 - 1
    with torch.no_grad():
        torch.testing.assert_close(
            stitched.eval().actor(task, robot)[0], nets.actor(task, robot)[0], atol=1e-4, rtol=1e-4
        )
        torch.testing.assert_close(
            stitched.target_critic(task, robot, action),
            nets.target_critic(task, robot, action),
            atol=1e-4,
            rtol=1e-4,
        )


def test_translation_needs_fit_states_and_refuses_restitching():
    nets, sig = _nets("ablation")
    with pytest.raises(ValueError, match="needs fit_states"):
        stitch_policies((nets, sig), (nets, sig), translation="affine")
    states = np.random.default_rng(0).normal(size=(64, 15)).astype(np.float32)
    stitched, tsig = stitch_policies((nets, sig), (nets, sig), translation="affine", fit_states=states)
    with pytest.raises(ValueError, match="itself a translated stitch"):
        stitch_policies((stitched, tsig), (nets, sig))


def _reading_permuted(nets, perm: np.ndarray):
    """A copy whose task modules read an input x as the original reads x[perm] (its first layer's
    columns and its normaliser's statistics permuted): a task that means by one marker what the
    original means by the other."""
    other, inv = copy.deepcopy(nets), torch.as_tensor(np.argsort(perm))
    with torch.no_grad():
        for name in NET_NAMES:
            task = getattr(other, name).task
            task.norm.mean.copy_(task.norm.mean[inv])
            task.norm.var.copy_(task.norm.var[inv])
            task.body[0].weight.copy_(task.body[0].weight[:, inv])
    return other


@pytest.mark.parametrize("method", ["ps", "ps+center=mean+norm=layer"])
def test_a_stitch_reanchored_on_matched_anchors_reads_the_scene_as_its_robot_module_does(method, tmp_path):
    """Task module X reads a scene as the robot module's own task module reads the scene with two
    markers trading places. Re-anchored on the anchors with those markers traded (what each anchor
    means to X), the stitch acts on a scene exactly as the robot source acts on the traded scene;
    left on the shared anchors, it does not. The matched anchors travel in the policy file."""
    nets, sig = _nets(method)
    perm = np.r_[3:6, 0:3, 6:15]  # the first two 3-D blocks trade places
    x_reader = _reading_permuted(nets, perm)
    anchors = nets.actor.anchors.numpy()
    task, robot = 2 * torch.randn(32, 15) + 1, torch.randn(32, 8)
    with torch.no_grad():
        want = nets.actor(task[:, perm], robot)[0]
        same_anchors, _ = stitch_policies((x_reader, sig), (nets, sig))
        matched, msig = stitch_policies(
            (x_reader, sig), (nets, sig), translation="anchors", fit_states=anchors[:, np.argsort(perm)]
        )
        assert (same_anchors.eval().actor(task, robot)[0] - want).abs().max() > 1e-2
        torch.testing.assert_close(matched.eval().actor(task, robot)[0], want, atol=1e-5, rtol=1e-5)
        action = torch.rand(32, 7) * 2 - 1
        torch.testing.assert_close(
            matched.critic(task, robot, action),
            nets.critic(task[:, perm], robot, action),
            atol=1e-4,
            rtol=1e-4,
        )
    assert msig.translation == "anchors" and msig.anchor_hash != sig.anchor_hash
    loaded, loaded_sig = load_policy(save_policy(tmp_path / "m.safetensors", matched, msig))
    assert loaded_sig == msig
    with torch.no_grad():
        torch.testing.assert_close(loaded.eval().actor(task, robot)[0], want, atol=1e-5, rtol=1e-5)


def test_reanchoring_on_the_same_anchors_is_the_plain_stitch_and_bad_anchors_are_refused():
    a, sig = _nets("ps", seed=0)
    b, _ = _nets("ps", seed=1)
    anchors = a.actor.anchors.numpy()
    task, robot = torch.randn(16, 15), torch.randn(16, 8)
    with torch.no_grad():
        plain, _ = stitch_policies((a, sig), (b, sig))
        same, _ = stitch_policies((a, sig), (b, sig), translation="anchors", fit_states=anchors)
        torch.testing.assert_close(same.eval().actor(task, robot)[0], plain.eval().actor(task, robot)[0])
    with pytest.raises(
        ValueError, match=r"matched anchors of shape \(7, 15\) cannot replace anchors of shape \(8, 15\)"
    ):
        stitch_policies((a, sig), (b, sig), translation="anchors", fit_states=anchors[:7])
    ablation, asig = _nets("ablation")
    with pytest.raises(ValueError, match="cannot re-anchor a ablation stitch: it has no relative projection"):
        stitch_policies((ablation, asig), (ablation, asig), translation="anchors", fit_states=anchors)


# -- retrieval and collapse -----------------------------------------------------------------------
def _relative(z: np.ndarray, anchor_rows: np.ndarray) -> np.ndarray:
    """A relative space of absolute latents z, anchors = the given rows of z."""
    projection = RelativeProjection(torch.as_tensor(z[anchor_rows]), RelativeSpec())
    return projection(lambda x: x, torch.as_tensor(z)).numpy()


def test_retrieval_is_perfect_for_identical_spaces_and_chance_for_shuffled_probes():
    x = latents(n=300)
    assert retrieval(x, x) == {"mrr": 1.0, "top1": 1.0}
    shuffled = retrieval(x, x[np.random.default_rng(1).permutation(300)])
    assert shuffled["mrr"] < 3 * chance_mrr(300) and shuffled["top1"] < 0.03


def test_retrieval_of_relative_spaces_is_invariant_to_rotation_and_scaling():
    z = latents(n=300)
    q, _ = np.linalg.qr(np.random.default_rng(2).normal(size=(16, 16)))
    anchors = np.arange(0, 300, 10)
    same, moved = _relative(z, anchors), _relative(3.7 * z @ q, anchors)
    np.testing.assert_allclose(same, moved, atol=1e-5)
    assert retrieval(same, moved) == {"mrr": 1.0, "top1": 1.0}
    # the absolute spaces themselves are not aligned: retrieval drops
    assert retrieval(z, 3.7 * z @ q)["mrr"] < 0.5


def test_a_collapsed_interface_is_flagged_and_cannot_score_retrieval():
    x = latents(n=200)
    constant = np.ones_like(x)
    assert collapsed(constant) and not collapsed(x)
    assert spread(constant) == pytest.approx(0.0, abs=1e-12)
    assert 0.5 < spread(x - x.mean(0)) <= 1.0 + 1e-12
    # two collapsed interfaces are "close" by the paper's distances, yet retrieve nothing
    assert retrieval(constant, constant)["mrr"] == pytest.approx(1 / 200)
    nearly = 1.0 + 1e-4 * latents(n=200, seed=7)
    assert collapsed(nearly)


def test_ps_is_the_papers_projection_and_variants_differ_only_in_settings():
    assert PRESETS["ps"].relative == RelativeSpec()
    variants = [m for m in CODE_PATHS if uses_anchors(m) and m != "ps"]
    assert variants and all(method_spec(m).relative != RelativeSpec() for m in variants)


def test_ps_ref_actor_has_a_relative_actor_cut_and_raw_latent_critic_cuts():
    """relative_critics=false puts the projection at the actor's cut only: its critics are the ablation's, so
    they carry no projection and no penalty, and their latent is the raw task-module output."""
    nets, _ = _nets("ps+norm=layer+norm_reg=1+ref_weight=0.1+relative_critics=false")
    ablation, _ = _nets("ablation")
    task = 2 * torch.randn(64, 15) + 1
    assert nets.actor.task.relative.spec == method_spec("ps+norm=layer+norm_reg=1+ref_weight=0.1").relative
    assert float(nets.actor.task.penalty(task).detach()) > 0
    for name in NET_NAMES[1:]:
        critic = getattr(nets, name)
        assert critic.task.relative is None and float(critic.task.penalty(task)) == 0.0, name
        # same seed, same parameters as the ablation's critic: the same raw latent
        torch.testing.assert_close(critic.task(task), getattr(ablation, name).task(task))
    with torch.no_grad():
        rel = nets.actor.interface(task, None)
        assert rel.shape == (64, 8)
        torch.testing.assert_close(rel.mean(-1), torch.zeros(64), atol=1e-5, rtol=0)  # LayerNorm


def test_centring_spreads_the_similarities_and_layer_norm_standardises_them():
    """At initialisation a ReLU encoder puts every embedding in one cone: the paper's cosines
    cluster well above 0. Centring by the anchors spreads them around 0; LayerNorm gives each
    state's similarity vector zero mean and unit variance."""
    torch.manual_seed(0)
    encoder = torch.nn.Sequential(
        torch.nn.Linear(6, 64),
        torch.nn.ReLU(),
        torch.nn.Linear(64, 64),
        torch.nn.ReLU(),
        torch.nn.Linear(64, 32),
    )
    x, anchors = torch.randn(500, 6), torch.randn(32, 6)
    with torch.no_grad():
        paper = RelativeProjection(anchors)(encoder, x)
        centred = RelativeProjection(anchors, RelativeSpec(center="mean"))(encoder, x)
        normed = RelativeProjection(anchors, RelativeSpec(center="standard", norm="layer"))(encoder, x)
    assert paper.mean() > 0.3 and abs(centred.mean()) < 0.1
    assert centred.std(0).mean() > 1.5 * paper.std(0).mean()
    torch.testing.assert_close(normed.mean(-1), torch.zeros(500), atol=1e-5, rtol=0)
    torch.testing.assert_close(normed.std(-1, unbiased=False), torch.ones(500), atol=1e-3, rtol=0)


def test_mean_centring_keeps_rotation_invariance_and_standard_scaling_does_not():
    z = torch.as_tensor(latents(n=200))
    q = torch.linalg.qr(torch.randn(16, 16, generator=torch.Generator().manual_seed(3)))[0].double()
    moved = 2.0 * z @ q + 5.0  # rotate, scale and translate the embedding space
    anchors = torch.arange(0, 200, 8)
    for center, invariant in (("none", False), ("mean", True), ("standard", False)):
        projection = RelativeProjection(torch.zeros(len(anchors), 16), RelativeSpec(center=center))
        rel = [projection.project(e, projection.reference(e[anchors])) for e in (z, moved)]
        assert torch.allclose(rel[0], rel[1], atol=1e-6) == invariant, center


def test_relative_spec_rejects_bad_settings():
    with pytest.raises(ValueError, match="unknown centring 'yes'"):
        RelativeSpec(center="yes")
    with pytest.raises(ValueError, match="unknown relative norm 'batch'"):
        RelativeSpec(norm="batch")
    with pytest.raises(ValueError, match="scale must be positive"):
        RelativeSpec(scale=0)
    with pytest.raises(ValueError, match="ref_weight must be >= 0, got -1"):
        RelativeSpec(ref_weight=-1)
    with pytest.raises(ValueError, match="ref_bandwidth must be positive, got 0"):
        RelativeSpec(ref_bandwidth=0)


@pytest.mark.parametrize("method", [m for m in CODE_PATHS if uses_anchors(m)])
def test_every_relative_variant_survives_a_policy_file_round_trip(method, tmp_path):
    nets, sig = _nets(method)
    loaded, loaded_sig = load_policy(save_policy(tmp_path / "p.safetensors", nets, sig))
    assert loaded_sig == sig and loaded.actor.task.relative.spec == method_spec(method).relative
    task, robot, action = torch.randn(16, 15), torch.randn(16, 8), torch.rand(16, 7) * 2 - 1
    with torch.no_grad():
        for name in NET_NAMES[1:]:
            assert torch.equal(
                getattr(loaded, name).eval()(task, robot, action), getattr(nets, name)(task, robot, action)
            ), name
        assert torch.equal(loaded.actor.eval()(task, robot)[0], nets.actor(task, robot)[0])


def test_norm_penalty_acts_only_on_the_embedding_length():
    """The cosine is blind to |z|, so its gradient is orthogonal to z; the penalty's is radial:
    together they can turn z and hold its length, without changing what the interface computes."""
    torch.manual_seed(0)
    anchors = torch.randn(8, 15)
    projection = RelativeProjection(anchors, RelativeSpec(norm_reg=1.0))
    z = (torch.randn(4, 6) * 5).requires_grad_(True)
    z_anchors = torch.randn(8, 6)

    (grad_interface,) = torch.autograd.grad(projection.project(z, projection.reference(z_anchors)).sum(), z)
    assert torch.allclose((grad_interface * z).sum(-1), torch.zeros(4), atol=1e-5)  # orthogonal

    def encoder(x):  # a fixed "encoder" of the 4 batch inputs and the 8 anchors
        assert x.shape[0] == 12
        return torch.cat([z, z_anchors])

    (grad_penalty,) = torch.autograd.grad(projection.penalty(encoder, torch.randn(4, 15)), z)
    cosine = torch.nn.functional.cosine_similarity(grad_penalty, z, dim=-1)
    assert torch.allclose(cosine, torch.ones(4), atol=1e-5)  # radial, shrinking |z| = 5·sqrt(6) > 1

    # zero without norm_reg; a variant without the penalty adds nothing to the SAC loss
    assert RelativeProjection(anchors).penalty(encoder, torch.randn(4, 15)).item() == 0.0


@pytest.mark.parametrize("anchor_grad", [True, False])
def test_one_encoder_pass_gives_the_interface_and_the_penalties(anchor_grad):
    """The training step takes a net's interface and its penalties from one pass of the encoder
    over the states and the anchors (``penalized``): the same values and gradients as the
    interface (``forward``) beside the penalties as RelativeSpec defines them."""
    torch.manual_seed(0)
    encoder = torch.nn.Sequential(torch.nn.Linear(15, 32), torch.nn.ReLU(), torch.nn.Linear(32, 8)).double()
    spec = RelativeSpec(norm="layer", norm_reg=1.0, ref_weight=0.1, anchor_grad=anchor_grad)
    anchors, x = torch.randn(8, 15, dtype=torch.float64), torch.randn(2, 16, 15, dtype=torch.float64)
    projection = RelativeProjection(anchors, spec).double()  # float64: sums in another order agree
    weights = torch.randn(2, 16, 8, dtype=torch.float64)  # a loss that reads every entry of the interface

    def gradients(loss):
        return torch.autograd.grad(loss, list(encoder.parameters()))

    interface, penalty = projection.penalized(encoder, x)
    one_pass = gradients((weights * interface).sum() + penalty)

    anchors = projection.anchors  # as the projection holds them
    inputs = torch.cat([x.reshape(-1, 15), anchors])
    z = encoder(inputs)
    z_anchors = z[-8:] if anchor_grad else z[-8:].detach()
    relative = projection.project(z, projection.reference(z_anchors))
    target = torch.nn.functional.layer_norm(input_reference(inputs, anchors), (8,))
    reference_term = (1 - torch.cosine_similarity(relative, target)).mean()
    defined = z.norm(dim=-1).log().pow(2).mean() + 0.1 * reference_term
    apart = projection(encoder, x)
    two_passes = gradients((weights * apart).sum() + defined)

    torch.testing.assert_close(interface, apart)
    torch.testing.assert_close(penalty, defined)
    assert float(penalty) > 0
    for a, b in zip(one_pass, two_passes):
        torch.testing.assert_close(a, b)


@pytest.mark.slow
def test_norm_penalty_holds_the_embedding_length_in_training():
    """Embeddings made 10x too long, then 300 gradient steps on the SAC losses: with ``norm_reg=1``
    the penalty brings |z| back near 1; with ``ps`` the loss, blind to |z|, leaves it long."""
    from ps_ray.nets.sac import SACHyper, sac_forward, sac_losses

    lengths = {}
    for method in ("ps", "ps+norm_reg=1"):
        nets, _ = _nets(method)
        with torch.no_grad():
            for name in NET_NAMES[:3]:
                getattr(nets, name).task.body[-1].weight.mul_(10)
        params = [p for name in NET_NAMES[:3] for p in getattr(nets, name).parameters()]
        optimiser = torch.optim.Adam(params, lr=3e-3)
        gen = torch.Generator().manual_seed(1)
        for _ in range(300):
            batch = {
                "task_in": torch.randn(64, 15, generator=gen),
                "robot_in": torch.randn(64, 8, generator=gen),
                "actions": torch.rand(64, 7, generator=gen) * 2 - 1,
                "next_task_in": torch.randn(64, 15, generator=gen),
                "next_robot_in": torch.randn(64, 8, generator=gen),
            }
            fwd = sac_forward(nets, batch)
            losses = sac_losses(fwd, -torch.rand(64, generator=gen), torch.zeros(()), SACHyper(), 7)
            optimiser.zero_grad()
            losses["total"].backward()
            optimiser.step()
        with torch.no_grad():
            lengths[method] = nets.actor.task.encode(torch.randn(256, 15)).norm(dim=-1).mean().item()
    assert 0.8 < lengths["ps+norm_reg=1"] < 1.25, lengths
    assert lengths["ps"] > 5, lengths


def test_the_input_reference_depends_on_the_anchors_only():
    """1 at each anchor, in (0, 1] elsewhere, and unchanged by a per-dimension rescaling and shift of
    the task input (units): it is the same function for every source that shares the anchors."""
    g = torch.Generator().manual_seed(0)
    anchors, x = torch.randn(32, 5, generator=g).double(), torch.randn(100, 5, generator=g).double()
    ref = input_reference(x, anchors)
    assert ref.shape == (100, 32) and bool(((ref > 0) & (ref <= 1)).all())
    torch.testing.assert_close(
        torch.diag(input_reference(anchors, anchors)), torch.ones(32, dtype=torch.double)
    )
    scale, shift = torch.tensor([0.1, 2.0, 5.0, 1.0, 30.0]).double(), torch.randn(5, generator=g).double()
    torch.testing.assert_close(input_reference(x * scale + shift, anchors * scale + shift), ref)
    # a kernel of a quarter the squared width is the same kernel to the fourth power: sharper
    torch.testing.assert_close(input_reference(x, anchors, bandwidth=0.25), ref**4)
    # a dimension with no spread among the anchors does not blow up the distances
    flat = anchors.clone()
    flat[:, 0] = 0.5
    assert bool(torch.isfinite(input_reference(x, flat)).all())


@pytest.mark.slow
def test_the_reference_penalty_aligns_independent_task_modules():
    """Two task modules from different initialisations, trained on the penalties alone (the SAC
    losses left out), end with nearly the same interface on unseen states: cosine distance below
    0.01 and every probe retrieved; the interface keeps its spread. Without the reference term
    (ps+norm=layer+norm_reg=1) they stay as far apart as their random initialisations."""
    reach = NetDims(3, 8, 7)
    g = torch.Generator().manual_seed(0)
    box = lambda n: torch.rand(n, 3, generator=g) * torch.tensor([0.6, 0.6, 0.3])  # noqa: E731
    anchors, probes = box(32), box(200)
    interfaces = {}
    pulled, free = "ps+norm=layer+norm_reg=1+ref_weight=1", "ps+norm=layer+norm_reg=1"
    for method in (pulled, free):
        pair = []
        for seed in (1, 2):
            torch.manual_seed(seed)
            actor = build_actor(method, reach, interface_dim=32, hidden=64, anchors=anchors)
            actor.task.norm.update(box(4096))
            optimiser = torch.optim.Adam(actor.task.parameters(), lr=1e-3)
            for _ in range(300):
                loss = actor.task.penalty(box(128))
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
            with torch.no_grad():
                pair.append(actor.interface(probes, torch.zeros(200, 8)))
        interfaces[method] = pair
    distance = {m: (1 - torch.cosine_similarity(a, b, -1)).mean().item() for m, (a, b) in interfaces.items()}
    mrr = {m: retrieval(a.numpy(), b.numpy())["mrr"] for m, (a, b) in interfaces.items()}
    assert distance[pulled] < 0.01 and mrr[pulled] > 0.9, (distance, mrr)
    assert distance[free] > 5 * distance[pulled] and mrr[free] < mrr[pulled], (
        distance,
        mrr,
    )
    assert not collapsed(interfaces[pulled][0].numpy())
