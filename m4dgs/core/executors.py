"""Where a command's tasks run: this process, a local process pool, a Ray cluster or Slurm
(through submitit). Shared by `m4dgs-eval suite run / campaign` (eval.experiments.runner: clips,
then training jobs) and `benchgen make` (benchgen.distribute: frame-range render tasks).

An executor takes a list of tasks (a module-level function, its arguments, the CPU threads and the
GPUs, 0 or 1, the task needs) and yields one Outcome per task as the tasks finish, in whatever
order they finish. Each task runs the same function wherever it runs, so the folder locks and the
files the tasks share work alike everywhere, as long as the output root is on storage every worker
sees.

- local: `jobs` 1 runs the tasks one after another in this process; `jobs` > 1 in a pool of that
  many worker processes.
- ray: each task is a Ray task (num_cpus = its threads, num_gpus = its GPUs, rerun up to
  max_retries times when its worker dies). Without an address the executor starts a one-machine
  cluster of its own (bound to 127.0.0.1, no dashboard unless asked, its own temp dir, token
  authentication where the installed Ray has it) and stops it at the end; with one it connects.
- slurm: the tasks of each map() call become Slurm job arrays through submitit (`cluster="local"`
  runs them as local processes instead: what the tests use).

Ray and submitit are optional (`pip install -e .[cluster]`) and imported only by their executors.
The command-line options that choose an executor are in m4dgs.core.executor_options.
"""

from __future__ import annotations

import abc
import os
import pickle
import secrets
import sys
import tempfile
import time
import traceback
import warnings
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence

from m4dgs.core.errors import InputError, M4DGSError

EXECUTORS = ("local", "ray", "slurm")
DEFAULT_CPUS_PER_JOB = 2  # ray, slurm: CPU threads of one job unless --cpus-per-job says


def _job_resources(threads, gpus) -> tuple:
    if int(threads) < 1:
        raise InputError(f"--cpus-per-job must be >= 1, got {threads!r}")
    if int(gpus) not in (0, 1):
        raise InputError(f"--gpus-per-job must be 0 or 1, got {gpus!r}")
    return int(threads), int(gpus)


@dataclass
class Task:
    """One unit of work: fn(*args, **kwargs) with `threads` CPU threads (None: as the process has
    them; only the local executor's in-process mode distinguishes) and `gpus` GPUs (0 or 1)."""

    name: str
    fn: Callable
    args: tuple = ()
    kwargs: Dict[str, Any] = field(default_factory=dict)
    threads: Optional[int] = 1
    gpus: int = 0


@dataclass
class Outcome:
    """A finished task: its result, or the error it raised (error set, result None)."""

    task: Task
    result: Any = None
    error: Optional[BaseException] = None


class RemoteError(M4DGSError):
    """A task that failed in another process (a Ray or Slurm worker): str() is the one-line error
    (error_line) the worker saw; `remote_traceback` the traceback of an
    exception that is not one of the project's own errors (None for those)."""

    def __init__(self, line: str, remote_traceback: Optional[str] = None):
        super().__init__(line)
        self.remote_traceback = remote_traceback


def error_line(exc: BaseException) -> str:
    """One line for an error: the message of the project's own errors (they name the file, key or
    stage), the type and first line of any other exception."""
    one = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return one if isinstance(exc, M4DGSError) else f"{type(exc).__name__}: {one}"


