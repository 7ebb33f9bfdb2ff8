"""The anchor-set file: an ``.npz`` of float32 anchors and a JSON ``meta`` (format tag, hash,
provenance), read without pickle and verified against its hash; and anchor sets made from any
file of task states (:func:`anchors_from_file`)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ps_ray.data.anchors import AnchorSet, _as_states, anchor_hash, select_anchors, selection_provenance
from ps_ray.errors import UserError
from ps_ray.store.atomic import atomic_file, file_sha256
from ps_ray.store.formats import ANCHOR_SET, id_in
from ps_ray.store.npz import NPY_MAGIC, ZIP_MAGIC, NpzError, magic, read_npy, read_npz

FORMAT = ANCHOR_SET.id
_ANCHOR_KEY, _META_KEY = "anchors", "meta"


def save_anchor_set(path: str | os.PathLike, anchor_set: AnchorSet) -> None:
    """Write ``anchor_set`` to ``path`` (exactly that name) as an ``.npz`` without pickle.

    Members: ``anchors`` (float32) and ``meta`` (a 0-d unicode array holding JSON with the
    format tag, hash and provenance). The file is written to a temporary file in the same
    directory and renamed over ``path``, so a crash never leaves a half-written file there.
    """
    path = Path(path)
    meta = json.dumps(
        {
            "format": FORMAT,
            "hash": anchor_set.hash,
            "provenance": anchor_set.provenance,
        },
        sort_keys=True,
        allow_nan=False,
    )
    with atomic_file(path) as fh:
        np.savez(
            fh, **{_ANCHOR_KEY: np.ascontiguousarray(anchor_set.anchors, "<f4"), _META_KEY: np.array(meta)}
        )


def _parse_anchor_npz(members: dict[str, np.ndarray]) -> AnchorSet:
    missing = sorted({_ANCHOR_KEY, _META_KEY} - set(members))
    extra = sorted(set(members) - {_ANCHOR_KEY, _META_KEY})
    if missing:
        raise NpzError(f"not an anchor-set file: missing member(s) {missing}, found {sorted(members)}")
    if extra:
        raise NpzError(f"not an anchor-set file: unexpected member(s) {extra}")
    raw_meta = members[_META_KEY]
    if raw_meta.dtype.kind != "U" or raw_meta.ndim != 0:
        raise NpzError(f"'meta' must be a 0-d unicode string, got {raw_meta.dtype} {raw_meta.shape}")
    try:
        meta = json.loads(str(raw_meta[()]))
    except json.JSONDecodeError as exc:
        raise NpzError(f"'meta' is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise NpzError(f"'meta' does not describe a {FORMAT} file")
    found = id_in(meta)
    if ANCHOR_SET.version_of(found) is None:
        raise NpzError(f"'meta' does not describe a {FORMAT} file")
    if not ANCHOR_SET.reads(found):
        raise NpzError(f"unsupported anchor set format {found!r} (this code reads {FORMAT})")
    stored_hash, provenance = meta.get("hash"), meta.get("provenance")
    if not isinstance(stored_hash, str) or not isinstance(provenance, dict):
        raise NpzError("'meta' lacks a string 'hash' or a dict 'provenance'")
    anchors = members[_ANCHOR_KEY]
    if anchors.dtype != np.float32 or anchors.ndim != 2 or 0 in anchors.shape:
        raise NpzError(
            f"'anchors' must be a non-empty 2-D float32 array, got {anchors.dtype} {anchors.shape}"
        )
    if not np.all(np.isfinite(anchors)):
        raise NpzError("'anchors' contains NaN or infinite values")
    actual = anchor_hash(anchors)
    if actual != stored_hash:
        raise NpzError(
            f"hash mismatch: stored {stored_hash[:16]}..., anchors hash to "
            f"{actual[:16]}... (the file was modified)"
        )
    return AnchorSet(anchors, stored_hash, provenance)


def load_anchor_set(path: str | os.PathLike) -> AnchorSet:
    """Load and verify an anchor set written by :func:`save_anchor_set`.

    Never unpickles. Any corrupt, foreign or tampered file raises a one-line ``ValueError``
    that names the file; a missing file raises ``FileNotFoundError``.
    """
    path = Path(path)
    try:
        head = magic(path)
        if head.startswith(NPY_MAGIC):
            raise NpzError(
                "it is a plain .npy array, not an anchor-set .npz "
                "(use anchors_from_file to select anchors from task states)"
            )
        if not head.startswith(ZIP_MAGIC):
            raise NpzError("not an .npz archive")
        return _parse_anchor_npz(read_npz(path))
    except NpzError as exc:
        raise UserError(f"{path}: {exc}") from None


def anchors_from_file(
    path: str | os.PathLike, k: int, *, seed: int = 0, n_init: int = 10, distinct: bool = True
) -> AnchorSet:
    """An anchor set from "any file of task states".

    - an anchor-set ``.npz`` (:func:`save_anchor_set`): loaded and verified; it must have
      exactly ``k`` rows;
    - a plain ``.npy`` array, or an ``.npz`` with a single array (or a member named
      ``states`` / ``task_states``), of shape ``(N, dim)`` with ``N >= k``: ``k`` anchors are
      selected with :func:`select_anchors`; the provenance names the file and its sha256.

    Never unpickles; bad files raise a one-line ``ValueError`` naming the file.
    """
    path = Path(path)
    try:
        head = magic(path)
        if head.startswith(NPY_MAGIC):
            states, member = read_npy(path), None
        elif head.startswith(ZIP_MAGIC):
            members = read_npz(path)
            if _META_KEY in members:
                anchor_set = _parse_anchor_npz(members)
                if anchor_set.k != k:
                    raise NpzError(f"anchor set has {anchor_set.k} anchors, {k} requested")
                return anchor_set
            for key in ("task_states", "states"):
                if key in members:
                    member = key
                    break
            else:
                if len(members) != 1:
                    raise NpzError(
                        f"expected one array (or a 'states' member) in the .npz, found {sorted(members)}"
                    )
                member = next(iter(members))
            states = members[member]
        else:
            raise NpzError("neither an .npy nor an .npz file")
        try:
            x = _as_states(states)
        except ValueError as exc:
            raise NpzError(str(exc)) from None
        if x.shape[0] < k:
            raise NpzError(f"{x.shape[0]} task states, fewer than the {k} anchors requested")
        try:
            anchors = select_anchors(x, k, seed=seed, n_init=n_init, distinct=distinct)
        except ValueError as exc:
            raise NpzError(str(exc)) from None
    except NpzError as exc:
        raise UserError(f"{path}: {exc}") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    provenance = selection_provenance(
        x, k, seed, n_init, distinct, source_file=str(path), source_sha256=file_sha256(path)
    )
    if member is not None:
        provenance["source_member"] = member
    return AnchorSet.of(anchors, provenance)
