"""A population of SAC learners updated as one gives each member exactly what a solo learner
gives it: same start, same batches, same noise -> the same weights, targets, temperature and
losses (to float tolerance), after 1 and after 10 updates; a member that leaves changes no other."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from ps_ray.errors import UserError
from ps_ray.nets.population import LearningRates, Population
from ps_ray.nets.sac import SACHyper, SACNets, build_sac_nets, sac_forward, sac_losses
from ps_ray.nets.solo import SoloLearner
from ps_ray.specs.dims import NetDims

DIMS = NetDims(task_dim=6, robot_dim=5, action_dim=3)
LRS = LearningRates(critic=1e-3, actor=3e-4, alpha=5e-4)
HP = SACHyper(action_l2=0.5)
TAU = 0.01


def member(method: str, seed: int):
    torch.manual_seed(seed)
    anchors = np.random.default_rng(seed).normal(size=(8, DIMS.task_dim))
    nets = build_sac_nets(
        method, DIMS, interface_dim=8, hidden=16, anchors=anchors if method == "ps" else None
    )
    for module in nets.modules():  # normaliser statistics of its own, as a trained source has
        if hasattr(module, "update"):
            module.update(torch.randn(64, module.mean.shape[0]) * (1 + seed))
    return nets


def solo_learner(nets: SACNets) -> SoloLearner:
    return SoloLearner(nets, hp=HP, lrs=LRS, tau=TAU)


def batches(k: int, size: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    widths = {"task_in": DIMS.task_dim, "robot_in": DIMS.robot_dim, "actions": DIMS.action_dim}
    widths |= {"next_task_in": DIMS.task_dim, "next_robot_in": DIMS.robot_dim}
    batch = {key: torch.randn(k, size, w, generator=g) for key, w in widths.items()}
    rewards = -(torch.rand(k, size, generator=g) < 0.7).float()
    noise = (
        torch.randn(k, size, DIMS.action_dim, generator=g),
        torch.randn(k, size, DIMS.action_dim, generator=g),
    )
    return batch, rewards, noise


def assert_same(population: Population, index: int, solo: SoloLearner):
    exported, log_alpha = population.export(index, copy.deepcopy(solo.nets))
    for (name, got), want in zip(exported.state_dict().items(), solo.nets.state_dict().values(), strict=True):
        torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-5, msg=f"member {index}: {name}")
    torch.testing.assert_close(log_alpha.reshape(1), solo.log_alpha.detach(), rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("method", ["ps", "ablation", "plain"])
def test_each_member_gets_the_updates_a_solo_learner_gives_it(method):
    starts = [member(method, seed) for seed in (1, 2, 3)]
    solos = [solo_learner(copy.deepcopy(nets)) for nets in starts]
    population = Population(starts, hp=HP, lrs=LRS, tau=TAU)
    assert len(population) == 3
    for step in range(10):
        batch, rewards, noise = batches(3, 32, seed=step)
        warmup = step < 2  # critics only for the first updates, as critic_warmup_updates does
        losses = population.update(batch, rewards, noise, warmup=warmup)
        for i, solo in enumerate(solos):
            alone = solo.update(
                {k: v[i] for k, v in batch.items()}, rewards[i], (noise[0][i], noise[1][i]), warmup=warmup
            )
            torch.testing.assert_close(losses[i], alone, rtol=1e-4, atol=1e-5)
        if step in (0, 9):
            for i, solo in enumerate(solos):
                assert_same(population, i, solo)


def test_twin_members_stay_twins_on_one_batch_and_part_on_their_own():
    """Two members from the same weights: fed the same batch and noise they stay equal, fed
    different ones they part: each moves by its own batch only."""
    twins = Population([member("ablation", 1), member("ablation", 1)], hp=HP, lrs=LRS, tau=TAU)
    same, rewards, noise = batches(1, 16, seed=7)
    both = {k: v.expand(2, *v.shape[1:]) for k, v in same.items()}
    twins.update(both, rewards.expand(2, -1), tuple(n.expand(2, *n.shape[1:]) for n in noise))
    weights = [
        torch.cat([p.flatten() for p in twins.export(i, member("ablation", 1))[0].parameters()])
        for i in (0, 1)
    ]
    assert torch.equal(weights[0], weights[1])
    twins.update(*batches(2, 16, seed=8))
    weights = [
        torch.cat([p.flatten() for p in twins.export(i, member("ablation", 1))[0].parameters()])
        for i in (0, 1)
    ]
    assert not torch.equal(weights[0], weights[1])


def test_a_member_that_leaves_changes_no_other():
    starts = [member("ps", seed) for seed in (1, 2, 3)]
    together = Population([copy.deepcopy(n) for n in starts], hp=HP, lrs=LRS, tau=TAU)
    apart = Population([copy.deepcopy(n) for n in (starts[0], starts[2])], hp=HP, lrs=LRS, tau=TAU)
    for step in range(6):
        batch, rewards, noise = batches(3, 16, seed=100 + step)
        if step == 3:  # member 1 stops (its target reached): exported, and the rest go on
            together.keep([0, 2])
        if step >= 3:
            batch = {k: v[[0, 2]] for k, v in batch.items()}
            rewards, noise = rewards[[0, 2]], (noise[0][[0, 2]], noise[1][[0, 2]])
            together.update(batch, rewards, noise)
            apart.update(batch, rewards, noise)
        else:
            together.update(batch, rewards, noise)
            pick = [0, 2]
            apart.update(
                {k: v[pick] for k, v in batch.items()}, rewards[pick], (noise[0][pick], noise[1][pick])
            )
    assert len(together) == 2
    for i in range(2):
        a = together.export(i, copy.deepcopy(starts[0]))[0].state_dict()
        b = apart.export(i, copy.deepcopy(starts[0]))[0].state_dict()
        for name in a:
            torch.testing.assert_close(a[name], b[name], rtol=1e-5, atol=1e-6, msg=name)


def test_a_population_refuses_to_be_empty():
    with pytest.raises(ValueError, match="at least one member"):
        Population([])


def test_the_update_benchmark_prices_a_population_per_source(capsys):
    """`ps-ray bench update --population K ...` prints one row per K beside the solo learner,
    with the cost per source (widths given: no env needed, as on a GPU host)."""
    from ps_ray.bench import update

    update.main(
        ["--dims", "15,8,7", "--methods", "ablation", "--population", "2", "1"]
        + ["--rounds", "1", "--updates", "1", "--batch-size", "32", "--interface-dim", "16"]
    )
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("ablation on cpu, batch 32, interface 16")
    rows = [line.split() for line in lines[2:]]
    assert [r[0] for r in rows] == ["1", "1", "2"] and rows[0][1] == "solo"
    solo, two = float(rows[0][2]), rows[2]  # K = 2: all of its update, then per source
    assert float(two[2]) == pytest.approx(float(two[1]) / 2, abs=0.01) and solo > 0


@pytest.mark.parametrize("method", ["ps", "ablation", "plain"])
def test_a_batched_pass_over_members_that_keep_their_own_parameters_is_their_solo_passes(method):
    """members_forward + members_losses (the RLlib population learner's pass) give each member
    the outputs, losses and gradients its own sac_forward + sac_losses give it."""
    from ps_ray.nets.population import members_forward, members_losses

    batched = [member(method, seed) for seed in (1, 2, 3)]
    alone = [copy.deepcopy(nets) for nets in batched]
    batch, rewards, noise = batches(3, 32, seed=0)
    log_alpha = torch.tensor([0.1, -0.2, 0.3], requires_grad=True)
    fwd = members_forward(batched, batch, noise)
    losses = members_losses(fwd, rewards, log_alpha, HP, DIMS.action_dim)
    losses["total"].sum().backward()
    log_alpha_alone, total = log_alpha.detach().clone().requires_grad_(), 0.0
    for i, nets in enumerate(alone):
        own = sac_forward(nets, {k: v[i] for k, v in batch.items()}, (noise[0][i], noise[1][i]))
        for name, value in own.items():
            torch.testing.assert_close(fwd[name][i], value, rtol=1e-5, atol=1e-6, msg=name)
        own_losses = sac_losses(own, rewards[i], log_alpha_alone[i], HP, DIMS.action_dim)
        for name, value in own_losses.items():
            torch.testing.assert_close(losses[name][i], value, rtol=1e-5, atol=1e-6, msg=name)
        total = total + own_losses["total"]
    total.backward()
    for i, (ours, theirs) in enumerate(zip(batched, alone)):
        for (name, got), want in zip(ours.named_parameters(), theirs.parameters(), strict=True):
            if want.grad is None:  # targets: no gradient either way
                assert got.grad is None, name
            else:
                torch.testing.assert_close(got.grad, want.grad, rtol=1e-4, atol=1e-6, msg=f"{i}: {name}")
    torch.testing.assert_close(log_alpha.grad, log_alpha_alone.grad)


def test_a_captured_update_is_asked_for_on_a_gpu_only(capsys):
    """`--graph` (a population's whole update as one CUDA graph) names what it needs, on a CPU
    in one line with exit 2; the learner refuses capture without capturable Adam."""
    from ps_ray.bench import update

    with pytest.raises(SystemExit) as stop:
        update.main(["--dims", "15,8,7", "--methods", "ablation", "--population", "2", "--graph"])
    assert stop.value.code == 2
    assert "--graph captures a population's update on a GPU: give --population K --devices cuda" in (
        capsys.readouterr().err
    )
    population = Population([member("ablation", 1)])
    with pytest.raises(ValueError, match="capturable=True"):
        population.captured(*batches(1, 8, seed=0)[:2])
    capturable = Population([member("ablation", 1)], capturable=True)
    with pytest.raises(ValueError, match="at least one warm-up update, got 0"):
        capturable.captured(*batches(1, 8, seed=0)[:2], warmups=0)


def test_the_gpu_check_finds_a_population_equal_to_solo_learners_and_says_what_a_cpu_leaves_out(capsys):
    """`ps-ray bench gpu` (a GPU host's one call) on this CPU: the eager population at the training
    widths is within the tolerance of solo learners after 2 and 10 updates, and so are the batched
    pass's gradients; the graph rows are left out and said to be, and the cost table follows."""
    from ps_ray.bench import gpu

    gpu.main(
        ["--device", "cpu", "--members", "2", "--population", "1", "2", "--rounds", "1", "--updates", "1"]
    )
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("cpu (no CUDA graph here), torch ") and out[0].endswith("(tf32 off)")
    assert out[1] == "2 ablation members, widths 15,8,7, against solo learners:"
    checks = [line.split() for line in out[2:6] if line.split()[0] == "eager"]
    assert [(" ".join(c[:5]), c[6]) for c in checks] == [
        ("eager population vs solo learners", "2"),
        ("eager population vs solo learners", "10"),
    ]
    assert all(float(c[10]) < 1e-3 and c[11] == "ok" for c in checks)  # rounding: about 1e-4 and less
    reach = [line.split() for line in out[2:6] if line.split()[0] == "one"]
    assert [c[-1] for c in reach] == ["(yardstick)", "(yardstick)"]  # not checked: what a rounding reaches
    batched = out[6].split()  # the RLlib population learner's pass: each member's gradients
    assert batched[:2] == ["batched", "pass"] and float(batched[-2]) < 1e-5 and batched[-1] == "ok"
    assert not any("captured" in line for line in out)
    assert [line.split()[0] for line in out[9:]] == ["1", "1", "2"]  # solo, then K = 1 and 2


def test_the_gpu_checks_gap_is_about_one_for_a_member_fed_anothers_batches():
    """The gap is a fraction of how far the updates moved each tensor: a population that hands
    each member the other's batches is about 1 away from the solo learners, far over the 1e-2
    the check allows."""
    from ps_ray.bench import gpu

    dims = NetDims(15, 8, 7)
    start = gpu.members("ablation", dims, 2, 16, "cpu")
    solos = [SoloLearner(copy.deepcopy(nets)) for nets in start]
    swapped = Population([copy.deepcopy(nets) for nets in start])
    for step in range(3):
        batch, rewards, noise = gpu.inputs(dims, 2, 64, step, "cpu")
        for i, learner in enumerate(solos):
            learner.update({k: v[i] for k, v in batch.items()}, rewards[i], (noise[0][i], noise[1][i]))
        other = [1, 0]
        swapped.update(
            {k: v[other] for k, v in batch.items()}, rewards[other], (noise[0][other], noise[1][other])
        )
    assert gpu.largest_gap(gpu.member_states(swapped, start), gpu.member_states(solos, start), start) > 0.5


def test_the_gpu_check_fails_when_a_population_mixes_up_its_members(capsys, monkeypatch):
    """A population that hands each member the other's batches is caught at the default tolerance
    (1e-2) by both eager rows; the RLlib learner's batched pass, which this fault leaves alone, stays
    ok. (A population of one on some CPUs equals its solo learner to the last bit, so a tiny
    tolerance alone is no way to reach the failure.)"""
    from ps_ray.bench import gpu

    update = Population.update

    def mixed_up(self, batch, rewards, noise=None, warmup=False):  # member i gets member i-1's inputs
        def other(tensor):
            return tensor.roll(1, dims=0)

        noise = None if noise is None else tuple(map(other, noise))
        return update(self, {k: other(v) for k, v in batch.items()}, other(rewards), noise, warmup)

    monkeypatch.setattr(Population, "update", mixed_up)
    with pytest.raises(SystemExit, match=r"^2 equality check\(s\) over the tolerance 0.01$"):
        gpu.main(
            ["--device", "cpu", "--members", "2", "--population", "1", "--rounds", "1"] + ["--updates", "1"]
        )
    out = capsys.readouterr().out
    eager = [line for line in out.splitlines() if line.strip().startswith("eager population")]
    assert len(eager) == 2 and all(line.endswith("OVER 0.01") for line in eager)
    assert all(float(line.split()[-3]) > 0.5 for line in eager)  # about 1: a member moved as another
    assert next(line for line in out.splitlines() if "batched pass" in line).endswith("ok")


def test_the_gpu_check_refuses_what_it_cannot_check_in_one_line(capsys):
    from ps_ray.bench import gpu

    with pytest.raises(SystemExit) as stop:
        gpu.main(["--device", "cpu", "--check-updates", "1"])
    assert stop.value.code == 2
    assert "--check-updates 1: at least 2 (the graph's first replay is the 2nd)" in capsys.readouterr().err
    with pytest.raises(UserError, match="unknown method 'psx'; valid presets: ps, ps_distilled, ablation"):
        gpu.main(["--device", "cpu", "--method", "psx"])
