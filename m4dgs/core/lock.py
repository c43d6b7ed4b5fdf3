"""A folder lock: one writing process per run folder.

`FolderLock(folder)` creates `folder/.lock` exclusively (O_CREAT | O_EXCL) holding the owner's PID,
host, process start time and command line. A second process is refused with `RunInUseError`, which
names the owner. A lock whose owner is dead (same host, and the PID is gone or now belongs to a
process started at another time) is stale: it is broken and taken over. Taking the lock again
inside the process that holds it is allowed and a no-op (the trainer holds its run folder and
calls the renderer, which locks the same folder), and only the outermost holder removes it.

    with FolderLock(run_dir):
        ...  # write the run
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import time
import uuid
from pathlib import Path
from typing import Optional

from m4dgs.core.errors import RunInUseError

LOCK_NAME = ".lock"


@contextlib.contextmanager
def file_lock(path):
    """Exclusive `fcntl.flock` on the file `path` (created with its folder) for the duration of the
    block: a second process taking the same lock WAITS for the first (unlike FolderLock, which
    refuses). The kernel drops the lock when its holder dies. Needs a file system with working
    flock (local disks, most NFS v4 set-ups)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def _process_start(pid: int) -> Optional[str]:
    """The start time of process `pid` in clock ticks since boot (Linux /proc), None elsewhere or
    when there is no such process."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # the command name (field 2) may contain spaces and parentheses: split after its last ")"
    fields = stat[stat.rfind(")") + 2 :].split()
    return fields[19] if len(fields) > 19 else None


def _alive(pid: int, start: Optional[str]) -> bool:
    """Is the process that wrote a lock (pid, start time) still running on this host?"""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        pass
    now = _process_start(pid)
    if start is not None and now is not None and now != start:
        return False  # the PID was reused by a newer process
    return True


class FolderLock:
    """Exclusive, re-entrant-per-process lock of a folder (see the module docstring)."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.owned = False

    def _me(self) -> dict:
        return {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "start": _process_start(os.getpid()),
            "since": time.strftime("%Y-%m-%dT%H:%M:%S"),
            "command": " ".join(sys.argv)[:300],
        }

    def read(self) -> Optional[dict]:
        """The current owner's record, None when unlocked (or unreadable: torn write)."""
        try:
            return json.loads(self.path.read_text())
        except (OSError, ValueError):
            return None

    def acquire(self) -> "FolderLock":
        self.folder.mkdir(parents=True, exist_ok=True)
        for _ in range(20):
            # the record is written to a private file first and hard-linked into place, which
            # fails when the lock exists: a lock file is never seen empty or half-written
            tmp = self.folder / f"{LOCK_NAME}.{os.getpid()}.{uuid.uuid4().hex}"
            tmp.write_text(json.dumps(self._me()))
            try:
                os.link(tmp, self.path)
            except FileExistsError:
                owner = self.read()
                if owner is None:  # unreadable: only a foreign or damaged file can be
                    self._break()
                    continue
                if owner.get("pid") == os.getpid() and owner.get("host") == socket.gethostname():
                    return self  # held by this process already: nested use, not the owner
                if owner.get("host") == socket.gethostname() and not _alive(
                    int(owner.get("pid", -1)), owner.get("start")
                ):
                    self._break()
                    continue
                raise RunInUseError(self._in_use_message(owner)) from None
            finally:
                tmp.unlink(missing_ok=True)
            self.owned = True
            return self
        raise RunInUseError(f"{self.path}: could not take the lock (contended)")

    def _in_use_message(self, owner: dict) -> str:
        here = owner.get("host") == socket.gethostname()
        where = "" if here else f" on {owner.get('host')}"
        hint = "" if here else f" (or delete {self.path} if that process is gone)"
        return (
            f"{self.folder}: in use by process {owner.get('pid')}{where} since "
            f"{owner.get('since')} ({owner.get('command', '?')}); wait for it to finish or use "
            f"another output folder{hint}"
        )

    def _break(self) -> None:
        """Remove a stale lock; renaming first makes two breakers not delete each other's lock."""
        grave = self.path.with_name(f"{LOCK_NAME}.stale-{uuid.uuid4().hex}")
        try:
            os.replace(self.path, grave)
        except FileNotFoundError:
            return
        grave.unlink(missing_ok=True)

    def release(self) -> None:
        if not self.owned:
            return
        owner = self.read()
        if owner is not None and owner.get("pid") == os.getpid():
            self.path.unlink(missing_ok=True)
        self.owned = False

    def __enter__(self) -> "FolderLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