def _worker_init(threads: int, device: str = "auto") -> None:
    """Spend a worker's `threads` CPUs as m4dgs.core.threads.use_threads does (on the CPU: torch 1,
    the compiled kernels `threads`)."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    # deferred: job listing and locking stay torch-free
    from m4dgs.core.threads import use_threads

    use_threads(max(1, threads), device)


def pool_context(device: str = "auto"):
    """The multiprocessing context of `run --jobs N` workers: "spawn" where they train on CUDA (a
    forked child cannot use CUDA once its parent has touched it, and spawn is what PyTorch supports
    for CUDA in subprocesses), else the platform default (fork on Linux: no re-imports)."""
    import multiprocessing

    from m4dgs.core.device import resolve_device

    cuda = device is not None and resolve_device(device).type == "cuda"
    return multiprocessing.get_context("spawn" if cuda else None)


def run_task(fn: Callable, args: tuple, kwargs: dict, threads: Optional[int], device: str) -> dict:
    """Run one task in a worker process: spend `threads` CPUs as m4dgs.core.threads.use_threads
    does, call fn and return {"result": ...}, or {"error": one line, "traceback": ... or None}
    (an envelope instead of a raised exception, so that the driver gets the message without
    unpickling the worker's exception classes, and Ray reruns only a task whose worker died)."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from m4dgs.core.threads import use_threads

    if threads is not None:
        use_threads(max(1, int(threads)), device)
    try:
        return {"result": fn(*args, **kwargs)}
    except Exception as exc:
        tb = None if isinstance(exc, M4DGSError) else traceback.format_exc()
        return {"error": error_line(exc), "traceback": tb}


def _pool_call(fn: Callable, args: tuple, kwargs: dict) -> Any:
    """fn(*args, **kwargs) in a LocalExecutor pool worker. An exception goes back to the driver as
    it is when it survives pickling, else as a RemoteError with its one-line message and traceback:
    an exception the driver cannot unpickle (one whose __init__ needs more than its message)
    would otherwise break the pool and fail every task after it."""
    try:
        return fn(*args, **kwargs)
    except Exception as exc:
        try:
            pickle.loads(pickle.dumps(exc))
        except Exception:
            raise RemoteError(error_line(exc), traceback.format_exc()) from None
        raise


def _unwrap(task: Task, env: Any) -> Outcome:
    if isinstance(env, dict) and "error" in env:
        return Outcome(task, error=RemoteError(env["error"], env.get("traceback")))
    return Outcome(task, result=env["result"])


class Executor(abc.ABC):
    """Base class: `map(tasks)` yields an Outcome per task as they finish; `slots` is how many tasks
    run at once (for the progress line); `inline` is true when tasks run in this process (they
    may then show progress bars). Use as a context manager: leaving it cancels what has not
    started (fail fast, Ctrl-C) and releases the workers or the cluster."""

    name = "base"
    inline = False
    threads = 1  # CPU threads of one job (Task.threads of the runner's tasks)
    gpus = 0  # GPUs of one job, 0 or 1 (clips take none)

    @property
    def slots(self) -> int:
        return 1

    @abc.abstractmethod
    def map(
        self, tasks: Sequence[Task], on_start: Optional[Callable[[Task], None]] = None
    ) -> Iterator[Outcome]:
        """Run `tasks` (calling on_start(task) as each starts) and yield their Outcomes as they
        finish."""

    def close(self) -> None:  # noqa: B027 - nothing to release unless a subclass holds workers
        return None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class LocalExecutor(Executor):
    """jobs 1: the tasks one after another in this process, each with `threads` CPU threads
    (default: every CPU of the process) while it runs; jobs > 1: a process pool of `jobs` workers
    with `threads` each (default cpu_budget / jobs), started with pool_context (spawn on CUDA,
    the platform default otherwise)."""

    name = "local"

    def __init__(self, jobs: int = 1, threads: Optional[int] = None, device: str = "auto"):
        from m4dgs.core.threads import cpu_budget

        if int(jobs) < 1:
            raise InputError(f"--jobs must be >= 1, got {jobs!r}")
        self.jobs = int(jobs)
        self.device = device
        self.inline = self.jobs <= 1
        self.threads = int(threads) if threads else max(1, cpu_budget() // self.jobs)
        self._pool: Optional[ProcessPoolExecutor] = None

    @property
    def slots(self) -> int:
        return self.jobs

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                max_workers=self.jobs,
                mp_context=pool_context(self.device),
                initializer=_worker_init,
                initargs=(self.threads, self.device),
            )
        return self._pool

    def map(self, tasks, on_start=None):
        if self.inline:
            from m4dgs.core.threads import threads_for

            for t in tasks:
                if on_start is not None:
                    on_start(t)
                try:
                    if t.threads is None:
                        res = t.fn(*t.args, **t.kwargs)
                    else:
                        with threads_for(t.threads, self.device):
                            res = t.fn(*t.args, **t.kwargs)
                except Exception as exc:
                    yield Outcome(t, error=exc)
                    continue
                yield Outcome(t, result=res)
            return
        pool = self._get_pool()
        futs = {pool.submit(_pool_call, t.fn, t.args, t.kwargs): t for t in tasks}
        if on_start is not None:
            for t in futs.values():
                on_start(t)
        pending = set(futs)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                exc = f.exception()
                yield Outcome(futs[f], error=exc) if exc else Outcome(futs[f], result=f.result())

    def close(self) -> None:
        if self._pool is not None:
            # fail fast / Ctrl-C: start nothing more, wait for the running ones
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def ray_token_auth_supported(version: Optional[str] = None) -> bool:
    """Whether a Ray version has token authentication (RAY_AUTH_MODE=token, Ray >= 2.52.0)."""
    if version is None:
        import ray

        version = ray.__version__
    parts = []
    for p in str(version).split(".")[:2]:
        digits = "".join(c for c in p if c.isdigit())
        parts.append(int(digits or 0))
    return tuple(parts) >= (2, 52)


def _ray_version_has_tokens() -> bool:
    from importlib import metadata

    try:
        return ray_token_auth_supported(metadata.version("ray"))
    except metadata.PackageNotFoundError:
        return False


def _reload_ray_auth() -> None:
    """Make an imported Ray read RAY_AUTH_MODE / RAY_AUTH_TOKEN again (it reads them on import)."""
    if "ray" not in sys.modules:
        return
    try:
        from ray._raylet import AuthenticationTokenLoader, Config

        AuthenticationTokenLoader.instance().reset_cache()
        Config.initialize("")
    except (ImportError, AttributeError):  # another Ray version: its import-time reading stands
        pass


@contextmanager
def _quiet_ray_tip():
    """Ray 2.5x warns at ray.init that a future version will stop hiding the GPUs from a task that
    asks for none; this executor wants them hidden (a clip or CPU job must not take a GPU), which
    docs/cluster.md says, so the tip is not repeated on every command."""
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore", message="Tip: In future versions of Ray", category=FutureWarning
        )
        yield


