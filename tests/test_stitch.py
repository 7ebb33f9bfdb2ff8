"""Stitching policies and the `ps-ray stitch` command: real policy files, real nets, no mocks."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

from ps_ray.cli import commands as cli
from ps_ray.errors import UserError
from ps_ray.nets.from_signature import nets_state
from ps_ray.nets.policy_file import load_policy, save_policy
from ps_ray.nets.sac import NET_NAMES, SACNets
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import uses_anchors
from ps_ray.stitching.paper import PANDA_L3_GRIPPER
from ps_ray.stitching.rule import check_stitchable
from ps_ray.stitching.stitch import stitch_policies
from tests.code_paths import CODE_PATHS
from tests.stitch_sources import OTHER_ANCHORS, PICK, PUSH, fake_sweep, make_nets

torch.set_num_threads(1)


@contextlib.contextmanager
def safe_open_pt(path):
    """Every tensor and the metadata of a safetensors file, to rewrite it."""
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        tensors, metadata = {k: f.get_tensor(k) for k in f.keys()}, dict(f.metadata())
    yield tensors, metadata


def inputs(dims: NetDims, batch: int = 16, seed: int = 3):
    g = torch.Generator().manual_seed(seed)
    return (
        3 * torch.randn(batch, dims.task_dim, generator=g),
        torch.randn(batch, dims.robot_dim, generator=g),
        torch.rand(batch, dims.action_dim, generator=g) * 2 - 1,
    )


def outputs(nets: SACNets, dims: NetDims) -> dict[str, torch.Tensor]:
    task, robot, action = inputs(dims)
    with torch.no_grad():
        out = dict(zip(("mean", "log_std"), nets.actor.eval()(task, robot)))
        for name in NET_NAMES[1:]:
            out[name] = getattr(nets, name).eval()(task, robot, action)
    return out


@pytest.fixture
def sweep(tmp_path) -> Path:
    return fake_sweep(tmp_path / "store" / "fake")


# -- stitching ------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", CODE_PATHS)
def test_self_stitch_is_identity(method):
    nets, signature = make_nets(method)
    stitched, stitched_sig = stitch_policies((nets, signature), (nets, signature))
    assert stitched_sig == signature
    for name in NET_NAMES:
        mine, theirs = getattr(stitched, name).state_dict(), getattr(nets, name).state_dict()
        assert mine.keys() == theirs.keys()
        assert all(torch.equal(mine[k], theirs[k]) for k in mine)
    expected, got = outputs(nets, PUSH), outputs(stitched, PUSH)
    assert all(torch.equal(expected[k], got[k]) for k in expected)


def test_a_deferred_relative_policy_is_stitched_only_once_switched_on(tmp_path):
    """ps_distilled trains on the raw latent and switches to the relative interface when its run
    finishes: the switch travels in the policy file, and a policy from before it is refused."""
    early, sig_early = make_nets("ps_distilled", seed=1, finished=False)
    done, sig_done = make_nets("ps_distilled", seed=2)
    assert (sig_early.projection_off, sig_done.projection_off) == (True, False)
    assert (sig_early.stitchable, sig_done.stitchable) == (False, True)
    path_early = save_policy(tmp_path / "early.safetensors", early, sig_early)
    path_done = save_policy(tmp_path / "done.safetensors", done, sig_done)
    assert load_policy(path_done)[0].actor.task.projection is not None
    assert load_policy(path_early)[0].actor.task.projection is None
    lying = save_policy(tmp_path / "lying.safetensors", early, sig_done)  # the switch is in both
    with pytest.raises(UserError, match="lying.safetensors: the relative projection's switch disagrees"):
        load_policy(lying)
    for pair in ((path_early, path_done), (path_done, path_early)):
        with pytest.raises(UserError, match=r"the (task|robot) module.s policy is from before"):
            stitch_policies(*pair)
    nets, _ = stitch_policies(path_done, path_done)
    x = inputs(PUSH)[:2]
    with torch.no_grad():  # the stitched actor's cut is the relative interface
        assert torch.equal(nets.actor.interface(*x), done.actor.interface(*x))
        assert not torch.equal(done.actor.interface(*x), done.actor.task.encode(x[0]))


def test_stitch_takes_task_modules_from_one_robot_modules_from_the_other(tmp_path):
    a, sig_a = make_nets("ps", PUSH, seed=1)  # push: 7-D actions
    b, sig_b = make_nets("ps", PICK, seed=2)  # pick: 8-D actions, same anchors
    path_a = save_policy(tmp_path / "a.safetensors", a, sig_a)
    path_b = save_policy(tmp_path / "b.safetensors", b, sig_b)
    nets, signature = stitch_policies(path_a, path_b)
    assert signature.dims == PICK and signature.anchor_hash == sig_a.anchor_hash
    for name in NET_NAMES:
        for part, source in (("task", a), ("robot", b)):
            got = getattr(getattr(nets, name), part).state_dict()
            want = getattr(getattr(source, name), part).state_dict()
            assert all(torch.equal(got[k], want[k]) for k in want), (name, part)
    task, robot, action = inputs(PICK)
    with torch.no_grad():
        assert torch.equal(nets.actor(task, robot)[0], b.actor.robot(a.actor.task(task), robot)[0])
        assert torch.equal(
            nets.target_critic(task, robot, action),
            b.target_critic.robot(a.target_critic.task(task), robot, action),
        )
    # saved and loaded back: the same nets, strictly checked against the signature
    loaded, loaded_sig = load_policy(save_policy(tmp_path / "s.safetensors", nets, signature))
    assert loaded_sig == signature
    assert all(
        torch.equal(x, y) for x, y in zip(outputs(loaded, PICK).values(), outputs(nets, PICK).values())
    )


@pytest.mark.parametrize(
    "task_side, robot_side, target, expected",
    [
        (
            ("ps", PUSH, {}),
            ("ablation", PUSH, {}),
            None,
            ["method: task module 'ps' vs robot module 'ablation'"],
        ),
        (
            ("ablation", PUSH, {}),
            ("ablation", PUSH, {"interface_dim": 16}),
            None,
            ["interface dim: task module 8 vs robot module 16"],
        ),
        (("ps", PUSH, {}), ("ps", PUSH, {"anchors": OTHER_ANCHORS}), None, ["anchor set: task module"]),
        (
            ("ablation", PUSH, {}),
            ("ablation", PUSH, {"hidden": 32}),
            None,
            ["hidden: task module 16 vs robot module 32"],
        ),
        (
            ("plain", PUSH, {}),
            ("plain", PICK, {}),
            None,
            ["action dim (plain needs equal dims): task module 7 vs robot module 8"],
        ),
        (
            ("ps", PUSH, {}),
            ("ps", PUSH, {}),
            ("panda", "pick_cube"),
            ["action dim: policy 7 vs target env (panda, pick_cube) 8"],
        ),
        (
            ("ps", PUSH, {}),
            ("ps", PUSH, {}),
            ({"name": "panda", "gripper": False}, "pick_cube"),
            ["pick_cube needs the gripper"],
        ),
        (
            ("ps", PUSH, {}),
            ("ps", PICK, {}),
            ("panda", "reach"),
            ["task dim: policy 15 vs target env (panda, reach) 3"],
        ),
        (("ps", PUSH, {}), ("ablation", PUSH, {"hidden": 32}), None, ["method:", "hidden:", "anchor set:"]),
    ],
)
def test_mismatches_are_named_in_one_error(task_side, robot_side, target, expected):
    sig_t = make_nets(task_side[0], task_side[1], **task_side[2])[1]
    sig_r = make_nets(robot_side[0], robot_side[1], **robot_side[2])[1]
    with pytest.raises(ValueError, match="^cannot stitch: ") as err:
        check_stitchable(sig_t, sig_r, target)
    for text in expected:
        assert text in str(err.value)
    assert "\n" not in str(err.value)


def test_devin_stitches_across_interface_dims():
    # devin's bottleneck is fixed at 16 whatever interface_dim says: the latent widths agree
    sig_t, sig_r = make_nets("devin", interface_dim=8)[1], make_nets("devin", interface_dim=128)[1]
    assert check_stitchable(sig_t, sig_r).interface_dim == 8


def test_corrupt_foreign_and_missing_files_are_refused(tmp_path):
    good, sig = make_nets("ps")
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(os.urandom(64))
    foreign = tmp_path / "foreign.safetensors"
    save_file({"w": torch.zeros(2)}, str(foreign))
    tampered = tmp_path / "tampered.safetensors"
    save_file(
        {k: v for k, v in nets_state(good).items() if ".robot." not in k},
        str(tampered),
        metadata={"format": "ps_ray.policy/1", "signature": json.dumps(dataclasses.asdict(sig))},
    )
    cases = [
        (garbage, "not a ps_ray policy file"),
        (foreign, "not a ps_ray policy file"),
        (tampered, "tensors do not match the signature"),
        (tmp_path / "nope", "no such policy file"),
    ]
    for path, message in cases:
        with pytest.raises(ValueError, match=message) as err:
            stitch_policies(path, (good, sig))
        assert str(path) in str(err.value)


# -- the command ----------------------------------------------------------------------------------
def test_cli_stitches_evaluates_and_saves(sweep, tmp_path, capsys):
    out = tmp_path / "stitched.safetensors"
    rc = cli.main(
        [
            "stitch",
            "--sweep",
            str(sweep),
            "--task-from",
            "ps/panda/push/1/i8",
            "--robot-from",
            "ps/panda_l3/pick_cube/1/i8",
            "--episodes",
            "2",
            "--repeats",
            "2",
            "--num-envs",
            "2",
            "--save",
            str(out),
        ]
    )
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "touching" in text and 'robot panda_l3{"gripper":true}, task push' in text
    nets, signature = load_policy(out)
    assert signature.action_dim == 8
    # a file path works too; the target is given explicitly
    rc = cli.main(
        [
            "stitch",
            "--task-from",
            str(out),
            "--robot-from",
            str(out),
            "--robot",
            json.dumps(PANDA_L3_GRIPPER),
            "--task",
            "push",
            "--episodes",
            "1",
            "--repeats",
            "1",
        ]
    )
    assert rc == 0


def test_the_example_zoos_modules_take_their_envs_from_its_manifest():
    """`ps-ray stitch` on the demo's own files needs no --robot/--task: the zoo's manifest says what
    each was trained on, so the target is the demo's."""
    from ps_ray.stitching.example import ExampleZoo
    from ps_ray.stitching.sources import resolve_source, resolve_target

    zoo = ExampleZoo.load()
    task, robot = (resolve_source(str(zoo.path(role))) for role in ("task_module", "robot_module"))
    assert task.spec == {"robot": "panda", "task": "reach_blue"}
    assert robot.spec == {"robot": "panda_far", "task": "reach_red"}
    assert tuple(part.text for part in resolve_target(task, robot)) == zoo.target


