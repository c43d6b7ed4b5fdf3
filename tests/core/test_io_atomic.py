"""m4dgs.core.io's one atomic-write mechanism (`atomic_target`) and the writers built on it."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from m4dgs.core import io as mio


def _names(folder):
    return sorted(p.name for p in folder.iterdir())


def test_write_bytes_atomic_writes_and_leaves_no_temp_file(tmp_path):
    p = tmp_path / "sub" / "a.bin"  # the parent folder is created
    mio.write_bytes_atomic(p, b"hello")
    assert p.read_bytes() == b"hello"
    assert _names(p.parent) == ["a.bin"]
    mio.write_text_atomic(p, "again")  # overwrite in place
    assert p.read_text() == "again" and _names(p.parent) == ["a.bin"]


def test_atomic_target_failure_keeps_the_old_file_and_removes_the_temp(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    with pytest.raises(RuntimeError):
        with mio.atomic_target(p, ".txt") as tmp:
            assert tmp.parent == tmp_path and tmp.name.endswith(".txt") and tmp != p
            tmp.write_text("half")  # a partial write, then the writer fails
            raise RuntimeError("writer died")
    assert p.read_text() == "old"  # never a partial file under the final name
    assert _names(tmp_path) == ["a.txt"]  # and no temporary left behind


def test_atomic_target_failure_without_old_file_leaves_nothing(tmp_path):
    p = tmp_path / "new.json"
    with pytest.raises(KeyboardInterrupt):
        with mio.atomic_target(p) as tmp:
            tmp.write_bytes(b"{")
            raise KeyboardInterrupt
    assert _names(tmp_path) == []


def test_atomic_files_get_normal_permissions(tmp_path):
    """mkstemp creates 0600 files; the published file follows the umask like open() would."""
    mask = os.umask(0o022)
    try:
        with mio.atomic_target(tmp_path / "x.ply", ".ply") as tmp:
            tmp.write_bytes(b"ply")
        mio.write_json(tmp_path / "y.json", {})
    finally:
        os.umask(mask)
    for name in ("x.ply", "y.json"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644


def test_every_writer_leaves_only_its_file(tmp_path):
    mio.write_json(tmp_path / "a.json", {"x": 1})
    mio.write_png(tmp_path / "b.png", np.zeros((2, 2, 3), np.uint8))
    mio.write_npz(tmp_path / "c.npz", a=np.arange(3))
    mio.write_exr(tmp_path / "d.exr", np.ones((2, 3), np.float32))
    assert _names(tmp_path) == ["a.json", "b.png", "c.npz", "d.exr"]
    assert mio.read_json(tmp_path / "a.json") == {"x": 1}
    np.testing.assert_array_equal(mio.read_npz(tmp_path / "c.npz")["a"], np.arange(3))
    np.testing.assert_array_equal(mio.read_exr(tmp_path / "d.exr"), np.ones((2, 3), np.float32))
