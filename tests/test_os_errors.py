"""What a new user meets when the operating system or their files refuse: one-line errors naming
the path (permission, no space, a file-size limit, a read-only file system), a training log
without a dead attempt's steps, and clear words for files that are not what they claim to be."""

from __future__ import annotations

import errno
import os
import pathlib
import resource
import shutil
import subprocess
import sys
import time
from collections import Counter

import numpy as np
import pytest
from click.testing import CliRunner

from m4dgs.cli import main as m4dgs_main
from m4dgs.core import io as mio
from m4dgs.run import RunDir

REPO = pathlib.Path(__file__).resolve().parents[1]


def _one_error_line(r) -> str:
    """The single `Error: ...` line of a click run that ended cleanly (no traceback)."""
    assert r.exit_code == 1, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("Error: ")]
    assert len(errors) == 1 and "Traceback" not in r.output, r.output
    return errors[0]


# -- the operating system's refusals ---------------------------------------------------------------
@pytest.mark.parametrize(
    "code, words",
    [
        (errno.EACCES, "permission denied"),
        (errno.EPERM, "not permitted"),
        (errno.ENOSPC, "no space left"),
        (errno.EDQUOT, "quota"),
        (errno.EFBIG, "file too large"),
        (errno.EROFS, "read-only file system"),
    ],
)
def test_an_os_refusal_at_the_run_folder_is_one_line_naming_it(
    tiny_clip_oracle, tmp_path, monkeypatch, code, words
):
    """`m4dgs train --out` where the run folder cannot be made (as an ordinary user under a folder
    of root's: the lock's mkdir raised PermissionError with a traceback)."""
    blocked = tmp_path / "blocked"
    real_mkdir = pathlib.Path.mkdir

    def mkdir(self, *a, **k):
        if str(self).startswith(str(blocked)):
            raise OSError(code, f"strerror {code}", str(self))
        return real_mkdir(self, *a, **k)

    monkeypatch.setattr(pathlib.Path, "mkdir", mkdir)
    r = CliRunner().invoke(
        m4dgs_main,
        ["train", "--clip", str(tiny_clip_oracle), "--preset", "tiny", "--quiet"]
        + ["--out", str(blocked / "run")],
    )
    line = _one_error_line(r)
    assert str(blocked / "run") in line and words in line.lower(), line


def test_os_error_line_knows_only_the_refusals_a_user_can_act_on(tmp_path):
    from m4dgs.core.errors import os_error_line, with_path

    assert os_error_line(FileNotFoundError(errno.ENOENT, "No such file", "x")) is None
    assert os_error_line(OSError(errno.EIO, "I/O error", "x")) is None  # a disk fault: traceback
    assert os_error_line(ValueError("no")) is None
    line = os_error_line(OSError(errno.ENOSPC, "No space left on device", "/data/run/ckpt.pt"))
    assert line.startswith("/data/run/ckpt.pt: no space left") and "\n" not in line
    # a partial write names no file, or the atomic writer's temporary one: the destination's goes in
    dest = tmp_path / "metrics.json"
    assert with_path(OSError(errno.EFBIG, "File too large"), dest).filename == str(dest)
    tmp = OSError(errno.ENOSPC, "No space", str(tmp_path / ".metrics.json.a1b2.tmp"))
    assert with_path(tmp, dest).filename == str(dest)
    other = OSError(errno.ENOSPC, "No space", str(tmp_path / "other.json"))
    assert with_path(other, dest) is other
    assert isinstance(with_path(OSError(errno.EACCES, "denied"), dest), PermissionError)


def _limited(limit_bytes: int):
    def preexec():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, resource.RLIM_INFINITY))

    return preexec


