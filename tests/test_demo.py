"""`ps-ray demo`: the shipped example zoo, verified file by file, stitched into a policy for a pair
none of its modules was trained on, scored beside its controls on the study's episodes."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ps_ray.stitching.example import EXAMPLE_DIR, ROWS


def demo(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ps_ray.cli", "demo", *args], capture_output=True, text=True)


@pytest.mark.e2e
@pytest.mark.slow
def test_the_demo_reproduces_the_study_and_the_stitch_beats_every_control():
    proc = demo()
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = proc.stdout
    assert "3 policy files verified (SHA-256), written by sweeps/confirm.yaml (seed 406" in out
    assert "-> panda_far/reach_blue, a pair no module was trained on" in out
    figures = {}
    for key, words in ROWS:
        ours, study = re.search(re.escape(words) + r"\s+([\d.]+)\s+([\d.]+)", out).groups()
        figures[key] = float(ours)
        assert ours == study, key  # the same files on the same episodes: the study's figure
    controls = ("robot_source", "task_source", "chance", "task_blind_floor")
    assert all(figures["stitched"] > figures[key] + 0.2 for key in controls)  # a stitch that works
    # below what a perfect map would give its robot module, which is below the oracle here
    assert figures["stitched"] < figures["ceiling"] < figures["oracle"]
    gain = figures["stitched"] - max(figures[key] for key in controls)
    assert f"transfer gain: {gain:+.2f} over the best control (task-blind floor)" in out
    # the README shows this table as the demo prints it: its block is the demo's output, line by line
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    block = readme.split("  policy   ", 1)[1].split("```", 1)[0]
    shown = [line.rstrip() for line in ("  policy   " + block).splitlines() if line.strip()]
    printed = {line.rstrip() for line in out.splitlines()}
    assert len(shown) >= 8 and [line for line in shown if line not in printed] == []


@pytest.mark.e2e
def test_a_corrupt_or_foreign_zoo_is_refused_in_one_line(tmp_path):
    zoo = tmp_path / "zoo"
    shutil.copytree(EXAMPLE_DIR, zoo)
    robot = zoo / "robot_module_source.safetensors"
    data = bytearray(robot.read_bytes())
    data[-1] ^= 0xFF
    robot.write_bytes(bytes(data))
    proc = demo("--zoo", str(zoo))
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "is not the manifest's" in proc.stderr
    assert f"{robot}: SHA-256" in proc.stderr and "a corrupt or foreign file" in proc.stderr
    manifest = json.loads((zoo / "zoo.json").read_text())
    (zoo / "zoo.json").write_text(json.dumps({**manifest, "format": "someone.else/1"}))
    proc = demo("--zoo", str(zoo))
    assert (
        proc.returncode == 2
        and "not an example zoo manifest (format ps_ray.example_zoo/1 expected)" in proc.stderr
    )
    proc = demo("--zoo", str(tmp_path / "nowhere"))
    assert proc.returncode == 2 and "nowhere/zoo.json: not an example zoo manifest" in proc.stderr
