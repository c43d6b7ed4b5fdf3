"""A Ray cluster of three processes on this machine for the executor tests (tests/eval/
test_executors.py, tests/benchgen/test_benchgen_executors.py), and what the tests check about its
processes from /proc: the test's descendants, their command lines (Ray titles a worker
`ray::<task name>` while it runs a task) and the TCP ports they listen on.

tests/conftest.py turns start_ray_cluster into the module-scoped `ray_cluster` fixture; the test
modules import the /proc helpers from here (pytest puts tests/ on sys.path for its conftest)."""

from __future__ import annotations

import os
import shutil
import socket
import tempfile
from contextlib import contextmanager
from pathlib import Path

from m4dgs.core.executors import ray_token_auth_supported


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def descendants(pid: int) -> list:
    """PIDs of the processes below `pid` (from /proc: the test's own processes only)."""
    children = {}
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            ppid = int((p / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(p.name))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def listening(pids) -> set:
    """(address, port) of the TCP sockets the processes `pids` listen on (/proc/net/tcp[6])."""
    inodes = set()
    for pid in pids:
        try:
            for fd in Path(f"/proc/{pid}/fd").iterdir():
                link = os.readlink(fd)
                if link.startswith("socket:["):
                    inodes.add(link[8:-1])
        except OSError:
            continue
    out = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # 0A: LISTEN
                addr, port = f[1].split(":")
                raw = bytes.fromhex(addr)
                if len(raw) == 4:
                    ip = ".".join(str(b) for b in raw[::-1])
                else:  # four little-endian 32-bit words
                    words = [raw[i : i + 4][::-1] for i in range(0, 16, 4)]
                    ip = socket.inet_ntop(socket.AF_INET6, b"".join(words))
                out.add((ip, int(port, 16)))
    return out


def loopback(ip: str) -> bool:
    return ip in ("127.0.0.1", "::1", "::ffff:127.0.0.1")


@contextmanager
def start_ray_cluster():
    """The address of a Ray cluster of three processes on this machine, started here: a head and
    two worker nodes, one CPU and an 80 MB object store each, no dashboard, bound to 127.0.0.1,
    token authentication where this Ray has it, no usage reports, everything under a temp dir
    removed at the end."""
    import ray
    import ray._private.ray_constants as ray_constants
    from ray.cluster_utils import Cluster

    from m4dgs.core.executors import _reload_ray_auth

    tmp = tempfile.mkdtemp(prefix="m4rt-")  # short: Ray's socket paths live under it
    os.makedirs(os.path.join(tmp, "ray"))  # Ray writes the cluster's address there
    # one machine: 127.0.0.1 stays 127.0.0.1 (Ray otherwise swaps it for the machine's address)
    env = {
        "RAY_TMPDIR": tmp,
        "RAY_USAGE_STATS_ENABLED": "0",
        "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
    }
    if ray_token_auth_supported(ray.__version__):
        env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN="m4dgs-test-" + "0" * 40)
    before = {k: os.environ.get(k) for k in env}
    one_machine = ray_constants.ENABLE_RAY_CLUSTER
    os.environ.update(env)
    ray_constants.ENABLE_RAY_CLUSTER = False
    _reload_ray_auth()
    node = dict(
        num_cpus=1,
        object_store_memory=80 * 1024 * 1024,
        include_dashboard=False,
        node_ip_address="127.0.0.1",
        temp_dir=tmp,
    )
    cluster = Cluster(shutdown_at_exit=False)
    try:
        port = free_port()
        cluster.add_node(**node, gcs_server_port=port, include_log_monitor=False)
        for _ in range(2):
            cluster.add_node(**node)
        yield f"127.0.0.1:{port}"
    finally:
        cluster.shutdown()
        ray_constants.ENABLE_RAY_CLUSTER = one_machine
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        _reload_ray_auth()
        shutil.rmtree(tmp, ignore_errors=True)
