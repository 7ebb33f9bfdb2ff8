"""Module zoo, stitching and the `ps-ray stitch` command: real policy files, real nets, no mocks."""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from safetensors.torch import save_file

from ps_ray.cli import commands as cli
from ps_ray.envs import make
from ps_ray.envs.core import effective_gripper
from ps_ray.errors import UserError
from ps_ray.nets.from_signature import nets_state, signature_of
from ps_ray.nets.modular import update_normalizers
from ps_ray.nets.obs import dims_from_spaces
from ps_ray.nets.policy_file import load_policy, save_policy
from ps_ray.nets.sac import NET_NAMES, SACNets, build_sac_nets
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import method_spec, uses_anchors
from ps_ray.specs.names import EnvPart
from ps_ray.stitching.matrix import combos, controls
from ps_ray.stitching.paper import PANDA_L3_GRIPPER, PAPER_COMBOS
from ps_ray.stitching.rule import check_stitchable, default_target
from ps_ray.stitching.stitch import env_dims, stitch_policies
from ps_ray.stitching.zoo import ModuleZoo, read_entry
from ps_ray.store.attempts import FINISHED, PARAMS_FILE, RESULT_FILE
from ps_ray.store.checkpoint import STATE_FILE, seal
from ps_ray.store.signature import Signature
from tests.code_paths import CODE_PATHS

torch.set_num_threads(1)

PUSH, PICK, REACH = NetDims(15, 8, 7), NetDims(15, 8, 8), NetDims(3, 8, 7)
K = 8  # interface dim = number of anchors


@contextlib.contextmanager
def safe_open_pt(path):
    """Every tensor and the metadata of a safetensors file, to rewrite it."""
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        tensors, metadata = {k: f.get_tensor(k) for k in f.keys()}, dict(f.metadata())
    yield tensors, metadata


def anchors_for(k: int = K, task_dim: int = 15, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(k, task_dim)).astype(np.float32)


ANCHORS, OTHER_ANCHORS = anchors_for(), anchors_for(seed=1)
SEEDS = itertools.count(10)


def make_nets(
    method: str = "ps",
    dims: NetDims = PUSH,
    *,
    interface_dim: int = K,
    hidden: int = 16,
    anchors: np.ndarray | None = ANCHORS,
    seed: int = 0,
    finished: bool = True,
) -> tuple[SACNets, Signature]:
    """Random nets with non-trivial normaliser statistics and targets that differ from the critics;
    ``finished``: a deferred relative projection (ps_distilled) is switched on, as at a run's end."""
    torch.manual_seed(seed)
    nets = build_sac_nets(
        method,
        dims,
        interface_dim=interface_dim,
        hidden=hidden,
        anchors=anchors if uses_anchors(method) else None,
    )
    g = torch.Generator().manual_seed(seed)
    update_normalizers(
        nets,
        2 * torch.randn(64, dims.task_dim, generator=g) + 1,
        torch.randn(64, dims.robot_dim, generator=g),
    )
    with torch.no_grad():
        for p in [*nets.target_critic.parameters(), *nets.target_critic_twin.parameters()]:
            p.add_(0.05 * torch.randn(p.shape, generator=g))
    if finished and method_spec(method).defer_relative:
        nets.actor.task.switch_relative_on()
    return nets, signature_of(nets, method, interface_dim, hidden)


def spec(method: str, robot, task, seed: int = 1, interface_dim: int = K) -> dict:
    """A trial's spec.json as TrainSpec writes it (robot and task as spelled in JSON)."""
    return {
        "method": method,
        "robot": EnvPart(robot).spelling,
        "task": EnvPart(task).spelling,
        "seed": seed,
        "interface_dim": interface_dim,
        "hidden": 16,
        "env_steps": 300,
    }


