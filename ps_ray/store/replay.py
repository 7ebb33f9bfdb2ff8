"""Incremental replay checkpoints: the buffer as segment files written once, not whole each time.

A checkpoint that holds the whole replay buffer rewrites it every time (about 140 MB at the
paper's 20,000 episodes; docs/state.md). Episodes never change once added, so this store keeps
them in segment files by lifetime index: segment j holds episodes [j*S, (j+1)*S) and is written
when first needed, then reused by every later checkpoint; only the segment still filling up is
written again. A checkpoint folder then holds ``replay.json`` (the buffer's state and the segment
files it needs, each with its SHA-256 and size) instead of ``replay.npz``.

Guarantees as for a whole checkpoint: each segment file is written beside and renamed (never
torn), read with ``allow_pickle=False``, and checked against the hash its checkpoint recorded.
:func:`prune` deletes only files that neither the new nor the previous checkpoint names, so a kill
at any moment leaves at least one checkpoint whose segments are all there.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ps_ray.errors import UserError
from ps_ray.store.atomic import atomic_file, file_sha256, fsync_file
from ps_ray.store.formats import REPLAY_SEGMENTS
from ps_ray.store.npz import NpzError, read_npz

FORMAT = REPLAY_SEGMENTS.id
MANIFEST_FILE = "replay.json"  # in the checkpoint folder
SEGMENT_EPISODES = 500  # about 3.7 MB of reach episodes: what a checkpoint rewrites at most


class ReplayStoreError(UserError):
    """A segment a checkpoint names is missing, altered or not a segment."""


def segment_file(first: int, end: int) -> str:
    """The file name of the segment that holds episodes [first, end)."""
    return f"ep{first:010d}-{end:010d}.npz"


def write(buffer, store: Path, previous: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write the segments of ``buffer``'s held episodes that ``previous`` (the last manifest this
    run wrote or restored) does not already cover into ``store``; returns the new manifest."""
    store.mkdir(parents=True, exist_ok=True)
    lo, hi = buffer.live_range()
    reusable = {(e["first"] // SEGMENT_EPISODES): e for e in (previous or {}).get("segments", [])}
    segments = []
    for j in range(lo // SEGMENT_EPISODES, -(-hi // SEGMENT_EPISODES)):
        first, end = max(j * SEGMENT_EPISODES, lo), min((j + 1) * SEGMENT_EPISODES, hi)
        old = reusable.get(j)
        if (
            old
            and old["first"] <= first
            and old["first"] + old["count"] >= end
            and (store / old["file"]).is_file()
        ):
            segments.append(old)  # episodes never change: a file that holds them stays valid
            continue
        path = store / segment_file(first, end)
        with atomic_file(path) as f:
            np.savez(f, **buffer.episodes(first, end))
        fsync_file(path)
        entry = {"file": path.name, "first": first, "count": end - first}
        segments.append({**entry, "sha256": file_sha256(path), "bytes": path.stat().st_size})
    return {"format": FORMAT, "state": buffer.state(), "segments": segments}


def save_manifest(manifest: dict[str, Any], checkpoint_dir: Path) -> None:
    (checkpoint_dir / MANIFEST_FILE).write_text(json.dumps(manifest))


def read_manifest(checkpoint_dir: Path) -> dict[str, Any]:
    """The checkpoint's replay manifest, checked for shape (ReplayStoreError if not one)."""
    path = checkpoint_dir / MANIFEST_FILE
    try:
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ReplayStoreError(f"{path}: unreadable replay manifest ({e})") from None
    ok = isinstance(manifest, dict) and REPLAY_SEGMENTS.reads(manifest.get("format"))
    ok = ok and isinstance(manifest.get("state"), dict) and isinstance(manifest.get("segments"), list)
    for e in manifest.get("segments", []) if ok else []:
        ok = (
            ok
            and isinstance(e, dict)
            and isinstance(e.get("file"), str)
            and Path(e["file"]).name == e["file"]
        )
        ok = ok and all(isinstance(e.get(k), int) for k in ("first", "count", "bytes"))
    if not ok:
        raise ReplayStoreError(f"{path}: not a replay manifest of format {FORMAT!r}")
    return manifest


def check(checkpoint_dir: Path, store: Path, hashed: bool = True) -> None:
    """Every segment the checkpoint names is in ``store`` with its size (and, ``hashed``, its
    SHA-256); else ReplayStoreError naming the first that is not."""
    for entry in read_manifest(checkpoint_dir)["segments"]:
        path = store / entry["file"]
        if not path.is_file():
            raise ReplayStoreError(f"{checkpoint_dir}: replay segment {path} is missing")
        if path.stat().st_size != entry["bytes"] or (hashed and file_sha256(path) != entry.get("sha256")):
            raise ReplayStoreError(f"{checkpoint_dir}: replay segment {path} does not match its checkpoint")


def load(buffer, checkpoint_dir: Path, store: Path) -> dict[str, Any]:
    """Restore ``buffer`` from the checkpoint's manifest and the segments in ``store`` (each
    checked against its hash first); returns the manifest (the next :func:`write`'s ``previous``)."""
    check(checkpoint_dir, store)
    manifest = read_manifest(checkpoint_dir)
    spec = buffer.obs_spec
    parts = []
    for entry in manifest["segments"]:
        path = store / entry["file"]
        try:
            arrays = read_npz(path)
        except NpzError as e:
            raise ReplayStoreError(f"{path}: {e}") from None
        want = {f"obs/{k}": (shape, dt) for k, (shape, dt) in spec.items()}
        want["actions"] = ((buffer.action_dim,), np.dtype(np.float32))
        steps = {"actions": buffer.horizon}
        for key, (shape, dt) in want.items():
            a = arrays.get(key)
            full = (entry["count"], steps.get(key, buffer.horizon + 1), *shape)
            if a is None or a.shape != full or a.dtype != dt:
                raise ReplayStoreError(f"{path}: {key!r} is not {dt}{full}")
        parts.append((entry["first"], arrays))
    buffer.restore(str(checkpoint_dir), manifest["state"], parts)
    return manifest


def prune(store: Path, *manifests: dict[str, Any] | None) -> int:
    """Delete the segment files of ``store`` that none of ``manifests`` names (pass the new
    checkpoint's and the previous one's); returns the bytes freed."""
    kept = {e["file"] for m in manifests if m for e in m["segments"]}
    freed = 0
    for path in store.glob("ep*.npz"):
        if path.name not in kept:
            freed += path.stat().st_size
            path.unlink(missing_ok=True)
    return freed
