"""Modes are enums compared by member: a setting that holds a mode (``scheduler``, ``pairing``,
``kind``, ...) is never compared with the bare word, where a typo would silently be false."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from ps_ray.specs import modes
from ps_ray.specs.engine import SpecError
from ps_ray.specs.search import SearchSpec
from ps_ray.specs.stage_settings import ZeroShotSpec

PACKAGE = Path(__file__).resolve().parents[1] / "ps_ray"
MODES = [
    m
    for m in vars(modes).values()
    if isinstance(m, type) and issubclass(m, modes.Mode) and m is not modes.Mode
]
WORDS = {member.value for mode in MODES for member in mode}
# The names that hold a mode: spec fields, trial records' fields and the variables that carry them
HOLDERS = {"scheduler", "metric", "policy", "goals", "pairs", "pairing", "kind_of_pair", "kind", "keep"}


def _name(node: ast.AST) -> str | None:
    return node.attr if isinstance(node, ast.Attribute) else node.id if isinstance(node, ast.Name) else None


def _words(node: ast.AST) -> set[str]:
    items = node.elts if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else [node]
    texts = {i.value for i in items if isinstance(i, ast.Constant) and isinstance(i.value, str)}
    return texts if len(texts) == len(items) else set()


def bare_mode_comparisons(source: str) -> list[tuple[int, str, str]]:
    """(line, holder, word) of every comparison of a mode holder with a mode's bare word."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            for holder in filter(lambda s: _name(s) in HOLDERS, sides):
                for other in sides:
                    found += [(node.lineno, _name(holder), w) for w in sorted(_words(other) & WORDS)]
    return found


def test_the_check_finds_a_bare_mode_word_and_passes_a_member():
    assert bare_mode_comparisons('if spec.scheduler == "none": pass') == [(1, "scheduler", "none")]
    assert bare_mode_comparisons('ok = pairing in ("same_seed", "both")') == [
        (1, "pairing", "both"),
        (1, "pairing", "same_seed"),
    ]
    assert bare_mode_comparisons("if spec.scheduler == Scheduler.NONE: pass") == []
    assert bare_mode_comparisons('if stage == "train": pass') == []  # a stage name, not a mode


def test_no_module_compares_a_mode_with_its_bare_word():
    found = [
        f"{path.relative_to(PACKAGE.parent)}:{line}: {holder} == {word!r}"
        for path in sorted(PACKAGE.rglob("*.py"))
        if path.name != "modes.py"
        for line, holder, word in bare_mode_comparisons(path.read_text())
    ]
    assert not found, "compare with the enum member instead:\n" + "\n".join(found)


@pytest.mark.parametrize(
    "build, message",
    [
        (
            lambda: ZeroShotSpec(pairs="same-seed"),
            "unknown zero_shot.pairs 'same-seed'; valid: same_seed, cross_seed, both",
        ),
        (
            lambda: SearchSpec(scheduler="hyperband"),
            "unknown search.scheduler 'hyperband'; valid: asha, none",
        ),
    ],
)
def test_a_mode_word_is_read_into_its_member_and_an_unknown_one_lists_the_choices(build, message):
    with pytest.raises(SpecError, match=message):
        build()
    assert ZeroShotSpec(pairs="both").pairs is modes.Pairing.BOTH
    assert SearchSpec(scheduler="none").scheduler is modes.Scheduler.NONE