def write_trial(
    root: Path,
    stage_dir: str,
    trial_spec: dict,
    *,
    checkpoint: int = 2,
    trial: str | None = None,
    seed: int | None = None,
    anchor_seed: int = 0,
) -> Path:
    """A trial as Tune and ps_ray leave it, with random nets: params.json naming the trial, a
    finished result row, and a sealed checkpoint (policy.safetensors, signature.json, spec.json,
    ps_ray_state.json, manifest.json); ``checkpoint`` x 100 env steps."""
    dims = env_dims(trial_spec["robot"], trial_spec["task"])
    k = trial_spec["interface_dim"]
    nets = make_nets(
        trial_spec["method"],
        dims,
        interface_dim=k,
        anchors=anchors_for(k, dims.task_dim, anchor_seed),
        seed=next(SEEDS) if seed is None else seed,
    )
    name = trial or f"sweep_trial_{next(SEEDS):05d}"
    directory = root / stage_dir / name / f"checkpoint_{checkpoint:06d}"
    save_policy(directory / "policy.safetensors", *nets)
    (directory / "signature.json").write_text(json.dumps(dataclasses.asdict(nets[1])))
    (directory / "spec.json").write_text(json.dumps(trial_spec))
    state = {"counters": {"env_steps": 100 * checkpoint}, "iteration": checkpoint}
    (directory / STATE_FILE).write_text(json.dumps(state))
    seal(directory)
    (directory.parent / PARAMS_FILE).write_text(json.dumps({"trial": {"spec": trial_spec}}))
    row = {"env_steps": 100 * checkpoint, FINISHED: True, "timestamp": checkpoint}
    with open(directory.parent / RESULT_FILE, "a") as f:
        f.write(json.dumps(row) + "\n")
    return directory / "policy.safetensors"


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


# -- zoo ------------------------------------------------------------------------------------------
@pytest.fixture
def sweep(tmp_path) -> Path:
    root = tmp_path / "store" / "fake"
    for robot in ("panda", "panda_l3"):
        for task in ("push", "pick_cube"):
            write_trial(root, "tune", spec("ps", robot, task))
            write_trial(root, "tune", spec("ablation", robot, task))
    write_trial(root, "tune", spec("ps", PANDA_L3_GRIPPER, "push"))
    write_trial(root, "tune", spec("ps", "panda", "push", seed=2))
    write_trial(root, "tune", spec("ps", "panda", "push", interface_dim=16))
    write_trial(root, "tune_plain", spec("plain", "panda", "push"))
    return root


def test_zoo_indexes_a_tune_tree(sweep):
    zoo = ModuleZoo.from_sweep(sweep)
    keys = {str(k) for k in zoo.keys()}
    assert "ps/panda/push/1/i8" in keys and "ablation/panda_l3/pick_cube/1/i8" in keys
    assert 'ps/panda_l3{"gripper":true}/push/1/i8' in keys
    assert "ps/panda/push/1/i16" in keys and "plain/panda/push/1/i8" in keys
    assert len(zoo) == 12
    entry = zoo.get("ps/panda_l3/pick_cube/1/i8")
    assert entry.robot == "panda_l3" and entry.task == "pick_cube" and entry.stage == "train"
    assert entry.signature.action_dim == 8 and entry.signature.anchor_hash
    assert zoo.get("plain/panda/push/1/i8").stage == "plain_source"
    assert {e.key.method for e in zoo} == {"ps", "ablation", "plain"}
    assert zoo.get("ps/panda/pick_cube/1/i8").signature.action_dim == 8


def test_zoo_uses_the_latest_checkpoint_and_prefers_train_entries(tmp_path):
    root = tmp_path / "sweep"
    old = write_trial(root, "tune", spec("plain", "panda", "push"), checkpoint=1, trial="t0", seed=1)
    new = write_trial(root, "tune", spec("plain", "panda", "push"), checkpoint=12, trial="t0", seed=2)
    write_trial(root, "tune_plain", spec("plain", "panda", "push"), trial="p0", seed=3)
    zoo = ModuleZoo.from_sweep(root)
    assert len(zoo) == 1 and zoo.get("plain/panda/push/1/i8").path == new != old


def test_zoo_get_unknown_key_names_close_keys(sweep):
    zoo = ModuleZoo.from_sweep(sweep)
    with pytest.raises(ValueError, match=r"no policy 'ps/panda/psuh/1/i8'.*close keys: .*ps/panda/push/1/i8"):
        zoo.get("ps/panda/psuh/1/i8")
    with pytest.raises(ValueError, match="ps/panda/push/1/i16"):
        zoo.get("ps/panda/push/1")  # no default-dim policy; the i16 one is close


