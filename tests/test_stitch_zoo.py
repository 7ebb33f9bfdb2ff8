"""Module zoo and stitching matrix: indexing a sweep's policies, the valid pairs, the paper's E1-E8."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from ps_ray.envs import make
from ps_ray.envs.core import effective_gripper
from ps_ray.nets.obs import dims_from_spaces
from ps_ray.stitching.matrix import combos, controls
from ps_ray.stitching.paper import PANDA_L3_GRIPPER, PAPER_COMBOS
from ps_ray.stitching.rule import check_stitchable, default_target
from ps_ray.stitching.stitch import env_dims
from ps_ray.stitching.zoo import ModuleZoo, read_entry
from ps_ray.store.checkpoint import seal
from tests.stitch_sources import K, fake_sweep, make_nets, spec, write_trial


# -- zoo ------------------------------------------------------------------------------------------
@pytest.fixture
def sweep(tmp_path) -> Path:
    return fake_sweep(tmp_path / "store" / "fake")


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
    from ps_ray.plan.catalogue import planned
    from ps_ray.plan.zero_shot import matrix
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
        (p.task_from_robot.short, p.task.short, p.robot_from_robot.short, p.robot_from_task.short)
        for p in matrix(grid, planned(grid), ["ablation"])
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
