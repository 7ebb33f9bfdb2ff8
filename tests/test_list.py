"""`ps-ray list`: every name a sweep may use, and every shipped sweep, once, on a line of its own."""

from __future__ import annotations

from pathlib import Path

from ps_ray.cli.commands import main
from ps_ray.envs.robots import ROBOTS
from ps_ray.envs.tasks import TASKS
from ps_ray.specs.methods import PRESETS
from ps_ray.specs.names import TRANSLATION_CHOICES, Translation

SWEEPS = sorted((Path(__file__).parents[1] / "sweeps").glob("*.yaml"))


def test_list_names_every_robot_task_method_translation_and_shipped_sweep_once(capsys):
    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    firsts = [line.split()[0] for line in lines if line.startswith("  ")]
    for name in [*ROBOTS, *TASKS, *PRESETS, *(path.name for path in SWEEPS)]:
        assert firsts.count(name) == 1, name
    (listed,) = [line for line in lines if line.startswith("  orthogonal")]
    assert listed.strip().split(", ") == list(TRANSLATION_CHOICES)
    parsed = [Translation(kind) for kind in TRANSLATION_CHOICES]  # each one a command accepts
    assert all(t == (f"{t.kind}@{t.fit}" if t.fit else t.kind) for t in parsed)  # parsed into its parts
    described = [line for line in lines if line.startswith("  ") and line.split()[0] in ROBOTS]
    assert any("joint 3 locked" in line for line in described) and any(
        "180 degrees" in line for line in described
    )
    assert all(len(line) <= 160 for line in lines if not line.startswith("  orthogonal"))
