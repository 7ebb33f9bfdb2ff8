"""Spec validation: every bad input is one line naming the bad value, before anything runs."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ps_ray.errors import UserError
from ps_ray.specs.methods import PRESETS
from ps_ray.specs.sweep import SweepSpec, load_sweep
from ps_ray.specs.train import SpecError, TrainSpec

SWEEPS = Path(__file__).resolve().parents[1] / "sweeps"


def test_train_spec_defaults_are_valid_and_label_names_the_trial():
    spec = TrainSpec()
    assert spec.label() == "ps/panda/reach/101"
    custom = TrainSpec(
        robot={"base": "panda", "locked_joints": [1]}, task={"name": "reach", "goal_region": "q2"}
    )
    assert custom.env_config == {
        "robot": {"base": "panda", "locked_joints": [1]},
        "task": {"name": "reach", "goal_region": "q2"},
    }


@pytest.mark.parametrize(
    "fields, message",
    [
        (
            {"method": "psx"},
            f"unknown method 'psx'; valid presets: {', '.join(PRESETS)} (+option=value)",
        ),
        ({"robot": "pandaa"}, "unknown robot 'pandaa'; valid robots: panda, panda_l3, panda_l5, panda_far"),
        ({"task": "pushh"}, "unknown task 'pushh'"),
        (
            {"robot": {"base": "panda", "locked_joints": [9]}},
            "bad locked joint 9; valid locked joints: 0-based arm joint indices 0..6",
        ),
        ({"env_steps": 0}, "env_steps must be a positive integer, got 0"),
        ({"gamma": 1.5}, "gamma must be in (0, 1), got 1.5"),
    ],
)
def test_bad_train_spec_values_name_the_value(fields, message):
    with pytest.raises(SpecError) as err:
        TrainSpec(**fields)
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_unknown_train_key_lists_valid_keys():
    with pytest.raises(SpecError, match=r"train spec: unknown key 'env_step'; valid keys: robot, task"):
        TrainSpec.from_mapping({"env_step": 10})


def test_resumable_changes_keep_the_identity():
    base = TrainSpec()
    assert TrainSpec(env_steps=99, eval_every=3).identity() == base.identity()
    assert TrainSpec(seed=102).identity() != base.identity()


@pytest.mark.parametrize(
    "name, n_trials",
    [
        ("smoke", 16),
        ("latent_reach", 72),
        ("zero_shot", 225),
        ("few_shot", 375),
        ("alignment_reach", 72),
        ("stitch_push", 32),
        ("push_paper", 36),
        ("push_confirm", 12),
    ],
)
def test_shipped_sweeps_load_and_expand_to_trials(name, n_trials):
    sweep = load_sweep(SWEEPS / f"{name}.yaml")
    trials = sweep.trials()
    assert (
        len(trials)
        == n_trials
        == (
            len(sweep.methods)
            * len(sweep.robots)
            * len(sweep.tasks)
            * len(sweep.seeds)
            * len(sweep.interface_dims)
        )
    )
    assert {t.method for t in trials} == set(sweep.methods)


def test_a_sweeps_description_is_its_files_opening_comment_unless_it_names_one(tmp_path):
    shipped = load_sweep(SWEEPS / "confirm2.yaml")
    assert shipped.description.startswith("The second confirmation of the transfer family's headline rows")
    assert (
        "#" not in shipped.description
        and "Price first: ps-ray run sweeps/confirm2.yaml --check" in shipped.description
    )
    named = _write(tmp_path, "# a header\n" + GOOD + "description: what it is for\n")
    assert load_sweep(named).description == "what it is for"
    # what a sweep is for is not what it trains: a folder trained under one description resumes under another
    assert load_sweep(named).training_identity() == load_sweep(_write(tmp_path, GOOD)).training_identity()


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "sweep.yaml"
    path.write_text(text)
    return path


GOOD = """name: t
methods: [ps]
robots: [panda]
tasks: [reach]
seeds: [1]
"""


@pytest.mark.e2e
@pytest.mark.parametrize(
    "text, message",
    [
        (GOOD + "colour: red\n", "unknown key 'colour'; valid keys: name, methods"),
        (GOOD + "seeds: [2]\n", "at line 6, column 1: duplicate key 'seeds' (a key may be given once)"),
        (
            GOOD + "stages: [zero_shot, train]\n",
            "stages ['zero_shot', 'train'] are not in the pipeline's order; write [train, zero_shot]",
        ),
        (GOOD + "train: {hidden: 64, hidden: 32}\n", "duplicate key 'hidden'"),
        (GOOD.replace("[ps]", "[ps, nope]"), "unknown method 'nope'"),
        (
            GOOD.replace("[panda]", "[{base: panda, locked_joints: [8]}]"),
            "bad locked joint 8; valid locked joints: 0-based arm joint indices 0..6",
        ),
        (GOOD + "train: {env_steps: -1}\n", "env_steps must be a positive integer, got -1"),
        (GOOD.replace("seeds: [1]", "seeds: abc"), "seed must be an integer 0..99999, got 'abc'"),
        (GOOD + "train: {method: ps}\n", "train.method is set by the sweep grid"),
        (GOOD + "train: {env: CartPole-v1}\n", "train.env: a sweep trains robots x tasks"),
        (
            GOOD + "stages: [train, fly]\n",
            "unknown stage 'fly'; valid stages: train, grid, zero_shot, few_shot, report",
        ),
        (GOOD + "anchors: {epizodes: 3}\n", "anchors: unknown key 'epizodes'; valid keys: file"),
        (GOOD + "grid: {held: []}\n", "grid: unknown key 'held'; valid keys: held_out, methods"),
        (GOOD + "grid: {held_out: [panda]}\n", "grid.held_out: cell 'panda' is not 'robot/task'"),
        (
            GOOD + "stages: [train, grid]\ngrid: {held_out: [panda/push]}\n",
            "grid: held-out cell 'panda/push' is not in the grid; its cells: panda/reach",
        ),
        (
            GOOD + "stages: [train, grid]\n",
            "grid: the held-out cells ['panda/reach'] leave robot 'panda' with no trained cell",
        ),
        (
            GOOD.replace("[panda]", "[panda, panda_far]").replace("[reach]", "[reach_red, reach_blue]")
            + "stages: [grid, zero_shot]\ngrid: {held_out: [panda_far/reach_blue]}\n",
            "grid: anchors.policy 'plain' rolls out the plain sources the train stage trains; add "
            "train to stages, or set anchors.policy: random or anchors.file",
        ),
        (
            GOOD + "grid: {methods: [ablation]}\n",
            "GridSettings: method 'ablation' is not trained by this sweep",
        ),
        (GOOD + "zero_shot: {episodes: 0}\n", "zero_shot.episodes must be a positive integer, got 0"),
        (
            GOOD + "zero_shot: {pairs: diagonal}\n",
            "unknown zero_shot.pairs 'diagonal'; valid: same_seed, cross_seed, both",
        ),
        (
            GOOD + "few_shot: {critic_warmup_updates: -1}\n",
            "few_shot.critic_warmup_updates must be a non-negative integer, got -1",
        ),
        (
            GOOD + "few_shot: {env_steps: 100, collect_steps: 200}\n",
            "few_shot.collect_steps must be in [0, env_steps), got 200",
        ),
        (GOOD + "few_shot: {methods: [plain]}\n", "method 'plain' is not trained by this sweep; valid: ps"),
        (GOOD + "report: [1, 2]\n", "report: expected a mapping, got [1, 2]"),
        ("name: t\nmethods: [ps\n", "malformed YAML at line"),
        ("- just\n- a list\n", "expected a mapping at the top level"),
        (GOOD.replace("seeds: [1]", "seeds: []"), "seeds must be a non-empty list"),
        (GOOD.replace("seeds: [1]", "seeds: [1, 2, 1]"), "seeds: duplicate entries 1; list each once"),
        (  # two spellings of one robot: one trial twice
            GOOD.replace("[panda]", "[panda_l3, {name: panda, locked_joints: [2]}]"),
            'robots: duplicate entries "panda_l3", {"locked_joints": [2], "name": "panda"}; list each once',
        ),
        (
            GOOD.replace("[reach]", "[reach, {name: reach}]"),
            'tasks: duplicate entries "reach"; list each once',
        ),
        (GOOD + "max_concurrent: lots\n", "sweep.max_concurrent must be an integer or null, got 'lots'"),
        (GOOD + "max_concurrent: -3\n", "sweep.max_concurrent must be a positive integer, got -3"),
        (GOOD + "max_failures: -1\n", "sweep.max_failures must be a non-negative integer, got -1"),
        (GOOD + "storage: 5\n", "sweep.storage must be a string, got 5"),
        (GOOD + "train: 5\n", "sweep.train must be a mapping, got 5"),
        (GOOD + "zero_shot: {episodes: ten}\n", "zero_shot.episodes must be an integer, got 'ten'"),
        (
            GOOD + "zero_shot: {methods: [ps, ps]}\n",
            'zero_shot.methods: duplicate entries "ps"; list each once',
        ),
        (
            GOOD + "anchors: {source_tasks: [reach, reach]}\n",
            'anchors.source_tasks: duplicate entries "reach"; list each once',
        ),
        (GOOD + "few_shot: {scratch: maybe}\n", "few_shot.scratch must be true or false, got 'maybe'"),
        (
            GOOD + "few_shot: {stitched: false, unstitched: false, scratch: false}\n",
            "few_shot: every start is off; turn on one of stitched, translation, halves, unstitched, scratch",
        ),
        (GOOD + "report: {seed: 1.5}\n", "report.seed must be an integer 0..1099511627775, got 1.5"),
        (
            GOOD + "report: {few_shot_threshold: 1.5}\n",
            "report.few_shot_threshold must be in (0, 1], got 1.5",
        ),
        (GOOD + "anchors: {robot: pandaa}\n", "anchors.robot: unknown robot 'pandaa'; valid robots: panda"),
        (GOOD + "anchors: {goals: future}\n", "unknown anchors.goals 'future'; valid: real, relabelled"),
        (GOOD + "train: {hidden: 100000}\n", "hidden must be at most 8192, got 100000"),
        (
            GOOD.replace("[panda]", "[{base: panda, locked_joints: [0, 1, 2, 3, 4, 5, 6]}]"),
            "all 7 arm joints locked leaves nothing to control; lock at most 6",
        ),
        (
            GOOD + "train: {target_success: 1.5}\n",
            "target_success must be in (0, 1], got 1.5",
        ),
        (
            GOOD.replace("[ps]", "[ps, ablation]") + "zero_shot: {translate: {ablation: [warp]}}\n",
            "zero_shot.translate.ablation: unknown translation 'warp'; valid: orthogonal, affine, "
            "affine_lstsq, orthogonal@outcome",
        ),
        (
            GOOD.replace("[ps]", "[ps, ablation]") + "zero_shot: {translate: {ablation: [affine@guess]}}\n",
            "unknown translation 'affine@guess'; valid: orthogonal, affine, affine_lstsq, "
            "orthogonal@outcome, orthogonal@shuffled, orthogonal@swapped, affine@outcome",
        ),
        (
            GOOD + "zero_shot: {translate: {ps: [anchors]}}\n",
            "zero_shot.translate.ps: unknown translation 'anchors'; valid: orthogonal, affine, "
            "affine_lstsq, orthogonal@outcome",
        ),
        (
            GOOD.replace("[ps]", "[ps, ablation]")
            + "zero_shot: {translate: {ablation: [anchors@outcome]}}\n",
            "zero_shot.translate.ablation: anchors@outcome re-anchors a relative projection, and ablation "
            "has none; methods with one: ps, ps_distilled",
        ),
        (
            GOOD + "zero_shot: {translate: {ps: [affine, anchors@outcome]}}\n",
            "zero_shot.translate: anchors@outcome sets reach marker scenes, and task reach has none; "
            "valid: the reach markers (reach_red, reach_blue, ...)",
        ),
        (
            GOOD + "zero_shot: {translate: {ps: [affine@swapped]}}\n",
            "zero_shot.translate: affine@swapped swaps marker scenes, and task reach has none; "
            "valid: tasks with markers (reach_red, push_red, ...)",
        ),
        (
            GOOD.replace("[reach]", "[push_red, push_blue]")
            + "zero_shot: {translate: {ps: [anchors@outcome]}}\n",
            "zero_shot.translate: anchors@outcome sets reach marker scenes, and task push_red has none; "
            "valid: the reach markers (reach_red, reach_blue, ...)",
        ),
        (
            GOOD.replace("[reach]", "[reach_red, push_blue]")
            + "zero_shot: {translate: {ps: [affine@swapped]}}\n",
            "zero_shot.translate: affine@swapped swaps marker scenes between two tasks of one family, "
            "and the sweep mixes Markers, PushMarkers; valid: tasks of one family",
        ),
        (
            GOOD + "zero_shot: {translate: {plain: [affine]}}\n",
            "method 'plain' is not trained by this sweep; valid: ps",
        ),
    ],
)
def test_bad_sweep_files_fail_with_one_line_naming_the_problem(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(SpecError) as err:
        load_sweep(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)
    assert "\n" not in str(err.value)


def test_the_push_family_takes_the_known_correspondence_as_an_upper_bound(tmp_path):
    text = (
        GOOD.replace("[reach]", "[push_red, push_blue]") + "zero_shot: {translate: {ps: [affine@swapped]}}\n"
    )
    spec = load_sweep(_write(tmp_path, text))
    assert [str(t) for t in spec.zero_shot.translations("ps")] == ["affine@swapped"]


def test_a_robot_or_task_given_by_name_alone_is_that_name():
    spec = SweepSpec.from_mapping(
        {
            "name": "t",
            "methods": ["ps"],
            "robots": [{"name": "panda_l5"}],
            "tasks": [{"name": "reach"}],
            "seeds": [1],
        }
    )
    assert spec.robots == ("panda_l5",) and spec.tasks == ("reach",)
    assert [t.label() for t in spec.trials()] == ["ps/panda_l5/reach/1"]
    assert TrainSpec(robot={"name": "panda"}, task={"name": "push", "object_friction": 0.1}).task == {
        "name": "push",
        "object_friction": 0.1,
    }


@pytest.mark.e2e
def test_cli_rejects_a_bad_sweep_with_exit_code_2_and_writes_nothing(tmp_path):
    path = _write(tmp_path, GOOD.replace("[ps]", "[nope]") + f"storage: {tmp_path / 'out'}\n")
    proc = subprocess.run(
        [sys.executable, "-m", "ps_ray.cli", "sweep", str(path)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2
    assert "unknown method 'nope'" in proc.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.e2e
def test_cli_rejects_bad_train_input(tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "ps_ray.cli",
            "train",
            "--robot",
            "pandaa",
            "--run-dir",
            str(tmp_path / "run"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().endswith(
        "unknown robot 'pandaa'; valid robots: panda, panda_l3, panda_l5, panda_far"
    )
    assert not (tmp_path / "run").exists()


def test_sweep_spec_is_checked_before_anything_starts():
    with pytest.raises(SpecError, match="unknown task 'swim'"):
        SweepSpec(name="x", methods=("ps",), robots=("panda",), tasks=("swim",), seeds=(1,))


def test_a_binary_sweep_file_is_refused_in_one_line(tmp_path):
    path = tmp_path / "sweep.yaml"
    path.write_bytes(b"\xff\xfe\x00name: t")
    with pytest.raises(SpecError, match=r"sweep.yaml: not a UTF-8 text file \(byte 0\)"):
        load_sweep(path)


def test_a_bad_json_robot_flag_is_one_line_but_a_bug_keeps_its_traceback(tmp_path, monkeypatch, capsys):
    from ps_ray.cli import commands as cli

    run_dir = tmp_path / "run"
    assert cli.main(["train", "--robot", '{"name": "panda",', "--run-dir", str(run_dir)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith('ps-ray train: error: --robot: \'{"name": "panda",\' is neither a name nor a JSON')
    assert "\n" not in err and not run_dir.exists()

    # a ValueError that is not a user error (here numpy's) is a bug: it is raised, not summarised
    def broken(args):
        return np.zeros(2) + np.zeros(3)

    monkeypatch.setattr(cli, "cmd_train", broken)
    with pytest.raises(ValueError, match="could not be broadcast"):
        cli.main(["train", "--run-dir", str(run_dir)])


@pytest.mark.parametrize(
    "value",
    ["push_slippery", {"name": "reach", "goal_region": "q2"}, {"base": "panda", "locked_joints": (2,)}],
)
def test_a_robot_or_task_is_one_type_whatever_its_spelling(value):
    from ps_ray.specs.names import EnvPart, parse_spec_text, spec_text

    part = EnvPart(value)
    assert parse_spec_text(spec_text(value)) == part == value  # text round trip; equal to what was written
    assert EnvPart(part) == part and hash(EnvPart(json.loads(json.dumps(part.spelling)))) == hash(part)
    assert dict(part) == ({"name": value} if isinstance(value, str) else json.loads(json.dumps(value)))
    assert spec_text({"b": 1, "a": 2}) == spec_text({"a": 2, "b": 1})  # one text per value
    # a spec normalises whatever was written, and writes the same JSON as before the type existed
    field = "task" if part.name in ("push_slippery", "reach") else "robot"
    spec = TrainSpec(**{field: value})
    assert type(getattr(spec, field)) is EnvPart and getattr(spec, field) == value
    written = spec.to_dict()[field]
    assert written == (value if isinstance(value, str) else json.loads(json.dumps(value)))
    assert TrainSpec.from_mapping(spec.to_dict()) == spec


def test_a_mapping_holding_only_a_name_is_that_name():
    from ps_ray.specs.names import EnvPart

    part = EnvPart({"name": "panda"})
    assert part == "panda" and part.spelling == "panda" and str(part) == "panda" and part.options == {}
    assert {"panda": 1}[part] == 1  # keys a dict written with the name
    assert EnvPart({"name": "panda", "gripper": True}) != "panda"
    assert TrainSpec(robot={"name": "panda"}).to_dict()["robot"] == "panda"


@pytest.mark.parametrize("field", ["robot", "task"])
def test_a_robot_or_task_of_another_type_is_refused_naming_the_field(field):
    with pytest.raises(SpecError, match=rf"^{field} must be a name or a mapping, got 5$"):
        TrainSpec(**{field: 5})


def test_a_sweep_on_a_base_file_is_the_base_with_its_keys_changed(tmp_path):
    """Mappings merge key by key, lists and values replace; the result is the same spec as the
    whole file written out; --set goes over both."""
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "family.yaml").write_text(
        "methods: [ablation]\nrobots: [panda, panda_far]\ntasks: [reach_red, reach_blue]\nseeds: [1, 2]\n"
        "train: {hidden: 64, env_steps: 800}\nzero_shot: {episodes: 6, repeats: 2}\n"
    )
    mine_text = "base: base/family.yaml\nname: mine\nseeds: [7]\ntrain: {hidden: 32}\n"
    (tmp_path / "mine.yaml").write_text(mine_text)
    (tmp_path / "whole.yaml").write_text(
        "name: mine\nmethods: [ablation]\nrobots: [panda, panda_far]\ntasks: [reach_red, reach_blue]\n"
        "seeds: [7]\ntrain: {hidden: 32, env_steps: 800}\nzero_shot: {episodes: 6, repeats: 2}\n"
    )
    mine, whole = load_sweep(tmp_path / "mine.yaml"), load_sweep(tmp_path / "whole.yaml")
    assert mine == whole and mine.train["env_steps"] == 800 and mine.seeds == (7,)
    overridden = load_sweep(tmp_path / "mine.yaml", ["zero_shot.episodes=3", "seeds=[1, 2, 3]"])
    assert overridden.zero_shot.episodes == 3 and overridden.seeds == (1, 2, 3)


@pytest.mark.parametrize(
    "text, sets, message",
    [
        (
            "base: base.yaml\nname: x\ncolour: red\n",
            [],
            "x.yaml (with its base base.yaml): unknown key 'colour'",
        ),
        ("base: x.yaml\nname: x\n", [], "x.yaml: base 'x.yaml' names a file already in its chain of bases"),
        ("base: nowhere.yaml\nname: x\n", [], "nowhere.yaml: no such sweep file"),
        ("base: base.yaml\nname: x\n", ["seeds"], "bad --set 'seeds'; write KEY=VALUE"),
        ("base: base.yaml\nname: x\n", ["seeds=[1"], "bad --set 'seeds=[1': its value is not YAML"),
        # a valid file with a bad --set: the --set is blamed, not the file
        ("base: base.yaml\nname: x\n", ["max_failures=many"], "--set max_failures=many (over "),
        ("base: base.yaml\nname: x\n", ["zero_shot.epsodes=3"], "zero_shot: unknown key 'epsodes'"),
    ],
)
def test_a_bad_base_or_override_is_one_line_naming_the_file(tmp_path, text, sets, message):
    (tmp_path / "base.yaml").write_text("methods: [ablation]\nrobots: [panda]\ntasks: [reach]\nseeds: [1]\n")
    (tmp_path / "x.yaml").write_text(text)
    with pytest.raises(UserError, match=re.escape(message)):
        load_sweep(tmp_path / "x.yaml", sets)