def _m4dgs(args, cwd, limit=None):
    """Run a tool in a child process (Python ignores SIGXFSZ, so a write past `ulimit -f` fails
    with EFBIG, "File too large", as in a shell with that limit)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}  # this checkout's code, whatever is installed
    return subprocess.run(
        [sys.executable, "-m", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        preexec_fn=None if limit is None else _limited(limit),
        timeout=300,
    )


@pytest.fixture(scope="module")
def limited_run(tiny_clip_oracle, tmp_path_factory):
    """A short tiny training whose first stage-1 checkpoint hits a 400 KiB file-size limit, then
    resumed without the limit: (first attempt, run folder, log records after the first attempt)."""
    root = tmp_path_factory.mktemp("limited")
    run = root / "run"
    sets = [
        "stage1.iterations=12",
        "stage2.iterations=8",
        "camera_init.ba_steps=20",
        "tonemap.pretrain_steps=10",
        "v2w.scale_refit_steps=5",
        "checkpoint_every=5",
    ]
    args = ["m4dgs", "train", "--clip", str(tiny_clip_oracle), "--preset", "tiny", "--quiet"]
    args += ["--out", str(run), "--threads", "1"] + [x for s in sets for x in ("--set", s)]
    first = _m4dgs(args, root, limit=400 * 1024)
    log_before = RunDir(run).read_log()
    second = _m4dgs(args, root)
    assert second.returncode == 0, second.stderr[-3000:]
    return first, run, log_before


def test_a_write_past_the_file_size_limit_is_one_line_naming_the_file(limited_run):
    first, run, _ = limited_run
    assert first.returncode == 1, first.stderr[-3000:]
    err = [ln for ln in first.stderr.splitlines() if ln.startswith("Error: ")]
    assert len(err) == 1 and "Traceback" not in first.stderr, first.stderr[-3000:]
    assert str(run / "model" / "ckpt.pt") in err[0] and "file too large" in err[0], err[0]


def test_the_resumed_log_holds_each_step_once(limited_run):
    """A stage killed (here: failing its first checkpoint's write) before its first checkpoint
    left its steps in log.jsonl, and the resumed run wrote them again (the loss figures read
    both)."""
    _, run, before = limited_run
    assert any(r["stage"] == "stage1" for r in before)  # the dead attempt did log steps
    log = RunDir(run).read_log()
    counts = Counter((r["stage"], r["step"]) for r in log)
    assert max(counts.values()) == 1, [k for k, v in counts.items() if v > 1][:5]
    assert sorted(s for st, s in counts if st == "stage1") == list(range(12))
    assert sorted(s for st, s in counts if st == "stage2") == list(range(8))


def test_truncate_log_on_a_fresh_start_of_a_stage(tmp_path):
    """Every resume path: no checkpoint of the stage (killed before its first one) drops all of
    its lines; a checkpoint at step k keeps steps < k; other stages' lines and the file itself
    stay when nothing goes."""
    from m4dgs.training.pipeline import Trainer

    run = RunDir(tmp_path)
    recs = [{"stage": "stage1", "step": i} for i in range(4)]
    recs += [{"stage": "stage2", "step": i} for i in range(3)]
    run.log_records(recs)

    class Fake:
        pass

    fake = Fake()
    fake.run = run
    fake._checkpoint = lambda stage: None
    assert Trainer._resume(fake, "stage2", None) == 0
    assert [(r["stage"], r["step"]) for r in run.read_log()] == [("stage1", i) for i in range(4)]

    class Obj:
        def load_state_dict(self, sd):
            self.sd = sd

    assert Trainer._resume(fake, "stage1", Obj(), {"step": 2, "state": {}}) == 2
    assert [r["step"] for r in run.read_log()] == [0, 1]
    mtime = (tmp_path / "log.jsonl").stat().st_mtime_ns
    time.sleep(0.01)
    run.truncate_log("stage1", 5)  # nothing past 5: the file is not rewritten
    assert (tmp_path / "log.jsonl").stat().st_mtime_ns == mtime


def test_a_failing_metrics_write_in_score_is_one_line(limited_run, tmp_path):
    """`m4dgs-eval score --force` under `ulimit -f 8`."""
    _, run, _ = limited_run
    r = _m4dgs(["eval", "score", str(run), "--force"], tmp_path, limit=8 * 1024)
    err = [ln for ln in r.stderr.splitlines() if ln.startswith("Error: ")]
    assert r.returncode == 1 and len(err) == 1 and "Traceback" not in r.stderr, r.stderr[-3000:]
    assert "file too large" in err[0] and str(run) in err[0], err[0]


# -- --set ----------------------------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore:config key 'stage1.lambda_dep' is deprecated")
@pytest.mark.parametrize(
    "setting, words",
    [
        ("stage1.nosuch=3", "unknown config key 'stage1.nosuch'"),
        ("stage1.loss.lambda_depp=3", "did you mean 'lambda_dep'"),
        ("nosuch.x=3", "unknown config key 'nosuch'"),
        ("stage1.lambda_dep=nan", "finite"),
        ("stage1.loss.lambda_dep=nan", "finite"),
        ("stage1.iterations=abc", "expects an integer"),
        ("stage1.iterations=[1,", "is not a value"),
    ],
)
def test_a_bad_set_is_one_line_and_leaves_no_folder(
    tiny_clip_oracle, tmp_path, monkeypatch, setting, words
):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(
        m4dgs_main,
        ["train", "--clip", str(tiny_clip_oracle), "--preset", "tiny", "--quiet", "--set", setting],
    )
    assert words in _one_error_line(r)
    assert not (tmp_path / "runs").exists()  # not even runs/<clip>/


# -- files that are not what they claim ------------------------------------------------------------
def _clip_copy(src, dst):
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("gt"))
    return dst


@pytest.mark.parametrize("damage", ["truncated", "jpeg"])
def test_a_damaged_or_foreign_frame_is_one_line(tiny_clip_oracle, tmp_path, capfd, damage):
    clip = _clip_copy(tiny_clip_oracle, tmp_path / "clip")
    frame = sorted((clip / "input" / "ldr").glob("*.png"))[1]
    if damage == "truncated":
        frame.write_bytes(frame.read_bytes()[:300])
    else:
        import OpenImageIO as oiio

        jpg = tmp_path / "f.jpg"
        oiio.ImageBuf(oiio.ImageSpec(72, 40, 3, oiio.UINT8)).write(str(jpg))
        shutil.copy(jpg, frame)
    r = CliRunner().invoke(
        m4dgs_main,
        ["train", "--clip", str(clip), "--preset", "tiny", "--quiet", "--out", str(tmp_path / "r")],
    )
    line = _one_error_line(r)
    assert str(frame) in line
    assert ("truncated PNG" if damage == "truncated" else "a JPEG file named .png") in line
    assert "libpng" not in capfd.readouterr().err  # the image library printed nothing of its own


def test_read_png_refuses_what_is_not_a_whole_png(tmp_path):
    img = (np.arange(12 * 10 * 3) % 256).astype(np.uint8).reshape(12, 10, 3)
    good = tmp_path / "good.png"
    mio.write_png(good, img)
    np.testing.assert_array_equal(mio.read_png(good), img)
    cut = tmp_path / "cut.png"
    cut.write_bytes(good.read_bytes()[:-20])
    with pytest.raises(mio.FileFormatError, match="truncated PNG"):
        mio.read_png(cut)
    with pytest.raises(mio.InputError, match="truncated PNG"):
        mio.read_image(cut)  # external frames too: converted when of another format, never cut
    text = tmp_path / "notes.png"
    text.write_text("hello")
    with pytest.raises(mio.FileFormatError, match="not a PNG file"):
        mio.read_png(text)


def test_stray_files_in_input_are_named(tiny_clip_oracle, tmp_path):
    from m4dgs.clip import Clip
    from m4dgs.training.pipeline import Trainer

    clip = _clip_copy(tiny_clip_oracle, tmp_path / "clip")
    assert Clip.open(clip).stray_inputs() == []
    (clip / "input" / "notes.txt").write_text("shot on a Tuesday")
    test_frame = Clip.open(clip).test_frames[0]
    name = f"{test_frame:05d}.png"
    shutil.copy(sorted((clip / "input" / "ldr").glob("*.png"))[0], clip / "input" / "ldr" / name)
    stray = [p.relative_to(clip).as_posix() for p in Clip.open(clip).stray_inputs()]
    assert stray == [f"input/ldr/{name}", "input/notes.txt"]
    with pytest.warns(UserWarning, match=r"2 file\(s\) in input/.*input/notes.txt"):
        Trainer(clip, tmp_path / "run", preset="tiny", progress=False)


def test_a_folder_of_frames_says_how_to_make_a_clip(tmp_path, monkeypatch):
    frames = tmp_path / "my-frames"
    frames.mkdir()
    for i in range(3):
        mio.write_png(frames / f"{i:04d}.png", np.zeros((8, 8, 3), np.uint8))
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(m4dgs_main, ["train", "--clip", str(frames), "--preset", "tiny"])
    line = _one_error_line(r)
    assert "clip.json" in line and "m4dgs import-clip" in line and "benchgen from-hdr" in line
    assert "3 image(s)" in line
    assert not (tmp_path / "runs").exists()


# -- YAML ------------------------------------------------------------------------------------------
def _yaml_loaders():
    from benchgen.priors import load_profile
    from benchgen.spec import read_yaml as read_spec
    from eval.experiments.campaign import load_campaign
    from eval.records.suite import load_eval_suite
    from m4dgs.training.config import load_yaml as load_config

    return {
        "scene spec": read_spec,
        "prior profile": load_profile,
        "eval suite": load_eval_suite,
        "campaign": load_campaign,
        "train config": load_config,
    }


@pytest.mark.parametrize("kind", list(_yaml_loaders()))
def test_a_yaml_syntax_error_names_the_file_and_line(tmp_path, kind):
    bad = tmp_path / "mine.yaml"
    bad.write_text("name: x\nscenes: [a, b\nfoo: 1\n")
    with pytest.raises(mio.InputError) as e:
        _yaml_loaders()[kind](bad)
    msg = str(e.value)
    assert str(bad) in msg and "line 3" in msg and "\n" not in msg, msg
    assert "<unicode string>" not in msg
