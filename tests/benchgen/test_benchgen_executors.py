"""`benchgen make --executor`: the tiny preset of tiny-flag-arm made with the local executor, on a
Ray cluster of three processes (a head and two workers, one CPU each), with a render task whose
Ray worker is killed, and half on this process then on submitit's local executor: every file of
every clip is the same bytes, except the wall-clock fields benchgen.make.WALL_CLOCK_FIELDS names
(generator.seconds and gt.timing_s_per_frame in clip.json and the resume state)."""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from ray_helpers import cmdline, descendants  # tests/ray_helpers.py

from benchgen.cli import main
from benchgen.make import UNIT_HDR_DIR, WALL_CLOCK_FIELDS
from m4dgs.clip import frame_name

SCENE = "tiny-flag-arm"
ARGS = ["make", "--suite", "tiny", "--preset", "tiny", "--scenes", SCENE, "--priors", "oracle"]
# 9 frames in tasks of 3 (0-2, 3-5, 6-8), the views of the 4 test frames in tasks of 3 (1-5, 7)
TASKS = 5


def _clip(root) -> Path:
    return Path(root) / "tiny" / SCENE


def _without_wall_clock(rel: str, data: bytes):
    """The file's bytes, or for a JSON file of WALL_CLOCK_FIELDS its content with those fields
    set to None (each must be there: a renamed field fails here instead of passing silently)."""
    fields = WALL_CLOCK_FIELDS.get(rel)
    if not fields:
        return data
    d = json.loads(data)
    for path in fields:
        node = d
        for k in path[:-1]:
            node = node[k]
        assert path[-1] in node, (rel, path)
        node[path[-1]] = None
    return d


def differing_files(a: Path, b: Path) -> list:
    """Relative paths of the files that differ between two clip folders (a file in one only
    included), wall-clock fields aside."""
    fa = {p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file()}
    fb = {p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file()}
    out = sorted(fa ^ fb)
    for rel in sorted(fa & fb):
        if _without_wall_clock(rel, (a / rel).read_bytes()) != _without_wall_clock(
            rel, (b / rel).read_bytes()
        ):
            out.append(rel)
    return out


@pytest.fixture(scope="module")
def local_clip(tmp_path_factory) -> Path:
    """The clip made as always (--executor local, the default)."""
    root = tmp_path_factory.mktemp("local")
    r = CliRunner().invoke(main, ARGS + ["--out", str(root)])
    assert r.exit_code == 0, r.output
    clip = _clip(root)
    assert (clip / "clip.json").exists() and not clip.joinpath(*UNIT_HDR_DIR).exists()
    return clip


# ------------------------------------------------------------------------------------ options
def test_help_names_every_executor_option():
    r = CliRunner().invoke(main, ["make", "--executor", "ray", "--help"])
    assert r.exit_code == 0, r.output
    for opt in (
        "--executor",
        "--cpus-per-job",
        "--address",
        "--max-retries",
        "--ray-dashboard",
        "--ray-temp-dir",
        "--slurm-folder",
        "--slurm-partition",
        "--slurm-time",
        "--slurm-array-parallelism",
        "--frames-per-task",
    ):
        assert opt in r.output, opt
    assert "--gpus-per-job" not in r.output  # the Mitsuba variant decides (BENCHGEN_MI_VARIANT)
    assert "render task" in r.output and "docs/cluster.md" in r.output


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--address", "127.0.0.1:1"], "--address applies only to --executor ray"),
        (["--cpus-per-job", "2"], "--cpus-per-job applies to --executor ray and slurm"),
        (["--frames-per-task", "2"], "--frames-per-task applies to --executor ray and slurm"),
        (["--executor", "ray", "--jobs", "2"], "--jobs 2 .* drop --jobs"),
        (["--executor", "slurm"], "needs --slurm-folder"),
        (["--executor", "ray", "--slurm-time", "5"], "--slurm-time applies only to"),
    ],
)
def test_misplaced_options_are_refused_before_anything_runs(tmp_path, extra, message):
    import re

    r = CliRunner().invoke(main, ARGS + ["--out", str(tmp_path / "o")] + extra)
    assert r.exit_code == 2 and re.search(message, r.output), r.output
    assert not (tmp_path / "o").exists()


