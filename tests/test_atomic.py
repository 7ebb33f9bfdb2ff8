"""The one atomic write: old or new file, never half of one; no temp files left; readable by
others sharing the storage as a plain write would be."""

from __future__ import annotations

import os

import pytest

from ps_ray.store.atomic import atomic_file, write_text


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temp_file(tmp_path):
    path = write_text(tmp_path / "result.json", "old")
    with pytest.raises(RuntimeError), atomic_file(path) as f:
        f.write(b"half of the new")
        raise RuntimeError("killed mid-write")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]


def test_the_written_file_has_the_mode_a_plain_write_gives(tmp_path):
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    atomic = write_text(tmp_path / "atomic.txt", "x")
    assert os.stat(atomic).st_mode & 0o777 == os.stat(plain).st_mode & 0o777


def test_a_policy_file_and_a_report_file_get_that_mode_though_safetensors_writes_0600(tmp_path):
    """safetensors makes its file private; a policy file (``ps-ray stitch --save``, every
    checkpoint) and the report's interfaces.safetensors must still be readable as a plain write is."""
    import numpy as np
    from safetensors.numpy import save_file

    from ps_ray.store.atomic import atomic_path

    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    with atomic_path(tmp_path / "policy.safetensors") as partial:
        save_file({"w": np.zeros(3, np.float32)}, str(partial))
    assert os.stat(tmp_path / "policy.safetensors").st_mode & 0o777 == os.stat(plain).st_mode & 0o777
