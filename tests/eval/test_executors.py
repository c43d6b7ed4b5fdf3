"""The executors of the suite runner (m4dgs.core.executors): the tiny suite's rows on one tiny
clip with a short training, run by the local executor, by a Ray cluster of three processes (a head
and two workers, one CPU each, token authentication, no dashboard) and by submitit's local
executor, give the same metrics (training on one thread is deterministic); a Ray worker killed in
the middle of a job has its job rerun to the same metrics."""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from ray_helpers import cmdline, descendants, listening, loopback  # tests/ray_helpers.py

from eval.cli import main
from eval.experiments.runner import job_list, run_suite
from m4dgs.core.errors import InputError
from m4dgs.core.executors import (
    LocalExecutor,
    Progress,
    RemoteError,
    Task,
    make_executor,
    ray_token_auth_supported,
    run_task,
)

# metrics.json entries that measure the machine or say how it was scored, not the model
MACHINE = ("seconds", "minutes", "fps", "peak_mem", "conventions", "options")
ROWS = ("static-hdr", "world-only", "full")  # the tiny suite's rows (eval/suites/tiny.yaml)


def write_tiny_suite(tmp_path, clip, short) -> Path:
    """The tiny suite's rows on one existing tiny clip, each with the short training."""
    folder = tmp_path / "clips"
    folder.mkdir()
    shutil.copytree(clip, folder / "flag-arm")
    path = tmp_path / "tiny1.yaml"
    d = {
        "name": "tiny1",
        "scenes": {"clips": str(folder)},
        "rows": [{"name": r, "variant": r, "overrides": dict(short)} for r in ROWS],
        "tables": [{"title": "t", "columns": "paper"}],
    }
    path.write_text(yaml.safe_dump(d))
    return path


def metrics(root, rows=ROWS) -> dict:
    out = {}
    for r in rows:
        m = json.loads((Path(root) / "runs/tiny1/flag-arm" / r / "metrics.json").read_text())
        out[r] = {k: v for k, v in m.items() if not any(w in k for w in MACHINE)}
        assert isinstance(out[r]["hdr_psnr"], float) and len(out[r]) > 20, sorted(out[r])
    return out


@pytest.fixture(scope="module")
def tiny1(tmp_path_factory, tiny_clip_oracle):
    """(suite file, metrics of the local executor: two worker processes, one thread each)."""
    tmp = tmp_path_factory.mktemp("tiny1")
    short = {
        "stage1.iterations": 12,
        "stage2.iterations": 12,
        "camera_init.ba_steps": 20,
        "tonemap.pretrain_steps": 10,
        "v2w.scale_refit_steps": 5,
    }
    suite = write_tiny_suite(tmp, tiny_clip_oracle, short)
    lines = []
    with LocalExecutor(jobs=2, threads=1) as ex:
        res = run_suite(
            suite, tmp / "local", "tiny", score_kw={"fps": False}, log=lines.append, executor=ex
        )
    assert all(r["steps"] == ["train", "score"] for r in res), res
    # the driver's progress line after each job: done, running, failed, ETA
    prog = [ln for ln in lines if " jobs: " in ln]
    assert len(prog) == 3 and prog[-1].endswith("3 done, 0 running, 0 failed, ETA 0 s"), lines
    return suite, metrics(tmp / "local")


# -------------------------------------------------------------------------------- no training
def test_progress_line_counts_and_eta():
    now = [0.0]
    p = Progress(5, 2, clock=lambda: now[0])
    assert p.line() == "0/5 jobs: 0 done, 2 running, 0 failed, ETA ?"
    now[0] = 40.0
    p.add(True)
    p.add(False)
    # 2 finished in 40 s, 3 left: 60 s at that pace
    assert p.line() == "2/5 jobs: 1 done, 2 running, 1 failed, ETA 60 s"
    for _ in range(3):
        p.add(True)
    assert p.line() == "5/5 jobs: 4 done, 0 running, 1 failed, ETA 0 s"


def test_options_that_do_not_apply_are_refused(tmp_path):
    with pytest.raises(InputError, match="--address applies only to --executor ray"):
        make_executor("local", address="127.0.0.1:6379")
    with pytest.raises(InputError, match="--slurm-partition applies only to --executor slurm"):
        make_executor("ray", slurm_partition="gpu")
    with pytest.raises(InputError, match="--jobs 2 .* drop --jobs"):
        make_executor("slurm", jobs=2, slurm_folder=str(tmp_path))
    with pytest.raises(InputError, match="needs --slurm-folder"):
        make_executor("slurm")
    with pytest.raises(InputError, match="--gpus-per-job must be 0 or 1"):
        make_executor("slurm", gpus_per_job=2, slurm_folder=str(tmp_path))
    pytest.importorskip("submitit")
    if not shutil.which("srun"):
        # never the local stand-in without saying so: no Slurm here is an error naming it
        with pytest.raises(InputError, match="--executor slurm: .*srun.*login node"):
            make_executor("slurm", slurm_folder=str(tmp_path))
    r = CliRunner().invoke(main, ["suite", "run", "tiny", "--address", "x:1", "--root", "r"])
    assert r.exit_code == 2 and "--address applies only to --executor ray" in r.output
    assert not Path("r").exists()


