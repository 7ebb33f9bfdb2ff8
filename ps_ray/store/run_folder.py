"""A run folder on disk (``ps-ray train --run-dir``; its file names: :mod:`ps_ray.store.run_layout`):
the checkpoint swapped in atomically, the checkpoint a resume starts from, the metrics rows kept
up to it, and the best policy's success. Callers pass the saving; nothing here imports torch."""

from __future__ import annotations

import csv
import io
import os
import shutil
from collections.abc import Callable
from pathlib import Path

from ps_ray.errors import UserError
from ps_ray.store import checkpoint
from ps_ray.store.atomic import atomic_file, atomic_path, fsync_dir
from ps_ray.store.run_layout import (
    BEST_POLICY_FILE,
    CHECKPOINT_DIR,
    METRIC_FIELDS,
    METRICS_FILE,
    POLICY_FILE,
    REPLAY_FOLDER,
)


def _checkpoint_dirs(run_dir: Path) -> tuple[Path, Path, Path]:
    return (run_dir / f"{CHECKPOINT_DIR}.tmp", run_dir / CHECKPOINT_DIR, run_dir / f"{CHECKPOINT_DIR}.old")


def save_atomically(
    save: Callable[[Path], None], run_dir: Path, copy_out: dict[str, str] | None = None
) -> None:
    """Checkpoint (``save(folder)``) into a fresh folder, then swap it in: a kill never leaves half
    a checkpoint. Between the two renames only ``checkpoint.old`` exists; :func:`latest_checkpoint` reads it
    then, so no moment makes a started run look unstarted. Then ``copy_out`` (a checkpoint file ->
    its copy's path in the run folder; default: the policy) is copied out, each file atomically."""
    tmp, final, old = _checkpoint_dirs(run_dir)
    shutil.rmtree(tmp, ignore_errors=True)
    save(tmp)
    fsync_dir(tmp)
    if final.exists():
        shutil.rmtree(old, ignore_errors=True)
        os.replace(final, old)
    os.replace(tmp, final)
    fsync_dir(run_dir)
    shutil.rmtree(old, ignore_errors=True)
    for name, destination in (copy_out or {POLICY_FILE: POLICY_FILE}).items():
        (run_dir / destination).parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(run_dir / destination) as partial:
            shutil.copyfile(final / name, partial)


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The complete checkpoint of a run folder: ``checkpoint/``, else ``checkpoint.old/`` (a kill
    between the swap's two renames); ``checkpoint.tmp/`` is never complete. A folder that holds
    checkpoints but none that verifies is refused (CheckpointError), not silently restarted."""
    _, final, old = _checkpoint_dirs(run_dir)
    found = [d for d in (final, old) if d.is_dir()]
    best = checkpoint.latest(found, replay_store=run_dir / REPLAY_FOLDER)
    if found and best is None:
        checkpoint.verify(found[0], replay_store=run_dir / REPLAY_FOLDER)  # raises, naming the problem
    return best


def metrics_up_to(run_dir: Path, env_steps: int, fields: tuple[str, ...] = METRIC_FIELDS) -> None:
    """Drop metrics rows written after the checkpoint a run resumes from (they will be written
    again, and must not be there twice) and a last row that a kill cut short. ``fields``: the
    file's columns. The header names every column, so a file written by a ps_ray with other
    columns is rewritten in these (its one upgrade): each value kept under its name, a column it
    lacks empty, one no longer written dropped; the resumed run then appends under that header."""
    path = run_dir / METRICS_FILE
    if not path.exists():
        return
    text = path.read_text()
    complete = text if text.endswith("\n") else text[: text.rfind("\n") + 1]
    reader = csv.DictReader(io.StringIO(complete, newline=""))
    rows = list(reader)
    kept = [
        r
        for r in rows
        if None not in r and None not in r.values() and r["env_steps"] and int(r["env_steps"]) <= env_steps
    ]
    if len(kept) == len(rows) and complete == text and tuple(reader.fieldnames or ()) == tuple(fields):
        return
    with atomic_file(path) as f:
        text = io.StringIO()
        writer = csv.DictWriter(text, fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(kept)
        f.write(text.getvalue().encode())


def best_so_far(run_dir: Path) -> float:
    """The greedy success of ``best_policy.safetensors`` (stored in its metadata), -1 if none."""
    from ps_ray.store.signature import read_signature

    path = run_dir / BEST_POLICY_FILE
    if not path.exists():
        return -1.0
    try:
        return float(read_signature(path)[1].get("eval_success", -1.0))
    except UserError:
        return -1.0
