"""The spec engine (ps_ray.specs.engine): values checked as a user writes them, one line per error
naming the dotted setting, and command-line flags read as the field reads them."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from ps_ray.specs.engine import SpecError, flag_kwargs, parse, type_hints
from ps_ray.specs.modes import Pairing
from ps_ray.specs.resources import ResourcesSpec
from ps_ray.specs.stage_settings import ZeroShotSpec
from ps_ray.specs.sweep import SweepSpec
from ps_ray.specs.train import TrainSpec


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"env_steps": "10"}, "env_steps must be an integer, got '10'"),  # YAML's "10" is text
        ({"env_steps": 10.0}, "env_steps must be an integer, got 10.0"),
        ({"lr": True}, "lr must be a number, got True"),
        ({"target_success": "high"}, "target_success must be a number or null, got 'high'"),
        ({"gamma": 1}, "gamma must be in (0, 1), got 1"),
        ({"seed": -1}, "seed must be an integer 0..99999, got -1"),
        ({"hidden": 0}, "hidden must be a positive integer, got 0"),
        ({"action_l2": -0.5}, "action_l2 must be a non-negative number, got -0.5"),
        ({"robot": 5}, "robot must be a name or a mapping, got 5"),
        ({"env_stepz": 1}, "train spec: unknown key 'env_stepz'; valid keys: robot, task, method"),
    ],
)
def test_a_bad_value_is_one_line_naming_the_setting(fields, message):
    with pytest.raises(SpecError) as info:
        TrainSpec.from_mapping(fields)
    assert str(info.value).startswith(message), str(info.value)
    assert "\n" not in str(info.value)


def test_values_are_kept_as_written():
    spec = TrainSpec(updates_per_step=1, lr=0.003)
    assert spec.updates_per_step == 1 and isinstance(spec.updates_per_step, int)  # not 1.0
    assert isinstance(spec.lr, float)
    settings = parse(ZeroShotSpec, {"methods": ["ablation"], "pairs": "both"})
    assert settings.methods == ("ablation",) and settings.pairs is Pairing.BOTH  # a YAML list, a word
    assert parse(ZeroShotSpec, None) == ZeroShotSpec()  # a block left empty: every default
    assert dataclasses.replace(settings, episodes=3).episodes == 3
    with pytest.raises(SpecError, match=r"^zero_shot.episodes must be a positive integer, got 0$"):
        dataclasses.replace(settings, episodes=0)  # a changed copy is checked too


def test_nested_blocks_and_missing_keys_are_named_by_their_path():
    grid = {"methods": ["ps"], "robots": ["panda"], "tasks": ["reach"], "seeds": [1]}
    with pytest.raises(SpecError, match=r"^resources.few_shot.gpu must be a non-negative number, got -1$"):
        SweepSpec.from_mapping({"name": "x", **grid, "resources": {"few_shot": {"gpu": -1}}})
    with pytest.raises(
        SpecError, match=r"^resources.grid: unknown key 'gpus'; valid keys: cpu, gpu, compile$"
    ):
        SweepSpec.from_mapping({"name": "x", **grid, "resources": {"grid": {"gpus": 1}}})
    with pytest.raises(SpecError, match=r"^resources: expected a mapping, got 3$"):
        SweepSpec.from_mapping({"name": "x", **grid, "resources": 3})
    with pytest.raises(SpecError, match=r"^x.yaml: missing key 'name'$"):
        SweepSpec.from_mapping(grid, where="x.yaml")
    assert isinstance(ResourcesSpec().train.cpu, int)


def test_a_flag_reads_its_text_as_the_field_does():
    parser = argparse.ArgumentParser()
    for name in ("updates_per_step", "env_steps", "target_success"):
        parser.add_argument(f"--{name}", **flag_kwargs(type_hints(TrainSpec)[name]))
    for name in ("methods", "pairs"):
        parser.add_argument(f"--{name}", **flag_kwargs(type_hints(ZeroShotSpec)[name]))
    args = parser.parse_args(
        "--updates_per_step 1 --env_steps 500 --target_success 0.9 --methods ps ablation --pairs both".split()
    )
    assert (args.updates_per_step, args.env_steps, args.target_success) == (1, 500, 0.9)
    assert isinstance(args.updates_per_step, int) and args.methods == ["ps", "ablation"]
    assert args.pairs == "both"
    with pytest.raises(SystemExit):
        parser.parse_args(["--pairs", "all"])  # not one of the mode's words
