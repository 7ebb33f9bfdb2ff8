"""PyBullet prints its build time on stderr when first imported: a stray line before every
output and error message of the command line. It is imported once here with stderr muted."""

from __future__ import annotations

import os
import sys


def import_pybullet() -> None:
    if "pybullet" in sys.modules:
        return
    if sys.stderr is not None:
        sys.stderr.flush()
    try:
        saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    except OSError:  # no stderr to mute (fd 2 closed)
        import pybullet  # noqa: F401

        return
    try:
        os.dup2(devnull, 2)
        import pybullet  # noqa: F401
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