@pytest.mark.parametrize(
    "args, message",
    [
        ("ps/panda/push/1/i8 ablation/panda_l3/push/1/i8", "method: task module 'ps'"),
        ("ps/panda/psuh/1/i8 ps/panda_l3/push/1/i8", "close keys: ps/panda/push/1/i8"),
        ("ps/panda/pick_cube/1/i8 ps/panda_l3/push/1/i8", "needs the gripper"),
        ("CORRUPT ps/panda_l3/push/1/i8 --robot panda --task push", "not a ps_ray policy file"),
        ("CORRUPT CORRUPT", "corrupt.safetensors: not a ps_ray policy file"),  # not "no spec.json"
        ("ps/panda/push/1/i8 ps/panda_l3/push/1/i8 --robot {bad", "Expecting"),
        ("ps/panda/push/1/i8 ps/panda_l3/push/1/i8 --robot panda_l9", "unknown robot"),
    ],
)
def test_cli_bad_input_one_line_exit_2_nothing_written(sweep, tmp_path, capsys, args, message):
    corrupt = tmp_path / "corrupt.safetensors"
    corrupt.write_bytes(b"\x00" * 32)
    out = tmp_path / "never.safetensors"
    task_from, robot_from, *rest = [str(corrupt) if a == "CORRUPT" else a for a in args.split()]
    rc = cli.main(
        [
            "stitch",
            "--sweep",
            str(sweep),
            "--task-from",
            task_from,
            "--robot-from",
            robot_from,
            *rest,
            "--episodes",
            "1",
            "--save",
            str(out),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and message in err and err.count("\n") == 1, err
    assert not out.exists()


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("hidden", "64", "hidden must be an integer in 1..8192, got '64'"),
        ("interface_dim", -3, "interface_dim must be an integer in 1..8192, got -3"),
        ("hidden", 10**9, "hidden must be an integer in 1..8192, got 1000000000"),
        ("method", "psx", "method 'psx' disagrees with its settings (named 'ps')"),
        ("settings", "{}", "malformed method record ('relative')"),
        ("settings", 7, "method and settings must be strings, got 'ps' and 7"),
        ("translation", "warp", "unknown translation 'warp'; valid: none, orthogonal, affine"),
    ],
)
def test_absurd_or_wrong_typed_signatures_are_refused_in_one_line(tmp_path, field, value, message):
    nets, signature = make_nets("ps")
    path = save_policy(tmp_path / "p.safetensors", nets, signature)
    with safe_open_pt(path) as (tensors, metadata):
        data = json.loads(metadata["signature"])
        data[field] = value
        metadata["signature"] = json.dumps(data)
        save_file(tensors, str(path), metadata=metadata)
    with pytest.raises(ValueError, match=re.escape(f"{path}: bad policy signature: {message}")):
        load_policy(path)