def test_run_task_envelope_and_token_versions():
    assert run_task(divmod, (7, 2), {}, None, "cpu") == {"result": (3, 1)}
    env = run_task(divmod, (1, 0), {}, None, "cpu")
    assert env["error"].startswith("ZeroDivisionError") and "Traceback" in env["traceback"]
    env = run_task(_raise_input_error, (), {}, None, "cpu")
    assert env == {"error": "no such clip", "traceback": None}  # the project's own: no traceback
    assert isinstance(RemoteError("x"), Exception)
    assert ray_token_auth_supported("2.52.0") and ray_token_auth_supported("2.60.1")
    assert not ray_token_auth_supported("2.51.2") and not ray_token_auth_supported("2.9.3")


def test_a_ray_executor_that_cannot_start_leaves_the_environment_as_it_was(monkeypatch):
    import m4dgs.core.executors as executors

    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    monkeypatch.setattr(executors, "_ray_version_has_tokens", lambda: True)

    def no_ray(module, executor):
        raise InputError(f"--executor {executor} needs the {module!r} package")

    monkeypatch.setattr(executors, "_need", no_ray)
    before = dict(os.environ)
    with pytest.raises(InputError, match="--executor ray needs the 'ray' package"):
        executors.RayExecutor()
    assert dict(os.environ) == before  # no token, no usage-stats switch left behind


def _raise_input_error():
    raise InputError("no such clip")


class _NeedsTwoArgs(Exception):
    """An exception that does not survive pickling: its __init__ needs more than its message."""

    def __init__(self, a, b):
        super().__init__(f"{a} and {b}")


def _raise_needs_two_args():
    raise _NeedsTwoArgs("one", "two")


def _raise_clip_error():
    from m4dgs.clip import ClipError

    raise ClipError("x/tracks.npz", "tracks", "bad points")


def test_an_exception_that_does_not_pickle_fails_only_its_task():
    """A task whose exception cannot be unpickled used to break the pool and fail every task
    after it (seen in a campaign: one clip's ClipError failed 33 jobs); now it fails alone, with
    its message, and the project's own errors keep their type."""
    import pickle

    from m4dgs.clip import ClipError
    from m4dgs.core.executors import RemoteError

    e = pickle.loads(pickle.dumps(ClipError("x/tracks.npz", "tracks", "bad points")))
    assert (e.path, e.field, e.problem) == ("x/tracks.npz", "tracks", "bad points")
    from eval.records.suite import SuiteError

    e = SuiteError("s.yaml", "rows", "no row")
    assert str(pickle.loads(pickle.dumps(e))) == str(e) == "s.yaml: 'rows': no row"
    tasks = [Task("bad", _raise_needs_two_args, ())]
    tasks += [Task(f"ok{i}", abs, (-i,)) for i in range(4)] + [Task("clip", _raise_clip_error, ())]
    with LocalExecutor(jobs=2, threads=1) as ex:
        out = {o.task.name: o for o in ex.map(tasks)}
    assert {n: out[n].result for n in ("ok0", "ok1", "ok2", "ok3")} == {
        "ok0": 0,
        "ok1": 1,
        "ok2": 2,
        "ok3": 3,
    }
    assert isinstance(out["bad"].error, RemoteError)
    assert str(out["bad"].error) == "_NeedsTwoArgs: one and two"
    assert "_raise_needs_two_args" in out["bad"].error.remote_traceback
    assert isinstance(out["clip"].error, ClipError) and out["clip"].error.field == "tracks"


def test_local_pool_yields_as_tasks_finish():
    with LocalExecutor(jobs=2, threads=1) as ex:
        got = [
            o.task.name
            for o in ex.map([Task("slow", time.sleep, (1.5,)), Task("fast", abs, (-1,))])
        ]
    assert got == ["fast", "slow"]


