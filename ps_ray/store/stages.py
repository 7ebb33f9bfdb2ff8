"""The pipeline's stage markers in ``<sweep>/stages/`` (docs/state.md).

A stage that finished leaves ``<stage>.json`` with a fingerprint of the settings its outputs depend
on (its own and those of the stages before it), its one-line summary and its wall time; a stage that
started leaves ``<stage>.started.json``. ``ps-ray run`` skips a stage whose marker matches, resumes
one that started under the same fingerprint, and starts afresh one whose settings changed.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from ps_ray.specs.stages import earlier_and
from ps_ray.specs.sweep import SweepSpec
from ps_ray.store.atomic import write_text
from ps_ray.store.layout import sweep_layout


def fingerprint(spec: SweepSpec, stage: str) -> str:
    """Hash of what ``stage``'s outputs depend on: training settings and every stage up to it."""
    data = spec.to_dict()
    parts = {"train": spec.training_identity()}
    for record in earlier_and(stage):
        if record.settings and not record.changes_training and record.name in spec.stages:
            parts[record.name] = data[record.settings]
    text = json.dumps(parts, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _marker(spec: SweepSpec, stage: str, suffix: str = "") -> Path:
    return sweep_layout(spec).stages / f"{stage}{suffix}.json"


def _read(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return {}
    return data if isinstance(data, dict) else {}


def mark_started(spec: SweepSpec, stage: str) -> None:
    write_text(_marker(spec, stage, ".started"), json.dumps({"fingerprint": fingerprint(spec, stage)}))


def mark_finished(spec: SweepSpec, stage: str, summary: str, wall_s: float) -> None:
    record = {"fingerprint": fingerprint(spec, stage), "summary": summary, "wall_s": round(wall_s, 1)}
    write_text(_marker(spec, stage), json.dumps(record, indent=1, sort_keys=True))


def finished_summary(spec: SweepSpec, stage: str) -> str:
    return str(_read(_marker(spec, stage)).get("summary", ""))


def stage_wall_s(spec: SweepSpec, stage: str) -> float | None:
    """Wall seconds of a stage's last finished run, if the pipeline ran it."""
    try:
        return float(_read(_marker(spec, stage))["wall_s"])
    except (KeyError, TypeError, ValueError):
        return None


def stage_state(spec: SweepSpec, stage: str) -> str:
    """'done' (skip), 'interrupted' (resume) or 'new' (start afresh)."""
    wanted = fingerprint(spec, stage)
    if _read(_marker(spec, stage)).get("fingerprint") == wanted:
        return "done"
    return "interrupted" if _read(_marker(spec, stage, ".started")).get("fingerprint") == wanted else "new"
