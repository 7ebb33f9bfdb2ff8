"""Every relative link of README.md and docs/ resolves, anchors included: a rewrite that drops a
section a link names fails here instead of leaving the reader at the top of a page."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "ps_ray").rglob("*.md"))]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, markup and punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]|\[([^\]]*)\]\([^)]*\)", lambda m: m.group(1) or "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    found, seen = set(), {}
    for line in FENCE.sub("", page.read_text()).splitlines():
        if line.startswith("#"):
            base = slug(line.lstrip("#"))
            n = seen.get(base, 0)
            found.add(base if n == 0 else f"{base}-{n}")
            seen[base] = n + 1
    return found


def links(page: Path) -> list[str]:
    return [m.group(1) for m in LINK.finditer(FENCE.sub("", page.read_text()))]


def broken(page: Path) -> list[str]:
    out = []
    for target in links(page):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto: are not checked here
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists():
            out.append(f"{target}: no such file")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file):
            out.append(f"{target}: no heading with that anchor")
    return out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_and_anchor_resolves(page):
    assert broken(page) == []


def test_the_checker_fails_on_a_broken_anchor_and_a_missing_file(tmp_path):
    (tmp_path / "a.md").write_text("# A `code` title: yes\n\n## Twice\n\n## Twice\n")
    page = tmp_path / "b.md"
    page.write_text(
        "[ok](a.md#a-code-title-yes) [ok](a.md#twice-1) [bad](a.md#gone) [bad](c.md) [self](#here)\n# Here\n"
    )
    assert broken(page) == ["a.md#gone: no heading with that anchor", "c.md: no such file"]


# A measured figure as the README quotes it: an estimate with its interval, or a cost in core-hours
FIGURE = re.compile(r"[+-]?\d+\.\d+ \[[+-]?\d+\.\d+, [+-]?\d+\.\d+\]|\d+(?:\.\d+)? core-hours")


def unsourced(readme: str, docs: str) -> list[str]:
    """The figures ``readme`` quotes that no page of ``docs`` states (markup ignored)."""
    plain = docs.replace("**", "")
    return [f for f in dict.fromkeys(FIGURE.findall(readme.replace("**", ""))) if f not in plain]


def test_every_figure_the_readme_quotes_is_stated_in_the_docs():
    """The README summarises: each interval and cost it quotes comes from a study page under docs/."""
    docs = "\n".join(p.read_text() for p in sorted((ROOT / "docs").rglob("*.md")))
    readme = (ROOT / "README.md").read_text()
    assert len(FIGURE.findall(readme)) >= 10  # the check reads the results, not nothing
    assert unsourced(readme, docs) == []


def test_the_figure_check_names_a_figure_no_doc_states():
    readme = "stitched 0.81 [0.75, 0.87], gain **+0.38 [0.32, 0.44]**, 1.8 core-hours, 0.99 [0.1, 0.2]"
    docs = "| 0.81 [0.75, 0.87] | **+0.38 [0.32, 0.44]** |\n1.8 core-hours each"
    assert unsourced(readme, docs) == ["0.99 [0.1, 0.2]"]
