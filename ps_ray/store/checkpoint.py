"""A training checkpoint is ps_ray's own, non-executable state, sealed by a manifest.

Files of a checkpoint folder (docs/state.md):
  learner.safetensors  the five SAC nets, log alpha, every Adam slot and torch's generator state
  replay.json          the replay buffer's state and the segment files that hold its episodes,
                       outside the folder (:mod:`ps_ray.store.replay`); a checkpoint written
                       without a segment store, or by ps_ray before them, has replay.npz instead
  ps_ray_state.json    counters (env steps, episodes, updates) and the training iteration
  policy.safetensors   the policy file with its signature (what stitching and the zoo read)
  signature.json, spec.json, progress.json
  manifest.json        written last: the SHA-256 of every other file

Nothing in a checkpoint is unpickled, whoever wrote it: safetensors, ``.npz`` without pickle and
JSON cannot run code. The manifest tells a complete checkpoint from one cut short by a kill (Tune
copies a trial's checkpoint into its folder file by file) or changed afterwards; any ``.pkl``
planted beside the listed files is never opened.
"""

from __future__ import annotations

import json
from pathlib import Path

from ps_ray.errors import UserError
from ps_ray.store import replay
from ps_ray.store.atomic import file_sha256, fsync_file, write_text
from ps_ray.store.formats import CHECKPOINT
from ps_ray.store.run_layout import POLICY_FILE

MANIFEST = "manifest.json"
FORMAT = CHECKPOINT.id
STATE_FILE = "ps_ray_state.json"
PROGRESS_FILE = "progress.json"  # the stopping rule's state: streak, best, consolidated (a population: more)
POLICY_ONLY = (STATE_FILE, POLICY_FILE)  # what a reader of the policy alone must hash


class CheckpointError(UserError):
    """A checkpoint folder that is incomplete, altered, foreign or from an older ps_ray."""


def seal(directory: str | Path) -> None:
    """Write the manifest over every file in ``directory`` (call it after the last file). Each
    file is flushed to disk first, so a sealed checkpoint survives a power loss, not only a kill."""
    directory = Path(directory)
    files = {}
    for p in sorted(directory.iterdir()):
        if p.is_file() and p.name != MANIFEST:
            fsync_file(p)
            files[p.name] = {"sha256": file_sha256(p), "bytes": p.stat().st_size}
    write_text(directory / MANIFEST, json.dumps({"format": FORMAT, "files": files}, indent=1))


def verify(
    directory: str | Path, hashed: tuple[str, ...] | None = None, replay_store: Path | None = None
) -> Path:
    """``directory`` if every file its manifest lists is there with its size, and the files in
    ``hashed`` (default: all) match their hashes; else CheckpointError naming the folder and the
    first problem. A reader hashes what it loads: the zoo only needs the policy file. With a
    ``replay_store``, the replay segments the checkpoint names are checked too (hashed when
    ``hashed`` is the default)."""
    directory = Path(directory)

    def bad(why: str) -> CheckpointError:
        return CheckpointError(f"{directory}: not a usable ps_ray checkpoint ({why})")

    try:
        manifest = json.loads((directory / MANIFEST).read_text())
    except FileNotFoundError:
        raise bad(f"no {MANIFEST}: cut short, or written by another program or an older ps_ray") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise bad(f"unreadable {MANIFEST}: {e}") from None
    if not isinstance(manifest, dict) or not CHECKPOINT.reads(manifest.get("format")):
        raise bad(f"{MANIFEST} is not of format {FORMAT!r}")
    files = manifest.get("files")
    if not isinstance(files, dict) or STATE_FILE not in files:
        raise bad(f"{MANIFEST} lists no {STATE_FILE}")
    for name, entry in files.items():
        path = directory / name
        if Path(name).name != name or not isinstance(entry, dict) or not path.is_file():
            raise bad(f"{name} is missing")
        if path.stat().st_size != entry.get("bytes"):
            raise bad(f"{name} has {path.stat().st_size} bytes, the manifest says {entry.get('bytes')}")
    for name in files if hashed is None else hashed:
        if name not in files:
            raise bad(f"{MANIFEST} lists no {name}")
        if file_sha256(directory / name) != files[name].get("sha256"):
            raise bad(f"{name} does not match its hash")
    if replay_store is not None and replay.MANIFEST_FILE in files:
        try:
            replay.check(directory, Path(replay_store), hashed=hashed is None)
        except replay.ReplayStoreError as e:
            raise bad(str(e).removeprefix(f"{directory}: ")) from None
    return directory


def version(directory: str | Path) -> int:
    """The format version of a verified checkpoint (its readers' upgrades ask it)."""
    manifest = json.loads((Path(directory) / MANIFEST).read_text())
    return CHECKPOINT.version_of(manifest["format"])


def progress(directory: str | Path) -> dict:
    """The stopping rule's state in a verified checkpoint, as version 2 holds it: a version-1
    checkpoint may have been written before the file, or the best evaluation or the consolidation
    in it, was kept (none yet); a version-2 checkpoint without it is refused in one line."""
    path = Path(directory) / PROGRESS_FILE
    if version(directory) == 1:
        kept = json.loads(path.read_text()) if path.is_file() else {}
        return {"streak": 0, "best": None, "consolidated": {}, **kept}
    if not path.is_file():
        raise CheckpointError(f"{directory}: not a usable ps_ray checkpoint (no {PROGRESS_FILE})")
    return json.loads(path.read_text())


def env_steps(directory: str | Path) -> int:
    """Env steps of a verified checkpoint (for choosing the furthest of several)."""
    return int(json.loads((Path(directory) / STATE_FILE).read_text())["counters"]["env_steps"])


def latest(
    folders: list[Path], hashed: tuple[str, ...] | None = None, replay_store: Path | None = None
) -> Path | None:
    """The verified checkpoint with the most env steps among ``folders`` (``hashed`` and
    ``replay_store`` as in :func:`verify`); unusable ones are skipped: a checkpoint cut short by a
    kill is expected, and an earlier one is used."""
    usable = []
    for folder in folders:
        try:
            usable.append((env_steps(verify(folder, hashed, replay_store)), folder))
        except (CheckpointError, KeyError, TypeError, ValueError):
            continue
    return max(usable)[1] if usable else None
