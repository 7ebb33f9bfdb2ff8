"""One writer at a time: a second driver on a sweep or run folder is refused in one line."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from ps_ray.store.lock import LOCK_FILE, FolderLocked, folder_lock

SWEEP = """name: locked
methods: [ps]
robots: [panda]
tasks: [reach]
seeds: [1]
"""


def test_a_held_folder_refuses_a_second_holder_and_names_the_first(tmp_path):
    with folder_lock(tmp_path / "sweep", "sweep"):
        with pytest.raises(FolderLocked, match=rf"this sweep is being written by PID {os.getpid()} on "):
            with folder_lock(tmp_path / "sweep", "sweep"):
                pass
    with folder_lock(tmp_path / "sweep", "sweep"):  # released on exit: taken again
        pass


@pytest.mark.e2e
def test_a_lock_left_by_a_killed_process_is_taken_over(tmp_path):
    folder = tmp_path / "sweep"
    code = (
        f"from ps_ray.store.lock import folder_lock\nimport os\n"
        f"with folder_lock({str(folder)!r}):\n    os._exit(9)\n"
    )  # dies holding it
    assert subprocess.run([sys.executable, "-c", code]).returncode == 9
    assert (folder / LOCK_FILE).exists()
    with folder_lock(folder):
        pass


@pytest.mark.e2e
@pytest.mark.parametrize("command", [["run"], ["sweep"], ["report"], ["zero-shot"], ["few-shot"]])
def test_every_sweep_command_is_refused_while_another_driver_holds_the_sweep(tmp_path, command):
    spec = tmp_path / "locked.yaml"
    spec.write_text(SWEEP)
    storage = tmp_path / "store"
    with folder_lock(storage / "locked", "sweep"):
        done = subprocess.run(
            [sys.executable, "-m", "ps_ray.cli", *command, str(spec), "--storage", str(storage)],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert done.returncode == 2, done.stderr[-2000:]
    assert (
        done.stderr.strip()
        .splitlines()[-1]
        .startswith(f"ps-ray {command[0]}: error: {storage / 'locked'}: this sweep is being written by PID")
    )
    assert sorted(p.name for p in (storage / "locked").iterdir()) == [LOCK_FILE]  # nothing else written