def _need(module: str, executor: str):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise InputError(
            f"--executor {executor} needs the {module!r} package, which is not installed: "
            'pip install -e ".[cluster]" (Ray and submitit), or use --executor local'
        ) from None


class RayExecutor(Executor):
    """Each task a Ray task with num_cpus = its threads and num_gpus = its GPUs, rerun up to
    `max_retries` times when its worker process dies (a failed job, which returns its error, is
    not rerun).

    address None: start a cluster on this machine for the duration (ray.init: bound to 127.0.0.1,
    no dashboard unless `dashboard`, temp dir `temp_dir` or a new one under the system's temp
    folder, token authentication with a fresh token when the installed Ray supports it and
    RAY_AUTH_MODE is not set otherwise; `num_cpus` CPUs, default all). address given ("auto", or
    HOST:PORT of the head's GCS): connect to that cluster, which must have this repository
    installed on every node and see ROOT at the same path; a token-authenticated cluster needs its
    token here as Ray reads it (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token)."""

    name = "ray"

    def __init__(
        self,
        address: Optional[str] = None,
        device: str = "auto",
        threads: int = DEFAULT_CPUS_PER_JOB,
        gpus: int = 0,
        max_retries: int = 3,
        dashboard: bool = False,
        temp_dir: Optional[str] = None,
        num_cpus: Optional[int] = None,
        object_store_mb: Optional[int] = None,
    ):
        self.device = device
        self.threads, self.gpus = _job_resources(threads, gpus)
        self.max_retries = int(max_retries)
        self._env_before: Dict[str, Optional[str]] = {}
        self._own_temp = None
        self._cluster_switch: Optional[bool] = None  # Ray's multi-machine switch, as it was
        self.started = address is None
        if self.started and "RAY_AUTH_MODE" not in os.environ and _ray_version_has_tokens():
            # a fresh token for this cluster, through the environment its processes inherit (no
            # token file written); Ray reads it when imported, or when told to reload it
            self._set_env("RAY_AUTH_MODE", "token")
            self._set_env("RAY_AUTH_TOKEN", secrets.token_hex(32))
            _reload_ray_auth()
        try:
            ray = self._init(address, dashboard, temp_dir, num_cpus, object_store_mb)
        except BaseException:  # no Ray, a failed start: leave the environment as it was
            self._restore()
            raise
        self._ray = ray
        self._remote = ray.remote(run_task)
        self._pending: List[Any] = []

    def _init(self, address, dashboard, temp_dir, num_cpus, object_store_mb):
        """Start (address None) or join the cluster; returns the ray module."""
        ray = _need("ray", "ray")
        if ray.is_initialized():
            raise InputError("Ray is already initialised in this process; run one executor at once")
        if self.started:
            if "RAY_USAGE_STATS_ENABLED" not in os.environ:
                self._set_env("RAY_USAGE_STATS_ENABLED", "0")  # no reports to Ray's servers
            self._one_machine()
            if temp_dir is None:
                # short: Ray's Unix socket paths live under it (a 107-byte limit)
                temp_dir = self._own_temp = tempfile.mkdtemp(prefix="m4ray-")
            kw = dict(
                # a new cluster even where `ray start` left one on this machine (ray.init()
                # would join that one)
                address="local",
                include_dashboard=bool(dashboard),
                _node_ip_address="127.0.0.1",
                _temp_dir=str(Path(temp_dir).resolve()),
                num_cpus=num_cpus,
                log_to_driver=False,
                configure_logging=False,
            )
            if object_store_mb:
                kw["object_store_memory"] = int(object_store_mb) * 1024 * 1024
            if dashboard:
                kw["dashboard_host"] = "127.0.0.1"
            with _quiet_ray_tip():
                ray.init(**kw)
        else:
            with _quiet_ray_tip():
                ray.init(address=address, log_to_driver=False, configure_logging=False)
        return ray

    def _one_machine(self) -> None:
        """Keep the cluster's node address at 127.0.0.1. Ray swaps a node address of 127.0.0.1
        for the machine's reachable one (its servers then listen there and on every interface)
        unless its multi-machine switch is off (its default on macOS and Windows): off here, in
        this process (Ray read it when imported) and in the processes the cluster starts (they
        read it from the environment), until the executor closes. A Ray without these names (a
        private module) gets the environment variable alone."""
        self._set_env("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
        try:
            from ray._private import ray_constants

            self._cluster_switch = bool(ray_constants.ENABLE_RAY_CLUSTER)
        except (ImportError, AttributeError):
            return
        ray_constants.ENABLE_RAY_CLUSTER = False

    def _restore(self) -> None:
        """The environment variables this executor set back as they were, and Ray's multi-machine
        switch; its own temp dir gone."""
        if self._cluster_switch is not None:
            from ray._private import ray_constants

            ray_constants.ENABLE_RAY_CLUSTER = self._cluster_switch
            self._cluster_switch = None
        for k, v in self._env_before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        if self._env_before:
            _reload_ray_auth()
        self._env_before = {}
        if self._own_temp is not None:
            import shutil

            shutil.rmtree(self._own_temp, ignore_errors=True)
            self._own_temp = None

    def _set_env(self, key: str, value: str) -> None:
        self._env_before.setdefault(key, os.environ.get(key))
        os.environ[key] = value

    def node_resources(self) -> List[Dict[str, float]]:
        return [n.get("Resources", {}) for n in self._ray.nodes() if n.get("Alive")]

    @property
    def slots(self) -> int:
        """How many jobs fit on the cluster at once (the progress line's bound on "running")."""
        n = 0
        for r in self.node_resources():
            fit = int(r.get("CPU", 0) // self.threads)
            if self.gpus:
                fit = min(fit, int(r.get("GPU", 0) // self.gpus))
            n += fit
        return max(1, n)

    def check_fits(self, threads: int, gpus: int) -> None:
        """Raise InputError naming the option when no alive node has `threads` CPUs and `gpus` GPUs
        (Ray would wait for such a node for ever)."""
        nodes = self.node_resources()
        if any(r.get("CPU", 0) >= threads and r.get("GPU", 0) >= gpus for r in nodes):
            return
        cpu = max((r.get("CPU", 0) for r in nodes), default=0)
        gpu = max((r.get("GPU", 0) for r in nodes), default=0)
        raise InputError(
            f"no node of the Ray cluster has {threads} CPU(s) and {gpus} GPU(s) for one job "
            f"(the largest has {cpu:g} CPU(s), {gpu:g} GPU(s)): lower --cpus-per-job or "
            "--gpus-per-job, or add such a node"
        )

    def map(self, tasks, on_start=None):
        ray = self._ray
        for need in {(max(1, t.threads or 1), t.gpus) for t in tasks}:
            self.check_fits(*need)
        refs = {}
        for t in tasks:
            threads = max(1, t.threads or 1)
            ref = self._remote.options(
                num_cpus=threads,
                num_gpus=t.gpus,
                max_retries=self.max_retries,
                retry_exceptions=False,
                name=t.name,
            ).remote(t.fn, t.args, t.kwargs, threads, self.device)
            refs[ref] = t
            if on_start is not None:
                on_start(t)
        self._pending = list(refs)
        while self._pending:
            done, self._pending = ray.wait(self._pending, num_returns=1)
            for ref in done:
                t = refs[ref]
                try:
                    env = ray.get(ref)
                except Exception as exc:  # the worker died more than max_retries times, ...
                    line = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
                    yield Outcome(t, error=RemoteError(f"{type(exc).__name__}: {line}"))
                    continue
                yield _unwrap(t, env)

    def close(self) -> None:
        ray = self._ray
        for ref in self._pending:  # fail fast / Ctrl-C: what has not finished
            try:
                ray.cancel(ref, force=True)
            except Exception:  # already finished or gone
                pass
        self._pending = []
        ray.shutdown()
        self._restore()


class SlurmExecutor(Executor):
    """The tasks of each map() call as Slurm job arrays through submitit (one array per distinct
    (threads, GPUs) need), each array task running one task; logs and submitit's pickles under
    `folder`. partition, time_min (minutes per task), array_parallelism (at most that many array
    tasks at once), and `cluster`: None lets submitit pick (Slurm where sbatch exists), "local" runs
    the tasks as local processes (tests), "slurm" insists on Slurm."""

    name = "slurm"

    def __init__(
        self,
        folder,
        device: str = "auto",
        threads: int = DEFAULT_CPUS_PER_JOB,
        gpus: int = 0,
        partition: Optional[str] = None,
        time_min: int = 240,
        array_parallelism: Optional[int] = None,
        cluster: Optional[str] = None,
        poll_s: float = 5.0,
    ):
        submitit = _need("submitit", "slurm")
        self._submitit = submitit
        self.folder = Path(folder)
        self.device = device
        self.threads, self.gpus = _job_resources(threads, gpus)
        self.partition = partition
        self.time_min = int(time_min)
        self.array_parallelism = array_parallelism
        self.cluster = cluster
        self.poll_s = float(poll_s)
        try:
            self._ex = submitit.AutoExecutor(folder=str(self.folder / "%j"), cluster=cluster)
        except RuntimeError as e:  # submitit: no srun / sbatch here
            raise InputError(
                f"--executor slurm: {e} Run the command where Slurm's commands work (a login "
                "node), or use --executor local or ray"
            ) from None
        if self._ex.cluster == "debug":
            raise InputError("--executor slurm: submitit's debug cluster runs nothing in parallel")
        self._pending: List[Any] = []

    @property
    def slots(self) -> int:
        # every submitted array task counts as running (queued ones too), unless capped
        return int(self.array_parallelism or 0) or 10**9

    def map(self, tasks, on_start=None):
        groups: Dict[tuple, List[Task]] = {}
        for t in tasks:
            groups.setdefault((max(1, t.threads or 1), t.gpus), []).append(t)
        jobs = {}
        for (threads, gpus), ts in groups.items():
            params = dict(
                timeout_min=self.time_min,
                cpus_per_task=threads,
                gpus_per_node=gpus,
                nodes=1,
                tasks_per_node=1,
                name="m4dgs",
            )
            if self.partition:
                params["slurm_partition"] = self.partition
            if self.array_parallelism:
                params["slurm_array_parallelism"] = int(self.array_parallelism)
            self._ex.update_parameters(**params)
            submitted = self._ex.map_array(
                run_task,
                [t.fn for t in ts],
                [t.args for t in ts],
                [t.kwargs for t in ts],
                [threads] * len(ts),
                [self.device] * len(ts),
            )
            for j, t in zip(submitted, ts):
                jobs[j] = t
                if on_start is not None:
                    on_start(t)
        self._pending = list(jobs)
        while self._pending:
            still = []
            for j in self._pending:
                if not j.done():
                    still.append(j)
                    continue
                t = jobs[j]
                try:
                    env = j.result()
                except Exception as exc:  # killed, timed out, node failure ...
                    line = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
                    logs = f"logs: {j.paths.stdout}, {j.paths.stderr}"
                    yield Outcome(t, error=RemoteError(f"{type(exc).__name__}: {line} ({logs})"))
                    continue
                yield _unwrap(t, env)
            self._pending = still
            if still:
                time.sleep(self.poll_s)

    def close(self) -> None:
        for j in self._pending:
            try:
                j.cancel(check=False)
            except Exception:
                pass
        self._pending = []


def make_executor(
    kind: str = "local",
    *,
    jobs: int = 1,
    device: str = "auto",
    cpus_per_job: Optional[int] = None,
    gpus_per_job: Optional[int] = None,
    address: Optional[str] = None,
    max_retries: int = 3,
    dashboard: bool = False,
    ray_temp_dir: Optional[str] = None,
    slurm_folder: Optional[str] = None,
    slurm_partition: Optional[str] = None,
    slurm_time: Optional[int] = None,
    slurm_array_parallelism: Optional[int] = None,
    slurm_cluster: str = "slurm",
) -> Executor:
    """The executor the command-line options describe; raises InputError naming an option that
    does not apply to `kind` (e.g. --address without --executor ray)."""
    if kind not in EXECUTORS:
        raise InputError(f"--executor {kind!r}: expected one of {', '.join(EXECUTORS)}")
    misplaced = []
    if kind != "ray":
        misplaced += [
            o
            for o, v in (
                ("--address", address),
                ("--ray-dashboard", dashboard),
                ("--ray-temp-dir", ray_temp_dir),
            )
            if v
        ]
    if kind != "slurm":
        misplaced += [
            o
            for o, v in (
                ("--slurm-folder", slurm_folder),
                ("--slurm-partition", slurm_partition),
                ("--slurm-time", slurm_time),
                ("--slurm-array-parallelism", slurm_array_parallelism),
            )
            if v
        ]
    if misplaced:
        raise InputError(
            f"{', '.join(misplaced)} appl{'ies' if len(misplaced) == 1 else 'y'} only to "
            f"--executor {'ray' if misplaced[0].startswith(('--address', '--ray')) else 'slurm'} "
            f"(this is --executor {kind}): drop them or choose that executor"
        )
    if kind != "local" and jobs != 1:
        raise InputError(
            f"--jobs {jobs} sets the local executor's worker processes; with --executor {kind} "
            "the cluster runs as many jobs at once as its CPUs allow (--cpus-per-job each"
            + (", --slurm-array-parallelism caps them" if kind == "slurm" else "")
            + "): drop --jobs"
        )
    if kind == "local":
        if gpus_per_job:
            raise InputError(
                "--gpus-per-job applies to --executor ray and slurm; local workers share the "
                "machine's GPUs (--device cuda)"
            )
        return LocalExecutor(jobs, cpus_per_job, device)
    threads = cpus_per_job or DEFAULT_CPUS_PER_JOB
    gpus = (1 if device == "cuda" else 0) if gpus_per_job is None else gpus_per_job
    if kind == "ray":
        return RayExecutor(
            address,
            device=device,
            threads=threads,
            gpus=gpus,
            max_retries=max_retries,
            dashboard=dashboard,
            temp_dir=ray_temp_dir,
        )
    if not slurm_folder:
        raise InputError(
            "--executor slurm needs --slurm-folder DIR: a folder every node sees, for the array "
            "tasks' logs and submitit's files"
        )
    return SlurmExecutor(
        slurm_folder,
        device=device,
        threads=threads,
        gpus=gpus,
        partition=slurm_partition,
        time_min=slurm_time or 240,
        array_parallelism=slurm_array_parallelism,
        cluster=slurm_cluster,
    )


class Progress:
    """The driver's progress line: done, running, failed, and an ETA from the pace so far (elapsed
    time / finished tasks x tasks left: the tasks run `slots` at a time, so the pace includes
    that)."""

    def __init__(self, total: int, slots: int, what: str = "jobs", clock=time.monotonic):
        self.total, self.slots, self.what = int(total), max(1, int(slots)), what
        self.done = self.failed = 0
        self.clock = clock
        self.t0 = clock()

    def add(self, ok: bool) -> None:
        if ok:
            self.done += 1
        else:
            self.failed += 1

    def line(self) -> str:
        finished = self.done + self.failed
        left = self.total - finished
        running = min(left, self.slots)
        eta = "?"
        if finished and left:
            eta = _duration((self.clock() - self.t0) / finished * left)
        elif not left:
            eta = "0 s"
        return (
            f"{finished}/{self.total} {self.what}: {self.done} done, {running} running, "
            f"{self.failed} failed, ETA {eta}"
        )


def _duration(s: float) -> str:
    if s < 90:
        return f"{s:.0f} s"
    if s < 90 * 60:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


def default_log(msg: str) -> None:
    print(msg, file=sys.stderr)