def test_zoo_refuses_corrupt_files_unless_lenient(sweep, tmp_path):
    bad = write_trial(sweep, "tune", spec("ps", "panda_l5", "push"))
    bad.write_bytes(b"not a safetensors file")  # changed after sealing: the manifest catches it
    changed = f"{bad.parent}: not a usable ps_ray checkpoint (policy.safetensors has 22 bytes"
    with pytest.raises(ValueError, match=re.escape(changed)):
        ModuleZoo.from_sweep(sweep)
    zoo = ModuleZoo.from_sweep(sweep, strict=False)
    assert len(zoo) == 12 and len(zoo.problems) == 1 and str(bad.parent) in zoo.problems[0]
    seal(bad.parent)  # sealed over a foreign file: the policy reader refuses it
    with pytest.raises(ValueError, match=re.escape(f"{bad}: not a ps_ray policy file")):
        ModuleZoo.from_sweep(sweep)
    assert len(ModuleZoo.from_sweep(sweep, strict=False).problems) == 1
    with pytest.raises(ValueError, match="no trained policies"):
        ModuleZoo.from_sweep(tmp_path / "empty")


def test_a_zoo_entry_needs_its_training_spec(tmp_path):
    path = write_trial(tmp_path, "runs", spec("ablation", "panda", "reach", seed=5), trial="r")
    assert str(read_entry(path, "run").key) == "ablation/panda/reach/5/i8"
    path.with_name("spec.json").unlink()
    with pytest.raises(ValueError, match="spec.json: missing or unreadable training spec"):
        read_entry(path, "run")


def test_zoo_from_a_real_tiny_sweep(tmp_path, ray_local, tiny_train):
    from ps_ray.pipeline.sweep import run_sweep, sweep_dir
    from ps_ray.specs.sweep import load_sweep

    train = tiny_train
    path = tmp_path / "tiny.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "name": "tiny",
                "methods": ["ps"],
                "robots": ["panda", "panda_l3"],
                "tasks": ["reach"],
                "seeds": [1],
                "interface_dims": [8],
                "train": train,
                "anchors": {"episodes": 12},
                "max_concurrent": 2,
                "storage": str(tmp_path / "store"),
            }
        )
    )
    spec_ = load_sweep(path)
    grid = run_sweep(spec_, progress=False)
    assert not [r for r in grid if r.error]
    zoo = ModuleZoo.from_sweep(sweep_dir(spec_))
    assert {str(k) for k in zoo.keys()} == {  # the plain anchor source policy included
        "ps/panda/reach/1/i8",
        "ps/panda_l3/reach/1/i8",
        "plain/panda/reach/1/i8",
    }
    assert zoo.get("plain/panda/reach/1/i8").stage == "plain_source"
    a, b = zoo.get("ps/panda/reach/1/i8"), zoo.get("ps/panda_l3/reach/1/i8")
    assert a.signature.anchor_hash == b.signature.anchor_hash  # one anchor set per sweep
    nets, signature = stitch_policies(a, b)
    from ps_ray.stitching.evaluate import evaluate

    result = evaluate((nets, signature), "panda_l3", "reach", episodes=2, repeats=1, num_envs=2)
    assert result["success_mean"] in (0.0, 0.5, 1.0)  # two fixed episodes
    # the same episodes however the envs are batched: the stitched policy is deterministic
    again = evaluate((nets, signature), "panda_l3", "reach", episodes=2, repeats=1, num_envs=1)
    assert again["success_mean"] == result["success_mean"]


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


# -- matrix and paper combinations ---------------------------------------------------------------
def test_env_dims_match_real_envs():
    for robot in ("panda", "panda_l5", PANDA_L3_GRIPPER, {"name": "panda", "gripper": False}):
        for task in ("reach", "push", "push_rocks", "pick_stick"):
            env = make(robot, task)
            assert env_dims(robot, task) == dims_from_spaces(env.observation_space, env.action_space)
            env.close()


