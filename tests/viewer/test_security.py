"""The viewer is private by default: it listens on the loopback address only (read back from the
kernel's socket table, not from the server), a wider --host prints a warning, and the HTTP side
serves viser's client page and nothing from the file system."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")


def _listening(port: int):
    """Local addresses (hex, as /proc/net/tcp{,6} write them) of sockets listening on port."""
    out = []
    for name in ("/proc/net/tcp", "/proc/net/tcp6"):
        if not Path(name).exists():
            continue
        for line in Path(name).read_text().splitlines()[1:]:
            f = line.split()
            addr, hport = f[1].rsplit(":", 1)
            if int(hport, 16) == port and f[3] == "0A":  # 0A = TCP_LISTEN
                out.append(addr)
    return out


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net/tcp")
def test_binds_loopback_by_default_and_serves_only_the_client(viewer_model, free_port):
    from m4dgs.viewer.server import Viewer

    v = Viewer(viewer_model, port=free_port, show_cameras=False)
    try:
        assert v.port == free_port
        addrs = _listening(free_port)
        # 0100007F = 127.0.0.1 (little-endian hex); never 00000000 (0.0.0.0) or :: (all zeros)
        assert addrs and all(a == "0100007F" for a in addrs), addrs
        base = f"http://127.0.0.1:{free_port}"
        with urllib.request.urlopen(base + "/", timeout=10) as r:
            assert r.status == 200 and b"<html" in r.read().lower()
        for path in ("/../../../../etc/passwd", "/%2e%2e/%2e%2e/%2e%2e/etc/passwd", "/etc/passwd"):
            try:
                with urllib.request.urlopen(base + path, timeout=10) as r:
                    assert b"root:" not in r.read(), path
            except urllib.error.HTTPError as e:
                assert e.code in (400, 403, 404), (path, e.code)
    finally:
        v.stop()


def test_wider_host_prints_the_warning(viewer_run, free_port):
    """`m4dgs view RUN --host 0.0.0.0` warns before serving (read from its stderr)."""
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    cmd = [sys.executable, "-m", "m4dgs", "view", str(viewer_run), "--host", "0.0.0.0"]
    p = subprocess.Popen(
        cmd + ["--port", str(free_port), "--device", "cpu"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
    )
    try:
        line = p.stderr.readline()
        assert "warning" in line and "0.0.0.0" in line and "anyone" in line, line
        # and it does listen everywhere, as asked
        deadline = time.time() + 120
        while not _listening(free_port) and time.time() < deadline and p.poll() is None:
            time.sleep(0.2)
        assert "00000000" in _listening(free_port)
    finally:
        p.terminate()
        p.wait(timeout=30)


def test_default_host_prints_no_warning():
    from m4dgs.viewer.web import exposure_warning

    assert exposure_warning("127.0.0.1") is None and exposure_warning("::1") is None
    assert "anyone" in exposure_warning("0.0.0.0")


def test_bad_target_names_the_missing_file(tmp_path):
    from click.testing import CliRunner

    from m4dgs.cli import main

    r = CliRunner().invoke(main, ["view", str(tmp_path)])
    assert r.exit_code != 0
    assert str(tmp_path / "model" / "final.pt") in r.output and "clip.json" in r.output
