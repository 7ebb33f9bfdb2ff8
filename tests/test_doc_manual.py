"""The manual apart from the notebook (issue 65): README.md and docs/ outside docs/notebook/ say
what holds, so they name no commit and no session of work (history lives in docs/notebook/ and
CHANGELOG.md); their short backticked pointers (`stitching.matrix.controls`) name code that
exists; and every results page answers in one order: question, sweep, command, table, verdict."""

from __future__ import annotations

import pkgutil
import re
from pathlib import Path

import pytest

import ps_ray
from tests.test_doc_links import FENCE
from tests.test_doc_names import resolves

ROOT = Path(__file__).parents[1]
DOCS = ROOT / "docs"
NOTEBOOK = DOCS / "notebook"
RESULTS = DOCS / "results"
MANUAL = [ROOT / "README.md", *sorted(p for p in DOCS.rglob("*.md") if NOTEBOOK not in p.parents)]

# A commit hash: 7-40 lowercase hex characters with at least one digit and one letter, not part of
# a longer word, path or number ("deadbeef" has no digit, "1,000,003" is a number); and any 7-40
# hex id, digits alone included, that follows the word "commit".
HASH = re.compile(r"(?<![\w.\-])(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}(?![\w\-])")
NAMED_COMMIT = re.compile(r"\bcommits?\s+(?:at\s+|from\s+)?([0-9a-f]{7,40})\b")
SESSION = re.compile(r"\bsessions?\b", re.I)
# A short pointer: identifiers joined by dots, the whole of a backticked span
POINTER = re.compile(r"`([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)+)`")
FILE_SUFFIXES = (".py", ".md", ".yaml", ".json", ".csv", ".npz", ".png", ".gif", ".html", ".safetensors")
TOP_LEVEL = {m.name for m in pkgutil.iter_modules(ps_ray.__path__)}


def commit_hashes(text: str) -> list[str]:
    """The commit hashes a page names outside its fenced code blocks."""
    prose = FENCE.sub("", text)
    return sorted(set(HASH.findall(prose)) | set(NAMED_COMMIT.findall(prose)))


def sessions(text: str) -> list[str]:
    """Each mention of a session (of work) on the page, code included."""
    return SESSION.findall(text)


def unresolved_pointers(text: str) -> list[str]:
    """Backticked `a.b[.c...]` pointers whose first part is a top-level module or subpackage of
    ps_ray and that name nothing as ``ps_ray.<pointer>`` (module import, then attributes)."""
    out = []
    for name in POINTER.findall(FENCE.sub("", text)):
        if name.split(".")[0] in TOP_LEVEL and not name.endswith(FILE_SUFFIXES):
            if not resolves(f"ps_ray.{name}"):
                out.append(name)
    return out


# A results page: its second-level headings, in this order (Figures where there are figures)
SECTIONS = [
    ("question", r"Question"),
    ("sweep", r"Sweeps?"),
    ("command", r"Run"),
    ("table", r"Tables?"),
    ("figure", r"Figures?"),
    ("verdict", r"Verdict"),
]
OPTIONAL = {"figure"}


def sections(text: str) -> dict[str, str]:
    """A page's second-level sections by heading, each with its body."""
    parts = re.split(r"^## (.+)$", FENCE.sub(lambda m: m.group(0).replace("## ", "   "), text), flags=re.M)
    return {parts[i].strip(): parts[i + 1] for i in range(1, len(parts) - 1, 2)}


def results_page_problems(text: str) -> list[str]:
    """What a results page lacks: a section the issue names, the sections' order, a command that
    prices the sweep first, a sweep file, a table (or a line saying why there is none yet)."""
    found = sections(text)
    order = []
    problems = []
    for role, pattern in SECTIONS:
        heads = [h for h in found if re.fullmatch(pattern, h)]
        if not heads:
            if role not in OPTIONAL:
                problems.append(f"no {role} section (## {pattern})")
            continue
        order.append(list(found).index(heads[0]))
        body = found[heads[0]]
        if role == "sweep" and not re.search(r"`sweeps/[\w/]+\.yaml`", body):
            problems.append("the sweep section names no sweeps/*.yaml file")
        if role == "command" and not re.search(r"ps-ray run sweeps/\S+\.yaml[^\n]*--check", body):
            problems.append("the run section does not price a sweep first (ps-ray run FILE --check)")
        if role == "table" and "|---" not in body and "None yet" not in body:
            problems.append("the table section holds no table and does not say why")
        if role == "verdict" and not body.strip():
            problems.append("the verdict section is empty")
    if order != sorted(order):
        problems.append("sections out of order: question, sweep, run, table, figure, verdict")
    return problems


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


