"""Pointers that cannot rot: every dotted ``ps_ray.`` name in the docs, the README, the sweep
files and the package's docstrings and comments names a module or an attribute that exists.
Names that are data, not code (MLflow tag keys, file-format ids such as ``ps_ray.policy/1``),
are the string constants the package writes, and are recognised as such."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

REPO = Path(__file__).parents[1]
NAME = re.compile(r"\bps_ray(?:\.[A-Za-z_]\w*)+")
TEXTS = ("README.md", "docs/**/*.md", "ps_ray/**/*.py", "ps_ray/**/*.md", "sweeps/**/*.yaml")


def resolves(name: str) -> bool:
    """Whether ``name`` is a module, or a chain of attributes of the longest module prefix."""
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            found = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            if not hasattr(found, attr):
                return False
            found = getattr(found, attr)
        return True
    return False


def data_names() -> set[str]:
    """Dotted ``ps_ray.`` names inside the package's string constants: tag keys and format ids."""
    found = set()
    for path in (REPO / "ps_ray").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, (str, bytes)):
                text = node.value.decode(errors="replace") if isinstance(node.value, bytes) else node.value
                if "\n" not in text:  # a docstring is text to check, not data
                    found.update(NAME.findall(text))
    return found


def named() -> dict[str, set[str]]:
    """Every dotted name in the texts, with the files that use it."""
    out: dict[str, set[str]] = {}
    for pattern in TEXTS:
        for path in REPO.glob(pattern):
            for name in NAME.findall(path.read_text()):
                if not name.endswith(("_py", ".py", ".md", ".yaml")):
                    out.setdefault(name, set()).add(str(path.relative_to(REPO)))
    return out


def test_every_dotted_ps_ray_name_in_docs_and_docstrings_resolves():
    data = data_names()
    names = named()
    assert len(names) > 100  # the check reads the texts
    stale = {n: sorted(f) for n, f in names.items() if n not in data and not resolves(n)}
    assert not stale, "names of nothing: " + "; ".join(
        f"{n} in {', '.join(f)}" for n, f in sorted(stale.items())
    )
    # and it would find one: a module that a split removed
    assert not resolves("ps_ray.stitching.stitch.controls") and "ps_ray.stitching.stitch.controls" not in data
