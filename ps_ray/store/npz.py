"""Reading numpy files without pickle: the one reader of every ps_ray .npz/.npy format (anchor
sets, task-state files, the replay buffer). Only zip archives reach ``np.load`` as .npz and only
.npy headers as .npy, always with ``allow_pickle=False``; every problem is one :class:`NpzError`
line saying what is wrong (the caller adds the file name)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ps_ray.errors import UserError

ZIP_MAGIC = b"PK\x03\x04"
NPY_MAGIC = b"\x93NUMPY"


class NpzError(UserError):
    """What is wrong with a file, in one line, without its name."""


def magic(path: str | Path) -> bytes:
    """The first bytes of a file (FileNotFoundError passes through)."""
    with open(path, "rb") as fh:
        return fh.read(6)


def _first_line(exc: Exception) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _refuse(exc: Exception, what: str) -> NpzError:
    msg = _first_line(exc)
    if "pickle" in msg.lower():
        return NpzError("it contains pickled (object) data, which is never loaded")
    return NpzError(f"unreadable {what} ({msg})")


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Every member of an .npz archive as an array."""
    head = magic(path)
    if not head.startswith(ZIP_MAGIC):
        raise NpzError(f"not an .npz (zip) archive (starts with {head[:4]!r})")
    try:
        with np.load(path, allow_pickle=False) as npz:
            members = {key: npz[key] for key in npz.files}
    except Exception as exc:  # zipfile, zlib, numpy format errors: all mean "bad file"
        raise _refuse(exc, ".npz archive") from None
    for key, value in members.items():
        if not isinstance(value, np.ndarray):  # numpy hands back raw bytes for non-.npy members
            raise NpzError(f"unreadable .npz archive (member {key!r} is not a .npy array)")
    return members


def read_npy(path: str | Path) -> np.ndarray:
    """The array of an .npy file."""
    if not magic(path).startswith(NPY_MAGIC):
        raise NpzError("not an .npy file")
    try:
        return np.load(path, allow_pickle=False)
    except Exception as exc:  # numpy format errors of any kind mean "bad file"
        raise _refuse(exc, ".npy file") from None
