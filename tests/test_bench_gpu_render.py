"""bench/gpu_render.sh, the two device calls that time Mitsuba's CUDA variant on a lent GPU, run
here on a stand-in kit: part b refuses to run without part a (a machine that went cold between
the calls), part a unpacks, and part b, with a Ray that cannot start, renders a tiny clip with the
local executor instead and writes render.json from the frames' own stats. A mistake in this
script costs minutes of a session's 15 minutes of device time."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import tarfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# a Ray whose cluster never starts: what part b must survive
FAKE_RAY = """__version__ = "0.0-stand-in"


def init(*args, **kwargs):
    raise RuntimeError("the stand-in Ray cannot start a cluster")


def is_initialized():
    return False
"""


def _tar_xz(path: Path, files: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with tarfile.open(path, "w:xz") as t:
        for name, text in files.items():
            data = text.encode()
            info = tarfile.TarInfo(name)
            info.size = len(data)
            t.addfile(info, io.BytesIO(data))


def _stage(stage: str, kit: Path, gr: Path, out: Path, **env_over):
    env = dict(
        os.environ,
        KIT=str(kit),
        GR=str(gr),
        OUT=str(out),
        PYTHON=sys.executable,
        **env_over,
    )
    env.pop("PYTHONPATH", None)
    p = subprocess.run(
        ["bash", "bench/gpu_render.sh", stage], cwd=ROOT, env=env, capture_output=True, text=True
    )
    return p.returncode, p.stdout + p.stderr


def test_two_stages_and_the_local_fallback(tmp_path):
    from benchgen.render import pick_variant

    kit, gr, out = tmp_path / "kit", tmp_path / "gr", tmp_path / "out"
    _tar_xz(kit / "ra" / "site.tar.xz", {"part_a_marker.txt": "a"})
    _tar_xz(kit / "rb" / "site.tar.xz", {"ray/__init__.py": FAKE_RAY})
    (kit / "rb" / "whl").mkdir()
    # part b on a machine without part a (it went cold between the calls): a clear stop
    rc, text = _stage("b", kit, gr, out)
    assert rc == 3 and "run stage a, then b at once" in text, text
    rc, text = _stage("a", kit, gr, out)
    assert rc == 0 and (gr / "site" / "part_a_marker.txt").exists(), text
    env = dict(SUITE="tiny", SCENE="tiny-flag-arm", PRESET="tiny", CPUS="1", T_RENDER="240")
    rc, text = _stage("b", kit, gr, out, VARIANT=pick_variant(), **env)
    assert rc == 0, text
    assert "ray 0.0-stand-in" in (out / "env.txt").read_text()  # part b's site comes first
    assert "Ray rendered nothing" in text and "--executor local --render-only" in text, text
    res = json.loads((out / "render.json").read_text())
    assert res["executor"] == "local" and res["render_rc"] == 0
    assert res["clip"] == str(gr / "bench" / "tiny" / "tiny-flag-arm")
    # tiny-flag-arm at the tiny preset: 9 frames; the views of its 4 test frames
    assert res["frames_on_disk"] == 9 and len(res["frame_render_seconds"]) == 9
    assert res["views_on_disk"] > 0 and res["views_s_per_test_frame"] > 0
    secs = sorted(res["frame_render_seconds"])
    assert res["median_s_per_frame"] == secs[4] > 0
    assert not (gr / "bench" / "tiny" / "tiny-flag-arm" / "clip.json").exists()  # render only
