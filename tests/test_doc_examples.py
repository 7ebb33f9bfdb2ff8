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