@pytest.mark.parametrize("page", MANUAL, ids=_rel)
def test_the_manual_names_no_commit_hash_and_no_session(page):
    text = page.read_text()
    assert commit_hashes(text) == [], "commits belong in docs/notebook/ or CHANGELOG.md"
    assert sessions(text) == [], "sessions of work belong in docs/notebook/ or CHANGELOG.md"


@pytest.mark.parametrize("page", MANUAL, ids=_rel)
def test_the_manuals_short_pointers_resolve(page):
    assert unresolved_pointers(page.read_text()) == []


RESULT_PAGES = sorted(p for p in RESULTS.glob("*.md") if p.name != "README.md")


@pytest.mark.parametrize("page", RESULT_PAGES, ids=_rel)
def test_every_results_page_has_the_sections_of_a_study(page):
    assert results_page_problems(page.read_text()) == []


def test_the_results_index_lists_every_page_and_the_notebook_keeps_the_history():
    index = (RESULTS / "README.md").read_text()
    assert len(RESULT_PAGES) >= 8  # one page per study, not an empty folder
    assert [p.name for p in RESULT_PAGES if f"]({p.name})" not in index] == []
    # the history has a home: the notebook names commits and sessions, the manual points to it
    assert commit_hashes((NOTEBOOK / "transfer_log.md").read_text())
    assert sessions((NOTEBOOK / "transfer_log.md").read_text())
    assert (ROOT / "CHANGELOG.md").exists() and not (DOCS / "results.md").exists()


def test_the_checkers_flag_a_planted_page(tmp_path):
    page = tmp_path / "planted.md"
    page.write_text(
        "Trained at 4a5b6c7, its grids from commit 8719935 in session 12.\n"
        "See `stitching.matrix.controls`, `stitching.pairs.pairs` and `nets.translation.no_such`.\n"
        "```\ngit checkout 9f8e7d6\n```\n"
    )
    text = page.read_text()
    assert commit_hashes(text) == ["4a5b6c7", "8719935"]  # the fenced one is code, not a claim
    assert sessions(text) == ["session"]
    assert unresolved_pointers(text) == ["stitching.pairs.pairs", "nets.translation.no_such"]


def test_the_checkers_pass_what_is_not_a_hash_a_session_or_a_pointer():
    text = (
        "A deadbeef of 1,000,003 seeds, `RidgeCV` over 1e-8 ... 1e4, the file `zoo.json`, "
        "the key `zero_shot.pairs`, `report.few_shot_threshold`, `ps_ray.policy/2`, the path "
        "/tmp/ray/session_latest, a SHA-256 and `reset_seeds.fixed_for_run`."
    )
    assert commit_hashes(text) == [] and sessions(text) == [] and unresolved_pointers(text) == []


def test_the_results_checker_flags_a_page_without_its_sections():
    good = (
        "# A study\n\n## Question\n\nDoes it?\n\n## Sweeps\n\n`sweeps/confirm.yaml`\n\n"
        "## Run\n\n```bash\nps-ray run sweeps/confirm.yaml --check\n```\n\n"
        "## Tables\n\n| a |\n|---|\n| 1 |\n\n## Verdict\n\nIt does.\n"
    )
    assert results_page_problems(good) == []
    bad = (
        "# A study\n\n## Verdict\n\nIt does.\n\n## Question\n\nDoes it?\n\n## Sweeps\n\nnone\n\n"
        "## Run\n\n`ps-ray run sweeps/confirm.yaml`\n"
    )
    assert results_page_problems(bad) == [
        "the sweep section names no sweeps/*.yaml file",
        "the run section does not price a sweep first (ps-ray run FILE --check)",
        "no table section (## Tables?)",
        "sections out of order: question, sweep, run, table, figure, verdict",
    ]