def test_combos_is_the_valid_matrix(sweep):
    zoo = ModuleZoo.from_sweep(sweep)
    found = {(c.label, json.dumps(c.robot.spelling), c.task) for c in combos(zoo, "ps", 1)}
    gripper = json.dumps(PANDA_L3_GRIPPER)
    assert found == {
        # pick robot modules drive the gripper-enabled robot on push
        ("t: push-panda & r: pick_cube-panda_l3", gripper, "push"),
        ("t: push-panda_l3 & r: pick_cube-panda", json.dumps({"name": "panda", "gripper": True}), "push"),
        ('t: pick_cube-panda & r: push-panda_l3{"gripper":true}', gripper, "pick_cube"),
        (
            't: push-panda_l3{"gripper":true} & r: pick_cube-panda',
            json.dumps({"name": "panda", "gripper": True}),
            "push",
        ),
        # t: pick_cube-panda_l3 x r: push-panda -> pick without a gripper: refused; i16 / seed 2
        # policies have other anchors or seeds; same-arm pairs are not stitching
    }
    assert {c.task_from.key.interface_dim for c in combos(zoo, "ps", 1, interface_dim=16)} <= {16}
    assert len(combos(zoo, "ablation", 1)) == 2


def test_the_cost_model_counts_the_pairs_the_zoo_stitches(sweep):
    """One pairing rule: the pairs the cost model counts from a sweep's spec, before training, are
    the zoo's matrix after it; a pick task module never meets a robot module without a gripper."""
    from ps_ray.analysis.workload import stitch_pairs
    from ps_ray.specs.sweep import SweepSpec

    grid = SweepSpec(
        name="fake",
        methods=("ablation",),
        robots=("panda", "panda_l3"),
        tasks=("push", "pick_cube"),
        seeds=(1,),
        interface_dims=(K,),
        train={"hidden": 16},
    )
    counted = {
        (str(t.robot.short), str(t.task.short), str(r.robot.short), str(r.task.short))
        for t, r in stitch_pairs(grid, "ablation")
    }
    stitched = {
        (c.task_from.key.robot, c.task_from.key.task, c.robot_from.key.robot, c.robot_from.key.task)
        for c in combos(ModuleZoo.from_sweep(sweep), "ablation", 1)
    }
    assert counted == stitched and len(counted) == 2
    assert ("panda_l3", "pick_cube", "panda", "push") not in counted  # pick needs the gripper


def test_cross_seed_pairs_join_only_modules_whose_signatures_allow_it(tmp_path):
    """Seed 1's task modules with seed 2's robot modules (one anchor set); seed 3 trained with
    another anchor set, so no PS pair joins it. Each pair names its controls on its target."""
    for seed, anchor_seed in ((1, 0), (2, 0), (3, 7)):
        for robot in ("panda", "panda_far"):
            for task in ("reach_red", "reach_blue"):
                write_trial(tmp_path, "tune", spec("ps", robot, task, seed=seed), anchor_seed=anchor_seed)
    zoo = ModuleZoo.from_sweep(tmp_path)
    across = combos(zoo, "ps", 1, robot_seed=2)
    assert len(across) == 4  # (X, Ra) x (Y != X, Rb != Ra)
    assert {(c.task_from.key.seed, c.robot_from.key.seed) for c in across} == {(1, 2)}
    assert combos(zoo, "ps", 1, robot_seed=3) == [] and len(combos(zoo, "ps", 3)) == 4
    for combo in across:
        found = controls(zoo, combo)
        assert found["robot_source"] == combo.robot_from and found["task_source"] == combo.task_from
        oracle = found["oracle"].key  # the target pair, trained with the robot module's seed
        assert (oracle.robot, oracle.task, oracle.seed) == (combo.robot_from.key.robot, combo.task, 2)


def test_combos_over_task_variants_given_as_mappings(tmp_path):
    q1, q3 = {"name": "reach", "goal_region": "q1"}, {"name": "reach", "goal_region": "q3"}
    for robot in ("panda", "panda_l3", "panda_l5"):
        for task in (q1, q3):
            write_trial(tmp_path, "tune", spec("ps", robot, task))
    found = combos(ModuleZoo.from_sweep(tmp_path), "ps", 1)
    assert len(found) == 3 * 2 * 2  # (Ra, X) x (Rb != Ra, Y != X)
    c = next(
        c
        for c in found
        if c.task_from.key.robot == "panda" and c.robot_from.key.robot == "panda_l5" and c.task == q1
    )
    assert c.robot == "panda_l5" and c.robot_from.task == q3
    assert c.label == 't: reach{"goal_region":"q1"}-panda & r: reach{"goal_region":"q3"}-panda_l5'