# ----------------------------------------------------------------------------------------- Ray
@pytest.mark.slow
def test_ray_cluster_of_its_own(tiny1, tmp_path):
    """--executor ray without --address: the executor starts a cluster on this machine (its own
    temp dir, every port on 127.0.0.1, token authentication where this Ray has it), runs the
    suite to the local metrics, and leaves nothing behind (slow: Ray's start-up on a busy 2-core
    machine takes 20-40 s). On a machine with a network address, a Ray that swaps 127.0.0.1 for
    that address listens there unless the executor keeps it to one machine."""
    ray = pytest.importorskip("ray")
    from ray._private import ray_constants

    from m4dgs.core.executors import RayExecutor

    suite, local = tiny1
    keys = ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_USAGE_STATS_ENABLED")
    keys += (ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR,)
    before = {k: os.environ.get(k) for k in keys}
    switch = ray_constants.ENABLE_RAY_CLUSTER
    with RayExecutor(threads=1, num_cpus=2) as ex:
        temp = Path(ex._own_temp)
        assert temp.is_dir()
        if ray_token_auth_supported(ray.__version__) and before["RAY_AUTH_MODE"] is None:
            assert (
                os.environ["RAY_AUTH_MODE"] == "token" and len(os.environ["RAY_AUTH_TOKEN"]) == 64
            )
        assert ex.slots == 2
        res = run_suite(
            suite, tmp_path / "root", "tiny", score_kw={"fps": False}, log=print, executor=ex
        )
        ports = listening(descendants(os.getpid()))
        assert ports and all(loopback(ip) for ip, _ in ports), ports
    assert all(r["steps"] == ["train", "score"] for r in res), res
    assert metrics(tmp_path / "root") == local
    assert not temp.exists()
    assert {k: os.environ.get(k) for k in keys} == before
    assert ray_constants.ENABLE_RAY_CLUSTER == switch
    # its processes are gone (they may take a moment to exit)
    deadline = time.monotonic() + 20
    while [p for p in descendants(os.getpid()) if "ray" in cmdline(p)]:
        assert time.monotonic() < deadline, "Ray processes left running"
        time.sleep(0.2)


def test_ray_cluster_gives_the_local_metrics(tiny1, ray_cluster, tmp_path):
    suite, local = tiny1
    r = CliRunner().invoke(
        main,
        [
            "suite",
            "run",
            str(suite),
            "--root",
            str(tmp_path / "ray"),
            "--preset",
            "tiny",
            "--executor",
            "ray",
            "--address",
            ray_cluster,
            "--cpus-per-job",
            "1",
        ],
    )
    assert r.exit_code == 0, r.output
    assert metrics(tmp_path / "ray") == local
    assert "3/3 jobs: 3 done, 0 running, 0 failed" in r.output
    # every port of the cluster's processes is on the loopback interface only
    ports = listening(descendants(os.getpid()))
    assert ports and all(loopback(ip) for ip, _ in ports), ports


def test_ray_reruns_the_job_of_a_killed_worker(tiny1, ray_cluster, tmp_path):
    """The worker running the full row's job is killed (SIGKILL) once the job trains; Ray reruns
    it (the run-folder lock died with the worker: the rerun resumes the run), and it finishes
    with the local metrics."""
    from eval.experiments.runner import _run_job_kw
    from m4dgs.core.executors import RayExecutor

    suite, local = tiny1
    job = next(j for j in job_list(suite, tmp_path / "root", "tiny") if j.row == "full")
    killed = []

    def kill_when_training():
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and not killed:
            if (Path(job.run_dir) / "status.json").exists():
                for pid in descendants(os.getpid()):
                    title = cmdline(pid)
                    # the worker executing the job (Ray titles it after the task's name, the job
                    # id), not Ray's own processes (e.g. a dashboard agent, which some Ray
                    # installations start)
                    if title.startswith("ray::") and job.id in title:
                        os.kill(pid, signal.SIGKILL)
                        killed.append((pid, title))
            time.sleep(0.02)

    watcher = threading.Thread(target=kill_when_training, daemon=True)
    kw = dict(score_kw={"fps": False}, progress=False)
    with RayExecutor(ray_cluster, threads=1, max_retries=2) as ex:
        watcher.start()
        (o,) = list(ex.map([Task(job.id, _run_job_kw, (job, kw), threads=1)]))
    watcher.join()
    assert len(killed) == 1, killed
    assert o.error is None, o.error
    assert o.result["steps"] == ["train", "score"]
    assert metrics(tmp_path / "root", ["full"]) == {"full": local["full"]}


# ------------------------------------------------------------------------------------ submitit
def test_submitit_local_executor_runs_the_job_list(tiny1, tmp_path):
    pytest.importorskip("submitit")
    from m4dgs.core.executors import SlurmExecutor

    suite, local = tiny1
    with SlurmExecutor(tmp_path / "slurm", threads=1, cluster="local", poll_s=0.5) as ex:
        res = run_suite(
            suite, tmp_path / "root", "tiny", score_kw={"fps": False}, log=print, executor=ex
        )
    assert all(r["steps"] == ["train", "score"] for r in res), res
    assert metrics(tmp_path / "root") == local
    assert list((tmp_path / "slurm").glob("*/*_log.out"))  # the array tasks' logs
