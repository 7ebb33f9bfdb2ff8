"""Where a command writes, checked before it does: one line for a place that cannot take it."""

from __future__ import annotations

import tempfile
from pathlib import Path

from ps_ray.errors import UserError


def writable_folder(folder: Path) -> None:
    """A folder a run could make and write (its nearest existing parent takes a folder made and
    removed at once); else one line."""
    parent = next(p for p in (folder, *folder.parents) if p.exists())
    try:
        if not parent.is_dir():
            raise NotADirectoryError(0, f"{parent} is a file, not a folder")
        with tempfile.TemporaryDirectory(dir=parent, prefix=".ps_ray_check."):
            pass
    except OSError as e:
        raise UserError(f"{folder}: cannot write the sweep folder ({e.strerror})") from None


def output_file(path: str) -> Path:
    """An output file's folder, made now that the inputs are checked; a place that cannot hold a
    file (under a file, a read-only or pseudo file system, a folder by that name) is bad input."""
    path = Path(path)
    blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise UserError(f"{path}: cannot write here ({blocking} is a file, not a folder)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"{path}: cannot write here ({e.strerror})") from None
    if path.is_dir():
        raise UserError(f"{path}: is a folder; give a file name")
    try:  # the one sure test: a file made and removed beside it
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}."):
            pass
    except OSError as e:
        raise UserError(f"{path}: cannot write here ({e.strerror})") from None
    return path
