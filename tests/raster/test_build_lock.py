"""The C++ rasterizer's build lock: a build killed mid-compile must not make every later first use
wait forever (torch's own ``lock`` file is only removed by the builder that made it)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from m4dgs.raster import cpu_backend as cb

pytestmark = pytest.mark.skipif(cb.fcntl is None, reason="flock is POSIX-only")

ROOT = Path(__file__).resolve().parents[2]


def test_stale_torch_lock_is_removed(tmp_path, capsys):
    (tmp_path / "lock").write_text("")  # what a builder killed mid-compile leaves behind
    with cb.build_lock(tmp_path, "waiting"):
        assert not (tmp_path / "lock").exists()
    err = capsys.readouterr().err
    assert "interrupted" in err and "waiting" not in err


def test_no_lock_no_message(tmp_path, capsys):
    with cb.build_lock(tmp_path / "new", "waiting"):
        pass
    assert capsys.readouterr().err == ""


# a live builder in another process: holds the flock, has torch's lock file, builds for a while
_HOLDER = """
import sys, time
from pathlib import Path
from m4dgs.raster import cpu_backend as cb
d = Path(sys.argv[1])
with cb.build_lock(d):
    (d / "lock").write_text("")
    print("held", flush=True)
    time.sleep(1.5)
    print("intact" if (d / "lock").exists() else "removed", flush=True)
    (d / "lock").unlink()
"""


def test_a_live_build_is_waited_for_not_broken(tmp_path, capsys):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(tmp_path)], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        assert p.stdout.readline().strip() == "held"
        t0 = time.perf_counter()
        with cb.build_lock(tmp_path, "waiting for the other build"):
            waited = time.perf_counter() - t0
            assert not (tmp_path / "lock").exists()  # the builder removed its own
        # the other builder kept its lock file to the end: we waited instead of deleting it
        assert p.stdout.readline().strip() == "intact"
    finally:
        p.wait(timeout=30)
    assert waited >= 1.0
    assert "waiting for the other build" in capsys.readouterr().err


@pytest.mark.skipif(not cb.cpu_available(), reason="needs the C++ rasterizer build")
def test_extension_loads_past_a_stale_lock(tmp_path):
    """End to end: a copy of this checkout's built extension folder with a stale ``lock`` in it
    loads in a fresh process (without the fix this process waits forever: the timeout)."""
    suffix, _ = cb._isa_flags()
    name = cb.build_folder_name(suffix)
    src = cb.extension_dir() / name
    base = tmp_path / "ext"
    dst = base / cb.extension_dir().name / name
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("lock", "m4dgs.flock"))
    (dst / "lock").write_text("")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "M4DGS_EXT_DIR": str(base)}
    code = "from m4dgs.raster import cpu_backend as cb; print(cb.cpu_available())"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    assert out.stdout.strip() == "True", out.stderr
    assert "interrupted" in out.stderr
    assert not (dst / "lock").exists()
