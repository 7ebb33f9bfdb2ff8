"""One writer at a time per sweep or run folder.

The lock is an ``fcntl.flock`` on ``<folder>/.ps_ray.lock``, held for the life of the command.
The kernel drops it when its process dies, however it dies, so a lock left by a killed driver is
taken over by the next one without any staleness guess. The file records who holds it (host,
PID, start time) so that a refused driver can name the holder. On shared storage the lock works
where the filesystem implements flock across clients (NFSv4, EFS, Lustre with flock enabled).
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ps_ray.errors import UserError

LOCK_FILE = ".ps_ray.lock"


class FolderLocked(UserError):
    """Another live process writes this folder (a user error: one line, exit 2)."""


@contextmanager
def folder_lock(folder: str | Path, what: str = "folder") -> Iterator[None]:
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle = open(folder / LOCK_FILE, "a+")
    except OSError as e:
        raise UserError(f"{folder}: cannot write the {what} folder ({e.strerror})") from None
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            raise FolderLocked(
                f"{folder}: this {what} is being written by {_holder(handle.read())}; "
                f"wait for it to finish or stop it"
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(
            json.dumps(
                {
                    "host": socket.gethostname(),
                    "pid": os.getpid(),
                    "since": time.strftime("%Y-%m-%d %H:%M:%S"),
                }
            )
        )
        handle.flush()
        yield
    finally:
        handle.close()  # closing releases the flock


def _holder(text: str) -> str:
    try:
        info = json.loads(text)
        return f"PID {info['pid']} on {info['host']} since {info['since']}"
    except (json.JSONDecodeError, KeyError, TypeError):
        return "another process"