def test_ray_not_installed_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    before = dict(os.environ)
    r = CliRunner().invoke(main, ARGS + ["--out", str(tmp_path / "o"), "--executor", "ray"])
    assert r.exit_code == 2, r.output
    assert "--executor ray needs the 'ray' package, which is not installed" in r.output
    assert 'pip install -e ".[cluster]"' in r.output
    assert dict(os.environ) == before and not (tmp_path / "o").exists()


def test_frame_chunks():
    from benchgen.distribute import frame_chunks

    assert frame_chunks(range(9), 3) == [(0, 1, 2), (3, 4, 5), (6, 7, 8)]
    assert frame_chunks([1, 3, 5, 7], 3) == [(1, 3, 5), (7,)]
    assert frame_chunks([], 3) == []


def test_a_failed_render_task_is_named_after_the_others_finish(tmp_path):
    """A task whose worker sees another scene spec than the driver's fails naming the file; the
    command's error names every failed task (and keeps what the others rendered)."""
    from benchgen.distribute import RenderSpec, RenderTaskError, render_specs
    from benchgen.suite import builtin_scenes_dir
    from m4dgs.core.executors import LocalExecutor

    spec = RenderSpec(
        name="render:x:frames:0-2",
        hdr_dir=str(tmp_path / "hdr"),
        scene_path=str(builtin_scenes_dir() / f"{SCENE}.yaml"),
        spec_sha256="0" * 64,  # not the file's
        width=72,
        height=40,
        render={},
        variant="scalar_rgb",
        kind="frames",
        frames=(0, 1, 2),
    )
    lines = []
    with LocalExecutor(jobs=1, threads=1) as ex, pytest.raises(RenderTaskError) as e:
        render_specs(ex, [spec], log=lines.append)
    msg = str(e.value)
    assert "1 of 1 render task(s) failed" in msg and "render:x:frames:0-2: " in msg
    assert "differs from the driver's" in msg and f"{SCENE}.yaml" in msg
    assert "1/1 render tasks: 0 done, 0 running, 1 failed" in lines[-1]
    assert not (tmp_path / "hdr").exists()


def _make_tiny(root, executor, lines):
    """benchgen make of the tiny scene under `root` on `executor`, tasks of 3 frames; its log lines
    into `lines`."""
    from benchgen.make import make_suite

    make_suite(
        "tiny",
        root,
        preset="tiny",
        scenes=[SCENE],
        priors="oracle",
        progress=False,
        executor=executor,
        frames_per_task=3,
        log=lines.append,
    )


def test_render_only_then_make_is_the_local_clip(local_clip, tmp_path, monkeypatch):
    """--render-only on the local executor (tasks of --frames-per-task, --cpus-per-job threads)
    renders the frames and views, prints the clip's seconds a frame and makes no clip (a relative
    --out, as the default is); run again it finds nothing to render; the same command without it
    makes the local clip's bytes."""
    import re

    monkeypatch.chdir(tmp_path)
    root = Path("render-only")
    args = ARGS + ["--out", str(root), "--render-only"]
    r = CliRunner().invoke(main, args + ["--frames-per-task", "3", "--cpus-per-job", "1"])
    assert r.exit_code == 0, r.output
    clip = _clip(root)
    unit = clip.joinpath(*UNIT_HDR_DIR)
    assert not (clip / "clip.json").exists()
    assert sorted(p.name for p in unit.glob("*.exr")) == [frame_name(g, "exr") for g in range(9)]
    assert f"{TASKS}/{TASKS} render tasks: {TASKS} done, 0 running, 0 failed" in r.output
    line = [ln for ln in r.output.splitlines() if ln.startswith(f"[benchgen] {clip}: ")]
    assert len(line) == 1, r.output
    assert re.search(
        r"9 HDR frame\(s\) on disk; 9 rendered now, median \d+\.\d\d s a frame", line[0]
    )
    assert "views of 4 test frame(s) rendered now" in line[0]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0 and "render tasks" not in r.output, r.output
    assert "9 HDR frame(s) on disk (render only" in r.output
    r = CliRunner().invoke(main, ARGS + ["--out", str(root)])
    assert r.exit_code == 0, r.output
    assert differing_files(local_clip, clip.resolve()) == []


