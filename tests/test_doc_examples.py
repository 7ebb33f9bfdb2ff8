"""The guide's Python examples run as written."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "guide.md"


def _python_block(heading: str) -> str:
    section = GUIDE.read_text().split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_guides_policy_in_python_example_runs_and_reaches_its_marker():
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(_python_block("Use a trained policy in Python"), str(GUIDE), "exec"), {})
    assert out.getvalue().strip() == "reached the blue marker: True"


def test_the_guides_gymnasium_id_names_the_same_env():
    import gymnasium

    from ps_ray.envs.registry import register
    from ps_ray.envs.robots import resolve_robot

    assert "ps_ray/PandaFarReachBlue-v0" in register(rllib=False)
    env = gymnasium.make("ps_ray/PandaFarReachBlue-v0")
    try:
        assert env.unwrapped.robot_spec == resolve_robot("panda_far")
        assert env.unwrapped.task_spec.name == "reach_blue"
    finally:
        env.close()
