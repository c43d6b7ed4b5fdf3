"""The folder lock (m4dgs.core.lock) with real processes: a live owner refuses a second writer, a
dead owner's lock is broken, a reused PID does not keep a lock alive, nested use is a no-op."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time

import pytest

from m4dgs.core.errors import M4DGSError, RunInUseError
from m4dgs.core.lock import LOCK_NAME, FolderLock

HOLD = """
import sys, time
from m4dgs.core.lock import FolderLock
with FolderLock(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(float(sys.argv[2]))
"""


def _holder(folder, seconds):
    p = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(folder), str(seconds)], stdout=subprocess.PIPE, text=True
    )
    assert p.stdout.readline().strip() == "locked"
    return p


def test_second_writer_refused_with_owner_pid(tmp_path):
    p = _holder(tmp_path, 30)
    try:
        with pytest.raises(RunInUseError) as e:
            FolderLock(tmp_path).acquire()
        assert str(p.pid) in str(e.value) and str(tmp_path) in str(e.value)
        assert isinstance(e.value, M4DGSError)
    finally:
        p.kill()
        p.wait()


def test_dead_owner_lock_is_broken(tmp_path):
    p = _holder(tmp_path, 30)
    p.kill()  # killed: its lock file stays behind
    p.wait()
    assert (tmp_path / LOCK_NAME).exists()
    with FolderLock(tmp_path) as lk:
        assert lk.owned and json.loads((tmp_path / LOCK_NAME).read_text())["pid"] == os.getpid()
    assert not (tmp_path / LOCK_NAME).exists()


def test_reused_pid_with_other_start_time_is_stale(tmp_path):
    # a record naming a live process (our parent) with another start time: the PID was reused
    rec = {"pid": os.getppid(), "host": socket.gethostname(), "start": "1", "since": "x"}
    (tmp_path / LOCK_NAME).write_text(json.dumps(rec))
    with FolderLock(tmp_path) as lk:
        assert lk.owned


def test_nested_use_in_one_process_and_release(tmp_path):
    outer = FolderLock(tmp_path).acquire()
    inner = FolderLock(tmp_path).acquire()  # e.g. the renderer called by the trainer
    assert outer.owned and not inner.owned
    inner.release()
    assert (tmp_path / LOCK_NAME).exists()  # still held by the outer one
    outer.release()
    assert not (tmp_path / LOCK_NAME).exists()


def test_foreign_host_lock_names_the_file_to_delete(tmp_path):
    rec = {"pid": 1, "host": "some-other-host", "since": "2026-01-01T00:00:00", "command": "m4dgs"}
    (tmp_path / LOCK_NAME).write_text(json.dumps(rec))
    with pytest.raises(RunInUseError, match="some-other-host.*delete"):
        FolderLock(tmp_path).acquire()


def test_lock_released_on_exception(tmp_path):
    with pytest.raises(ValueError):
        with FolderLock(tmp_path):
            raise ValueError("boom")
    assert not (tmp_path / LOCK_NAME).exists()
    t0 = time.perf_counter()
    with FolderLock(tmp_path):
        pass
    assert time.perf_counter() - t0 < 1.0