# ----------------------------------------------------------------------------------------- Ray
def test_ray_cluster_makes_the_local_bytes(local_clip, ray_cluster, tmp_path):
    root = tmp_path / "ray"
    r = CliRunner().invoke(
        main,
        ARGS
        + ["--out", str(root), "--executor", "ray", "--address", ray_cluster]
        + ["--cpus-per-job", "1", "--frames-per-task", "3"],
    )
    assert r.exit_code == 0, r.output
    assert f"{TASKS}/{TASKS} render tasks: {TASKS} done, 0 running, 0 failed" in r.output
    assert differing_files(local_clip, _clip(root)) == []
    # the rendering's own fields are there and measured on the workers
    meta = json.loads((_clip(root) / "clip.json").read_text())
    assert meta["gt"]["timing_s_per_frame"]["render"] > 0
    assert meta["gt"]["render"]["adaptive_extra_spp_mean"] > 0
    # a finished clip is skipped: no render task the second time
    r = CliRunner().invoke(
        main, ARGS + ["--out", str(root), "--executor", "ray", "--address", ray_cluster]
    )
    assert r.exit_code == 0 and "render tasks" not in r.output, r.output


def test_a_killed_render_task_reruns_to_the_local_bytes(local_clip, ray_cluster, tmp_path):
    """The worker rendering frames 3-5 is killed (SIGKILL) once frame 3 is on disk; Ray reruns the
    task, which skips frame 3 and renders the rest, and the clip is the local one."""
    from m4dgs.core.executors import RayExecutor

    root = tmp_path / "killed"
    unit = _clip(root).joinpath(*UNIT_HDR_DIR)
    name = f"render:{SCENE}:frames:3-5"
    killed, lines = [], []

    def kill_after_frame_3():
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and not killed:
            if (unit / frame_name(3, "exr")).exists():
                for pid in descendants(os.getpid()):
                    title = cmdline(pid)
                    # the worker running the task (Ray titles it after the task's name)
                    if title.startswith("ray::") and name in title:
                        os.kill(pid, signal.SIGKILL)
                        killed.append((pid, title))
            time.sleep(0.02)

    watcher = threading.Thread(target=kill_after_frame_3, daemon=True)
    with RayExecutor(ray_cluster, threads=1, max_retries=2) as ex:
        watcher.start()
        _make_tiny(root, ex, lines)
    watcher.join()
    assert len(killed) == 1, killed
    done = [ln for ln in lines if ln.startswith(f"[benchgen] rendered {name} ")]
    assert len(done) == 1 and "(3 frame(s)" not in done[0], lines  # frame 3 was kept
    assert f"{TASKS}/{TASKS} render tasks: {TASKS} done" in lines[-1]
    assert differing_files(local_clip, _clip(root)) == []


# ------------------------------------------------------------------------------------ submitit
# ~35 s: slow; the default run keeps the Ray tests (submitit: tests/eval/test_executors.py)
@pytest.mark.slow
def test_a_half_rendered_clip_continues_on_submitit(local_clip, tmp_path):
    """Two of the five render tasks run here, then the command runs again with submitit's local
    executor (the Slurm executor's stand-in): it renders only the three missing tasks and makes
    the local clip."""
    pytest.importorskip("submitit")
    from benchgen.distribute import render_specs
    from benchgen.make import plan_clip
    from benchgen.suite import builtin_scenes_dir
    from m4dgs.core.executors import LocalExecutor, SlurmExecutor

    root = tmp_path / "half"
    specs = plan_clip(
        builtin_scenes_dir() / f"{SCENE}.yaml", _clip(root), "tiny", priors="oracle",
        frames_per_task=3,
    )  # fmt: skip
    assert len(specs) == TASKS
    with LocalExecutor(jobs=1, threads=1) as ex:
        render_specs(ex, specs[:2], log=lambda m: None)
    lines = []
    with SlurmExecutor(tmp_path / "slurm", threads=1, cluster="local", poll_s=0.5) as ex:
        _make_tiny(root, ex, lines)
    assert "3/3 render tasks: 3 done, 0 running, 0 failed, ETA 0 s" in lines[-1], lines
    assert differing_files(local_clip, _clip(root)) == []
    assert list((tmp_path / "slurm").glob("*/*_log.out"))  # the array tasks' logs
