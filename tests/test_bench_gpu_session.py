"""bench/gpu_session.sh, the one command of a lent GPU session, run here with stand-ins for
python3, nvidia-smi, nvcc and pkill on PATH: which slots run with which arguments, which are
skipped, what comes back under $OUT, and that a gsplat that does not build stops the script. A
mistake in this script costs minutes of a session's 15 minutes of device time."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# python3: the calls are logged; pip does nothing, gpu_check.py writes a gpu_check.json into its
# --out (env with or without the gsplat build, as GSPLAT_BUILDS says), `-m m4dgs train` writes a
# finished status.json into its --out, `-c` runs the real interpreter
FAKE_PYTHON = r"""#!/usr/bin/env bash
echo "python3 $*" >> "$LOG"
out=""
prev=""
for a in "$@"; do
  if [ "$prev" = "--out" ]; then out="$a"; fi
  prev="$a"
done
case "$1" in
  -c) exec "$REAL_PYTHON" "$@" ;;
  -m)
    if [ "$2" = "m4dgs" ]; then
      mkdir -p "$out"
      echo '{"stage": "done"}' > "$out/status.json"
      echo '{"step": 1}' > "$out/log.jsonl"
    fi
    exit 0 ;;
  bench/gpu_check.py)
    mkdir -p "$out"
    env='{"gsplat": "import failed"}'
    if [ "$GSPLAT_BUILDS" = 1 ]; then env='{"gsplat_first_render_s": 60.0}'; fi
    echo "{\"steps\": {\"env\": $env}}" > "$out/gpu_check.json"
    exit 0 ;;
esac
exit 0
"""


def _session(tmp_path, gsplat_builds=True, **env_over):
    """Run the script in a copy of the kit layout; returns (rc, output, python3 calls, OUT)."""
    work = tmp_path / "repo"
    (work / ".gpu" / "whl").mkdir(parents=True)
    (work / ".gpu" / "whl" / "x-1.0-py3-none-any.whl").write_bytes(b"")
    (work / ".gpu" / "clip" / "lamp-room-orbit").mkdir(parents=True)
    (work / "bench").mkdir()
    shutil.copy(ROOT / "bench" / "gpu_session.sh", work / "bench" / "gpu_session.sh")
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "python3").write_text(FAKE_PYTHON)
    for name, body in (
        ("nvidia-smi", "echo GPU 0: fake"),
        ("nvcc", "echo Build fake"),
        ("pkill", ""),
    ):
        (fake / name).write_text(f"#!/usr/bin/env bash\n{body}\nexit 0\n")
    for f in fake.iterdir():
        f.chmod(0o755)
    log, out, run = tmp_path / "calls.log", tmp_path / "out", tmp_path / "gpu_run"
    env = dict(
        os.environ,
        PATH=f"{fake}{os.pathsep}{os.environ['PATH']}",
        LOG=str(log),
        REAL_PYTHON=sys.executable,
        GSPLAT_BUILDS="1" if gsplat_builds else "0",
        OUT=str(out),
        GPU_RUN=str(run),
        **env_over,
    )
    p = subprocess.run(
        ["bash", "bench/gpu_session.sh"], cwd=work, env=env, capture_output=True, text=True
    )
    calls = log.read_text().splitlines() if log.exists() else []
    return p.returncode, p.stdout + p.stderr, calls, out


def _checks(calls):
    return [c for c in calls if c.startswith("python3 bench/gpu_check.py")]


def test_default_slots_their_arguments_and_what_comes_back(tmp_path):
    rc, text, calls, out = _session(tmp_path)
    assert rc == 0, text
    run = tmp_path / "gpu_run"
    # the wheels go to GPU_RUN/site, the slots' scratch folders under GPU_RUN
    assert any(
        c.startswith("python3 -m pip install") and f"--target {run}/site" in c for c in calls
    )
    a, b, c = _checks(calls)
    assert f"--out {run}/a --steps env,tests" in a
    assert f"--out {run}/b --preset paper --iters 1000" in b
    assert "--steps train,fps,fps_scale,profile --fps-counts 50000,150000,300000" in b
    assert f"--out {run}/c --preset small --steps jobs --jobs 1,2,4 --jobs-iters 300" in c
    assert sorted(p.name for p in out.iterdir()) == ["a.json", "b.json", "c.json"]
    assert json.loads((out / "a.json").read_text())["steps"]["env"]["gsplat_first_render_s"] == 60
    assert not any("-m m4dgs train" in c for c in calls)  # no paper run without PAPER_RUN=1


def test_a_slot_given_0_seconds_is_skipped(tmp_path):
    rc, text, calls, out = _session(tmp_path, T_B="0", STEPS_A="env")
    assert rc == 0, text
    checks = _checks(calls)
    assert len(checks) == 2 and checks[0].endswith("--steps env") and "--steps jobs" in checks[1]
    assert sorted(p.name for p in out.iterdir()) == ["a.json", "c.json"]


def test_paper_run_then_its_fps_and_profile_once_finished(tmp_path):
    rc, text, calls, out = _session(tmp_path, PAPER_RUN="1", STEPS_A="env", T_B="0", T_C="0")
    assert rc == 0, text
    run = tmp_path / "gpu_run"
    train = [c for c in calls if "-m m4dgs train" in c]
    assert len(train) == 1 and "--preset paper --device cuda" in train[0]
    assert f"--out {run}/paper" in train[0]
    a, p2 = _checks(calls)
    assert f"--out {run}/p --preset paper --steps fps,profile --run {run}/paper" in p2
    assert sorted(x.name for x in out.iterdir()) == ["a.json", "paper.json", "paper.txt"]
    assert (out / "paper.txt").read_text().startswith("rc 0\n")
    assert "slot P2" in text


def test_a_gsplat_that_does_not_build_stops_after_slot_a(tmp_path):
    rc, text, calls, out = _session(tmp_path, gsplat_builds=False, PAPER_RUN="1")
    assert rc == 4 and "gsplat did not build" in text
    assert len(_checks(calls)) == 1 and not any("-m m4dgs train" in c for c in calls)
    assert sorted(p.name for p in out.iterdir()) == ["a.json"]