@pytest.mark.e2e
def test_a_signature_claiming_huge_nets_is_refused_before_they_are_built(tmp_path):
    """8192 wide passes the size bound, but the file's tensors are 16 wide: refused on shapes,
    checked against nets built on the meta device. Built for real, such nets need about 6 GB; the
    check runs in a process limited to 3 GB of address space."""
    nets, signature = make_nets("ablation")
    path = save_policy(tmp_path / "p.safetensors", nets, signature)
    with safe_open_pt(path) as (tensors, metadata):
        data = json.loads(metadata["signature"])
        data["hidden"] = data["interface_dim"] = 8192
        metadata["signature"] = json.dumps(data)
        save_file(tensors, str(path), metadata=metadata)
    code = (
        "import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))\n"
        "from ps_ray.nets.policy_file import load_policy\n"
        "try:\n    load_policy(sys.argv[1])\nexcept ValueError as e:\n    print(e)"
    )
    argv = [sys.executable, "-c", code, str(path)]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith(f"{path}: tensors do not match the signature"), done.stdout


@pytest.mark.parametrize("method", ["ps", "ablation", "ps_distilled"])
def test_a_half_stitch_keeps_one_half_bit_for_bit_and_starts_the_other_fresh(method):
    """Few-shot's halves: the kept half is its source's module (weights and normaliser statistics),
    the other half is what a fresh build from the pair's seed holds (empty statistics, the
    target task's anchors), and the fresh half follows the seed."""
    from ps_ray.stitching.halves import half_stitch

    task_from, robot_from = make_nets(method, seed=1), make_nets(method, seed=2)
    keeps_robot = half_stitch(task_from, robot_from, "robot_module", seed=5)[0]
    keeps_task, signature = half_stitch(task_from, robot_from, "task_module", seed=5)
    assert signature == check_stitchable(task_from[1], robot_from[1])
    for name in NET_NAMES:
        kept_r, kept_t = getattr(keeps_robot, name), getattr(keeps_task, name)
        for key, value in getattr(robot_from[0], name).robot.state_dict().items():
            assert torch.equal(kept_r.robot.state_dict()[key], value), (name, key)
        for key, value in getattr(task_from[0], name).task.state_dict().items():
            assert torch.equal(kept_t.task.state_dict()[key], value), (name, key)
        for norm in (m for m in (kept_r.task, kept_t.robot) for m in m.modules()):
            if hasattr(norm, "count") and hasattr(norm, "clip"):
                assert norm.count.item() == 0  # a fresh half's normaliser has seen nothing
    if uses_anchors(method):
        assert torch.equal(keeps_robot.actor.anchors, task_from[0].actor.anchors)
    same = half_stitch(task_from, robot_from, "robot_module", seed=5)[0]
    other = half_stitch(task_from, robot_from, "robot_module", seed=6)[0]
    first = next(keeps_robot.actor.task.parameters())
    assert torch.equal(next(same.actor.task.parameters()), first)
    assert not torch.equal(next(other.actor.task.parameters()), first)
    with pytest.raises(ValueError, match="keep must be one of"):
        half_stitch(task_from, robot_from, "both", seed=5)
