"""The report page: sections of figures, tables and clips, in order, and their one
self-contained HTML file (figures and clips embedded as data URIs, so it opens anywhere)."""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from ps_ray.analysis import clips
from ps_ray.specs.names import readable, short_name
from ps_ray.specs.sweep import SweepSpec
from ps_ray.store.layout import sweep_layout


@dataclass
class Section:
    title: str
    intro: str = ""
    # ("figure", Path) | ("table", (caption, frame)) | ("clips", (pair label, [Clip, ...]))
    items: list[tuple[str, object]] = field(default_factory=list)


@dataclass
class Headline:
    """The per-method figures the report's summary puts at the top, each filled by its section
    (None where the sweep has no such section)."""

    steps: pd.DataFrame | None = None  # env steps to the success target, per method
    sources: pd.DataFrame | None = None  # each source's final success
    collapsed: pd.Series | None = None  # collapsed interfaces per method
    alignment: pd.DataFrame | None = None  # latent distances and retrieval scores
    zero_shot: pd.DataFrame | None = None  # zero-shot success per method (and translation)
    transfer: pd.DataFrame | None = None  # transfer gain against the controls and chance


@dataclass
class Report:
    """What the page shows, in order; files are written under ``root`` as they are added."""

    root: Path
    sections: list[Section] = field(default_factory=list)
    metrics: dict[str, float] = field(default_factory=dict)
    headline: Headline = field(default_factory=Headline)

    def section(self, title: str, intro: str = "", first: bool = False) -> Section:
        """A new section at the end of the page (``first``: at the top)."""
        section = Section(title, intro)
        self.sections.insert(0 if first else len(self.sections), section)
        return section

    def figure(self, section: Section, name: str, draw: Callable[[Path], Path]) -> None:
        section.items.append(("figure", draw(self.root / "figures" / f"{name}.png")))

    def table(
        self,
        section: Section,
        name: str,
        caption: str,
        frame: pd.DataFrame,
        numbers: pd.DataFrame | None = None,
    ) -> None:
        path = self.root / "tables" / f"{name}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        (frame if numbers is None else numbers).to_csv(path)
        section.items.append(("table", (caption, frame)))

    def shown(self, section: Section, caption: str, frame: pd.DataFrame) -> None:
        """A table for the page only: another view of a table already saved (a wide one split)."""
        section.items.append(("table", (caption, frame)))


STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
h1 { border-bottom: 2px solid #444; } h2 { margin-top: 2em; border-bottom: 1px solid #bbb; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: right; }
th { background: #f0f0f0; } caption { font-weight: bold; text-align: left; padding: 4px 0; }
img { max-width: 100%; display: block; margin: 1em 0; } .meta td { text-align: left; }
.clips td { text-align: left; vertical-align: top; width: 240px; } .clips img { margin: 0; }
.caption { font-size: 0.8em; } .wide { overflow-x: auto; max-width: 100%; }
"""


def prose(text: str) -> str:
    """A section's text as HTML: escaped, and `code` spans (as the notes and the README write
    commands and names) set as code, not left as literal backticks."""
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", html.escape(text))


def render_html(spec: SweepSpec, report: Report) -> str:
    """One page, figures embedded as data URIs, so the file opens anywhere without its folder."""
    from ps_ray.store.tracking import git_commit

    esc = html.escape
    meta = {
        "methods": ", ".join(spec.methods),
        "robots": ", ".join(readable(short_name(r)) for r in spec.robots),
        "tasks": ", ".join(readable(short_name(t)) for t in spec.tasks),
        "seeds": ", ".join(map(str, spec.seeds)),
        "interface dims": ", ".join(map(str, spec.interface_dims)),
        "stages": ", ".join(spec.stages),
        "code": git_commit() or "unknown",
        "ran": _ran(spec),
        "libraries": _versions(),
    }
    parts = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>ps_ray report: {esc(spec.name)}</title><style>{STYLE}</style></head><body>",
        f"<h1>ps_ray report: {esc(spec.name)}</h1>",
        "<table class='meta'>",
        *(f"<tr><th>{esc(k)}</th><td>{esc(v)}</td></tr>" for k, v in meta.items()),
        "</table>",
    ]
    parts.append(
        "<ul>"
        + "".join(f"<li><a href='#s{i}'>{esc(s.title)}</a></li>" for i, s in enumerate(report.sections))
        + "</ul>"
    )
    for index, section in enumerate(report.sections):
        parts.append(f"<h2 id='s{index}'>{esc(section.title)}</h2><p>{prose(section.intro)}</p>")
        for kind, item in section.items:
            if kind == "figure":
                data = base64.b64encode(item.read_bytes()).decode()
                parts.append(f"<img alt='{esc(item.stem)}' src='data:image/png;base64,{data}'>")
            elif kind == "clips":
                label, row = item
                parts.append(f"<h3>{esc(readable(label))}</h3><table class='clips'><tr><th>method</th>")
                parts += [f"<th>{esc(role)}</th>" for role in clips.ROLES]
                for method in dict.fromkeys(c.method for c in row):
                    parts.append(f"<tr><th>{esc(method)}</th>")
                    for clip in (c for c in row if c.method == method):
                        data = base64.b64encode(clip.path.read_bytes()).decode()
                        verdict = "reached the goal" if clip.success else "did not reach the goal"
                        verdict += f" (ended {100 * clip.distance:.1f} cm from it)"
                        parts.append(
                            f"<td><img alt='{esc(clip.path.stem)}' src='data:image/gif;base64,{data}'>"
                            f"<div class='caption'>{esc(readable(clip.env))}: {verdict}</div></td>"
                        )
                    parts.append("</tr>")
                parts.append("</table>")
            else:
                caption, frame = item
                head, rest = _table_html(frame).split(">", 1)
                parts.append(f"<div class='wide'>{head}><caption>{esc(caption)}</caption>{rest}</div>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _table_html(frame: pd.DataFrame) -> str:
    """A table as a reader sees it: labels in words, the index as ordinary columns (no index
    column of row numbers, no header row of index names), numbers to three significant figures
    (counts and env steps whole, with thousands separators), NaN as a dash."""
    shown = frame if isinstance(frame.index, pd.RangeIndex) else frame.reset_index()
    if isinstance(shown.columns, pd.MultiIndex):  # ("ps", "success") -> "ps success": one header row
        shown.columns = [" ".join(str(part) for part in column if str(part)) for column in shown.columns]
    shown = shown.rename_axis(columns=None).rename(columns=_readable).map(_readable)
    return shown.to_html(border=0, na_rep="–", index=False, float_format=_number)


def _number(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 1000 or (x == int(x) and abs(x) >= 100) else f"{x:.3g}"


def _ran(spec: SweepSpec) -> str:
    """When the sweep's last stage before the report finished (its marker's time; else when the
    spec was recorded): a date a rebuilt report keeps, so the page stays the same bytes."""

    where = sweep_layout(spec)
    marks = [p for p in where.stages.glob("*.json") if not p.name.startswith("report")]
    times = [p.stat().st_mtime for p in marks or [where.spec_file] if p.exists()]
    return datetime.fromtimestamp(max(times), UTC).strftime("%Y-%m-%d %H:%M UTC") if times else "–"


def _versions() -> str:
    """The versions of the libraries a result depends on, as installed."""
    from importlib.metadata import PackageNotFoundError, version

    found = []
    for name in ("ps_ray", "ray", "torch", "pybullet", "gymnasium", "scikit-learn", "mlflow"):
        try:
            found.append(f"{name} {version(name)}")
        except PackageNotFoundError:
            continue
    return ", ".join(found)


def _readable(value: object) -> object:
    """A table cell or label as :func:`ps_ray.specs.names.readable` writes it (text only)."""
    return readable(value) if isinstance(value, str) else value
