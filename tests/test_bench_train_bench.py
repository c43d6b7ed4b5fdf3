"""bench/train_bench.py's configuration overrides and share folder: a second configuration of the
same clip takes the phases its changed field does not reach from the share, computes the rest, and
trains with the override."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def _bench(clip, out, share, *extra):
    cmd = [sys.executable, str(ROOT / "bench" / "train_bench.py"), str(clip), "--preset", "tiny"]
    cmd += ["--iters1", "3", "--iters2", "3", "--profile-steps", "0", "--no-score"]
    cmd += ["--threads", "1", "--share", str(share), "--out", str(out), *extra]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)


def _lambda_flat(run):
    return yaml.safe_load((run / "config.yaml").read_text())["stage2"]["loss"]["lambda_flat"]


def test_set_and_share(tiny_clip_realistic, tmp_path):
    share = tmp_path / "share"
    first = _bench(tiny_clip_realistic, tmp_path / "a", share)
    assert first.returncode == 0, first.stderr[-2000:]
    assert {p.name for p in share.iterdir()} == {"camera_init", "stage1", "v2w", "stage2"}
    # a stage-2 field: the three phases before stage 2 come from the share, stage 2 is computed
    second = _bench(
        tiny_clip_realistic, tmp_path / "b", share, "--set", "stage2.loss.lambda_flat=0.25"
    )
    assert second.returncode == 0, second.stderr[-2000:]
    status = json.loads((tmp_path / "b" / "status.json").read_text())
    assert status["stage"] == "done"
    assert set(status["shared_phases"]) == {"camera_init", "stage1", "v2w"}
    assert _lambda_flat(tmp_path / "b") == 0.25 and _lambda_flat(tmp_path / "a") == 0.0
    # a malformed override is refused before any work, naming the option
    bad = _bench(tiny_clip_realistic, tmp_path / "c", share, "--set", "stage2.loss.lambda_flat")
    assert bad.returncode == 2 and "--set" in bad.stderr
    assert not (tmp_path / "c").exists()