def test_paper_combos_are_e1_to_e8_consistent_with_the_reference():
    names = {
        "Pu1": "push",
        "Pu2": "push_slippery",
        "Pu3": "push_rocks",
        "Pi1": "pick_cube",
        "Pi2": "pick_stick",
        "R1": "panda",
        "R2": "panda_l3",
        "R3": "panda_l5",
    }
    reference = {  # docs/authors_code.md §10: task module, robot module, target env
        "E1": ("Pu1-R1", "Pu2-R2", "Pu1-R2"),
        "E2": ("Pu2-R1", "Pu1-R2", "Pu2-R2"),
        "E3": ("Pu1-R3", "Pu3-R1", "Pu1-R1"),
        "E4": ("Pu3-R1", "Pu1-R2", "Pu3-R2"),
        "E5": ("Pi1-R1", "Pu1-R2", "Pi1-R2"),
        "E6": ("Pu1-R3", "Pi1-R2", "Pu1-R2"),
        "E7": ("Pi2-R1", "Pi1-R3", "Pi2-R3"),
        "E8": ("Pi1-R3", "Pi2-R1", "Pi1-R1"),
    }
    assert [c.name for c in PAPER_COMBOS] == list(reference)
    arm = arm_name
    for combo in PAPER_COMBOS:
        t, r, target = (s.split("-") for s in reference[combo.name])
        assert combo.label == f"t: {'-'.join(t)} & r: {'-'.join(r)}"
        assert (combo.task_from.task, arm(combo.task_from.robot)) == (names[t[0]], names[t[1]])
        assert (combo.robot_from.task, arm(combo.robot_from.robot)) == (names[r[0]], names[r[1]])
        assert (combo.target.task, arm(combo.target.robot)) == (names[target[0]], names[target[1]])
        assert combo.target.task == combo.task_from.task
        # the robot module drives its own robot: same arm, same gripper as trained
        assert effective_gripper(combo.target.robot, combo.target.task) == effective_gripper(
            combo.robot_from.robot, combo.robot_from.task
        )
        robot, task = default_target(
            {"task": combo.task_from.task}, {"robot": combo.robot_from.robot, "task": combo.robot_from.task}
        )
        assert task == combo.target.task and env_dims(robot, task) == env_dims(combo.target.robot, task)
        # stitchable for modular methods, and the stitched dims are the target env's
        sig_t = make_nets("ps", env_dims(combo.task_from.robot, combo.task_from.task))[1]
        sig_r = make_nets("ps", env_dims(combo.robot_from.robot, combo.robot_from.task))[1]
        stitched = check_stitchable(sig_t, sig_r, (combo.target.robot, combo.target.task))
        env = make(combo.target.robot, combo.target.task)
        assert stitched.dims == dims_from_spaces(env.observation_space, env.action_space)
        env.close()
    assert PAPER_COMBOS[4].robot_from.robot == PANDA_L3_GRIPPER  # E5: push robot module with gripper
    assert PAPER_COMBOS[5].target.robot == PANDA_L3_GRIPPER  # E6: pick robot module on push


def arm_name(robot) -> str:
    from ps_ray.envs.robots import ROBOTS, resolve_robot

    locked = resolve_robot(robot).locked_joints
    return next(name for name, spec in ROBOTS.items() if spec.locked_joints == locked)


def test_paper_combo_sources_are_trials_of_the_few_shot_sweep():
    from ps_ray.specs.sweep import load_sweep

    sweep_file = Path(__file__).resolve().parents[1] / "sweeps" / "few_shot.yaml"  # any working dir
    trials = {t.label() for t in load_sweep(sweep_file).trials()}
    for combo in PAPER_COMBOS:
        for method in ("ps", "ablation", "devin", "devin_large", "plain"):
            task_key, robot_key = combo.keys(method, 101)
            assert task_key in trials and robot_key in trials, (combo.name, method)


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


@pytest.mark.parametrize(
    "args, message",
    [
        ("ps/panda/push/1/i8 ablation/panda_l3/push/1/i8", "method: task module 'ps'"),
        ("ps/panda/psuh/1/i8 ps/panda_l3/push/1/i8", "close keys: ps/panda/push/1/i8"),
        ("ps/panda/pick_cube/1/i8 ps/panda_l3/push/1/i8", "needs the gripper"),
        ("CORRUPT ps/panda_l3/push/1/i8 --robot panda --task push", "not a ps_ray policy file"),
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
