"""Run an experiment suite: make missing clips, train missing runs, score missing metrics
(resumable).

The job list of a suite is (clip setting, scene, row) (eval.records.suite), times the trainer seeds
of `seeds` (0 .. N-1, or a list such as [2, 3]; the clip is the same for every seed). Seed 0
trains into OUT/runs/<suite>/<scene>/<row> with the row's config as it is, seed n > 0 into
OUT/runs/<suite>/<scene>/<row>-seed-<n> with the override `seed` = the row's seed + n. `run_suite`
works through it on an executor (m4dgs.core.executors): locally, with a process pool for
`jobs > 1`, or on a Ray cluster or Slurm; `job_list` / `run_job` are the same work one job at a
time (`m4dgs-eval run SUITE --list-jobs` prints one JSON line per job with its `python -m eval job
...` command line, for other schedulers; docs/cluster.md).

Concurrency: making a clip and training a run each hold an exclusive `fcntl.flock` on a lock file
beside the folder (`<folder>.lock`), so two workers given the same clip or run wait for each other
instead of writing the same files (the second one then finds the work done). Locks need a file
system with working flock (local disks, most NFS v4 set-ups).

Shared phases: the runs of one clip share camera initialisation, stage 1, the V2W transform and
stage 2 wherever their configurations agree on everything that phase reads (stage 2: the whole
configuration and the variant, so a row that two suites both have is trained once;
m4dgs.training.phases), through OUT/.shared (`share=False` / `--no-share` turns it off). Trainer
seeds are never shared.

Failures: by default a job that fails (bad input, a diverged run, a bug) is reported and the suite
goes on with the other jobs; the jobs of a clip that could not be made are skipped. `run_suite`
returns every job's result, the failed ones with an "error" entry, and `m4dgs-eval run` exits with
status 1 naming them after the last job. `fail_fast=True` (`--fail-fast`) stops at the first
failure instead. A job that fails while training or scoring leaves `<run>/failure.json` (its
one-line error and when), which `m4dgs-eval export` turns into a row with status "failed" and the
results page lists; a later attempt of the job (a suite or campaign run again retries it) removes
the file when it scores."""

from __future__ import annotations

import json
import numbers
import re
import shlex
import sys
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

from benchgen.exposure import ExposureSettings
from benchgen.suite import load_suite
from eval.calibration import SEED_FREE_ROWS
from eval.records.suite import (
    EvalSuite,
    is_builtin_suite_file,
    load_eval_suite,
    scene_suite_names,
)
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError, M4DGSError
from m4dgs.core.executors import error_line
from m4dgs.core.lock import file_lock

PRESETS = ("tiny", "small", "paper")
SHARE_DIR = ".shared"  # under OUT: trainer phases shared between runs (m4dgs.training.phases)


SEED_SUFFIX = "-seed-"
FAILURE_FILE = "failure.json"  # in a run folder: the last attempt of its job failed


def record_failure(run_dir, error: str) -> None:
    """Write <run_dir>/failure.json {"error", "time"} (atomic) when the run folder exists."""
    d = Path(run_dir)
    if d.is_dir():
        stamp = time.strftime("%Y-%m-%dT%H:%M:%S")
        mio.write_json(d / FAILURE_FILE, {"error": error, "time": stamp})


def read_failure(run_dir) -> Optional[str]:
    """The recorded error of a run folder's last failed attempt, or None."""
    p = Path(run_dir) / FAILURE_FILE
    if not p.exists():
        return None
    try:
        return str(mio.read_json(p).get("error") or "failed (no message recorded)")
    except (OSError, M4DGSError):
        return "failed (unreadable failure.json)"


def seed_run_name(row: str, seed: int) -> str:
    """Run folder name of a row's trainer seed: the row name for seed 0 (the layout before seeds
    existed), else `<row>-seed-<seed>`."""
    return row if seed == 0 else f"{row}{SEED_SUFFIX}{seed}"


_SEED_NAME_RE = re.compile(re.escape(SEED_SUFFIX) + r"([0-9]+)$")


def split_run_name(name: str) -> Tuple[str, int]:
    """(row, trainer seed) of a run folder name, the inverse of seed_run_name: `<row>-seed-<n>` is
    seed n of <row>, any other name is seed 0 of the row of that name."""
    m = _SEED_NAME_RE.search(name)
    return (name[: m.start()], int(m.group(1))) if m else (name, 0)


@dataclass
class Job:
    """One (clip setting, scene, row, trainer seed) of a suite, with its folders and the command
    that runs it."""

    suite: str  # suite name or path, as given to `eval`
    suite_name: str
    setting: str  # clip setting key
    setting_id: str  # folder name under OUT/clips
    scene: str
    row: str
    label: str
    variant: str
    overrides: Dict
    clip_dir: str
    run_dir: str
    preset: str
    out: str
    seed: int = (
        0  # trainer seed index (0: the row as it is; n > 0: overrides["seed"] = row seed + n)
    )
    # a calibration row (eval.calibration.ROWS): predicted and scored, not trained
    # (eval.experiments.calibration_rows); its seed reaches dibr's camera initialisation
    calibration: Optional[str] = None

    @property
    def id(self) -> str:
        return f"{self.suite_name}/{self.scene}/{seed_run_name(self.row, self.seed)}"

    @property
    def clip_key(self) -> str:
        return f"{self.setting_id}/{self.scene}"

    @property
    def share_dir(self) -> str:
        return str(Path(self.out) / SHARE_DIR)

    def command(
        self, lpips_weights: Optional[str] = None, device: Optional[str] = None, share: bool = True
    ) -> List[str]:
        cmd = [
            "python",
            "-m",
            "eval",
            "job",
            self.suite,
            "--root",
            self.out,
            "--preset",
            self.preset,
            "--scene",
            self.scene,
            "--row",
            self.row,
        ]
        if self.seed:
            cmd += ["--seed", str(self.seed)]
        if lpips_weights:
            cmd += ["--lpips-weights", str(lpips_weights)]
        if device:
            cmd += ["--device", device]
        if not share:
            cmd += ["--no-share"]
        return cmd

    def to_json(self, **cmd_kw) -> dict:
        d = asdict(self)
        d["id"], d["clip_key"] = self.id, self.clip_key
        d["cmd"] = shlex.join(self.command(**cmd_kw))
        return d


def _suite_ref(suite) -> tuple:
    """(EvalSuite, the reference to put on job command lines: the built-in name, or the file's
    absolute path)."""
    s = suite if isinstance(suite, EvalSuite) else load_eval_suite(suite)
    builtin = is_builtin_suite_file(s.path)
    return s, (s.name if builtin else str(s.path.resolve()))


def job_list(
    suite,
    out,
    preset: str = "small",
    scenes: Optional[Sequence[str]] = None,
    seeds: Union[int, Sequence[int]] = 1,
    rows: Optional[Sequence[str]] = None,
) -> List[Job]:
    """Every job of a suite for the trainer seeds `seeds` (seed_list: N for 0 .. N-1, or a list
    such as [2, 3] for seeds no earlier run used): seed by seed, each ordered by clip setting,
    scene, row (seeds=1 is the job list before seeds existed). scenes / rows: only these scenes /
    rows of the suite (a name it lacks is a ValueError)."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r} (known: {PRESETS})")
    seed_ids = seed_list(seeds)
    s, ref = _suite_ref(suite)
    out = Path(out).resolve()
    names = scene_suite_names(s)
    if scenes is not None:
        unknown = sorted(set(scenes) - set(names))
        if unknown:
            raise InputError(f"suite {s.name!r} has no scene(s) {unknown} (it has {names})")
        names = [n for n in names if n in scenes]
    if rows is not None:
        unknown = sorted(set(rows) - {r.name for r in s.rows})
        if unknown:
            raise InputError(
                f"suite {s.name!r} has no row(s) {unknown} (it has {[r.name for r in s.rows]})"
            )
    jobs = []
    for seed in seed_ids:
        for key, setting in s.clips.items():
            sid = setting.setting_id(s.scenes)
            for scene in names:
                for r in s.rows:
                    if r.clip != key or (rows is not None and r.name not in rows):
                        continue
                    ov = dict(r.overrides)
                    if seed:
                        ov["seed"] = int(ov.get("seed", 0)) + seed
                    jobs.append(
                        Job(
                            ref,
                            s.name,
                            key,
                            sid,
                            scene,
                            r.name,
                            r.label,
                            r.variant,
                            ov,
                            str(
                                s.clip_folder / scene
                                if s.clip_folder is not None
                                else out / "clips" / sid / scene
                            ),
                            str(out / "runs" / s.name / scene / seed_run_name(r.name, seed)),
                            preset,
                            str(out),
                            seed,
                            r.calibration,
                        )
                    )
    return jobs


def seed_list(seeds: Union[int, Sequence[int]]) -> List[int]:
    """The trainer seeds of `seeds`: an integer N >= 1 is 0 .. N-1; a non-empty sequence of distinct
    integers >= 0 is those, in increasing order. Anything else is a ValueError."""
    if isinstance(seeds, bool):
        raise ValueError(f"seeds must be an integer >= 1 or a list of seeds, got {seeds!r}")
    if isinstance(seeds, numbers.Integral):
        if int(seeds) < 1:
            raise ValueError(f"seeds must be >= 1, got {seeds!r}")
        return list(range(int(seeds)))
    out = list(seeds) if isinstance(seeds, (list, tuple, range)) else None
    if (
        not out
        or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in out)
        or min(out) < 0
        or len(set(out)) != len(out)
    ):
        raise ValueError(
            f"seeds must be an integer >= 1 or a non-empty list of distinct seeds >= 0, "
            f"got {seeds!r}"
        )
    return sorted(int(v) for v in out)


def folder_lock(folder: Path):
    """Exclusive flock on <folder>.lock (beside the folder) for the duration of the block."""
    folder = Path(folder)
    return file_lock(folder.parent / f".{folder.name}.lock")


def clip_waves(todo: Sequence[Job]) -> List[List[Job]]:
    """The clips to make in two waves for a process pool: the first missing clip of each scene,
    then the scene's other clips, which can take the first one's render (benchgen.make.make_clip,
    render_from) instead of rendering the same frames in parallel."""
    seen, first, rest = set(), [], []
    for j in todo:
        (rest if j.scene in seen else first).append(j)
        seen.add(j.scene)
    return [w for w in (first, rest) if w]


def make_job_clip(job: Job, progress: bool = False) -> Path:
    """Make the job's clip when clip.json is missing (benchgen.make.make_clip; resumes an unfinished
    one)."""
    clip_dir = Path(job.clip_dir)
    if (clip_dir / "clip.json").exists():
        return clip_dir
    s = load_eval_suite(job.suite)
    if s.clip_folder is not None:
        raise InputError(f"{clip_dir}: no clip.json (the suite's scenes are existing clips)")
    # deferred: benchgen.make loads the renderer stack (~2 s), needed only when a clip is missing
    from benchgen.make import make_clip, sibling_clips

    setting = s.clips[job.setting]
    bs = load_suite(s.scenes)
    scene_path = {p.stem: p for p in bs.scenes}[job.scene]
    ex = ExposureSettings(
        setting.observed if setting.observed is not None else tuple(bs.observed),
        setting.novel if setting.novel is not None else tuple(bs.novel),
        setting.schedule or bs.schedule,
    )
    with folder_lock(clip_dir):
        if not (clip_dir / "clip.json").exists():
            make_clip(
                scene_path,
                clip_dir,
                preset=job.preset,
                settings=ex,
                priors=setting.priors,
                seed=setting.seed,
                crf=setting.crf or "hdrnerf",
                progress=progress,
                allow_misplaced=bs.placement == "warn",
                # the other settings' clips of this scene (ROOT/clips/<setting>/<scene>): a clip
                # that differs only after the render (response, exposures, priors) takes theirs
                render_from=sibling_clips(clip_dir.parent.parent, job.scene),
            )
    return clip_dir


def train_job(job: Job, device: str = "auto", progress: bool = False, share: bool = True) -> Path:
    """Train the job's run (m4dgs.training.pipeline.train resumes an interrupted run and returns at
    once when done); share: phases shared through OUT/.shared."""
    # the trainer's entry point, imported when called (tests replace it in sys.modules)
    from m4dgs.training.pipeline import train

    run_dir = Path(job.run_dir)
    with folder_lock(run_dir):
        return Path(
            train(
                job.clip_dir,
                run_dir,
                preset=job.preset,
                variant=job.variant,
                overrides=dict(job.overrides) or None,
                device=device,
                progress=progress,
                **({"share_dir": job.share_dir} if share else {}),
            )
        )


def run_job(
    job: Job,
    *,
    force: bool = False,
    lpips_weights=None,
    device: str = "auto",
    clip_only: bool = False,
    progress: bool = False,
    score_kw: Optional[dict] = None,
    share: bool = True,
) -> dict:
    """Make the clip, train and score ONE job; each step is skipped when its output exists.

    force: recompute metrics.json even if it exists (never retrains: delete the run folder for
    that). share: share trainer phases with the clip's other runs through OUT/.shared. Returns
    {"id", "clip", "run", "metrics" (path or None), "seconds", "steps": [what was done]}."""
    t0 = time.perf_counter()
    steps = []
    if not (Path(job.clip_dir) / "clip.json").exists():
        make_job_clip(job, progress=progress)
        steps.append("clip")
    res = {"id": job.id, "clip": job.clip_dir, "run": job.run_dir, "metrics": None}
    if clip_only:
        res.update(seconds=round(time.perf_counter() - t0, 2), steps=steps)
        return res
    run_dir = Path(job.run_dir)
    if job.calibration is not None:
        return _run_calibration_job(job, res, steps, t0, force, lpips_weights, share)
    status = run_dir / "status.json"
    what = "training"
    try:
        if not (status.exists() and mio.read_json(status).get("stage") == "done"):
            train_job(job, device=device, progress=progress, share=share)
            steps.append("train")
        mpath = run_dir / "metrics.json"
        if force or not mpath.exists():
            from eval.experiments.score import (
                score_run,  # deferred: scoring loads torch and the metrics (~1.5 s)
            )

            what = "scoring"
            score_run(
                run_dir,
                clip=job.clip_dir,
                lpips_weights=lpips_weights,
                device=device,
                **(score_kw or {}),
            )
            steps.append("score")
    except Exception as exc:  # recorded for the CSV and the results page, then raised as before
        record_failure(run_dir, f"{what}: {error_line(exc)}")
        raise
    (run_dir / FAILURE_FILE).unlink(missing_ok=True)  # an earlier attempt's record
    res.update(metrics=str(mpath), seconds=round(time.perf_counter() - t0, 2), steps=steps)
    return res


def _run_calibration_job(job: Job, res, steps, t0, force, lpips_weights, share) -> dict:
    """run_job for a calibration row: predict and score (eval.experiments.calibration_rows) unless
    metrics.json exists (or force); another seed of a seed-free row (copy-nearest, flow-merge)
    copies seed 0's finished run instead (calibration_rows.copy_seed_free_run)."""
    run_dir = Path(job.run_dir)
    mpath = run_dir / "metrics.json"
    # a seed-free row's other seeds take seed 0's run (the same frames, the same scores)
    first = run_dir.parent / seed_run_name(job.row, 0)
    try:
        if (
            not force
            and not mpath.exists()
            and job.seed > 0
            and job.calibration in SEED_FREE_ROWS
            and (first / "metrics.json").exists()
        ):
            from eval.experiments.calibration_rows import copy_seed_free_run

            copy_seed_free_run(first, run_dir)
            steps.append("copy")
        elif force or not mpath.exists():
            from eval.experiments.calibration_rows import make_calibration_run

            make_calibration_run(
                job.calibration,
                job.row,
                job.clip_dir,
                run_dir,
                preset=job.preset,
                overrides=job.overrides,
                share_dir=job.share_dir if share else None,
                lpips_weights=lpips_weights,
            )
            steps.append("predict")
            steps.append("score")
    except Exception as exc:
        record_failure(run_dir, f"calibration row {job.calibration}: {error_line(exc)}")
        raise
    (run_dir / FAILURE_FILE).unlink(missing_ok=True)
    res.update(metrics=str(mpath), seconds=round(time.perf_counter() - t0, 2), steps=steps)
    return res


def _run_job_kw(job: Job, kw: dict) -> dict:
    return run_job(job, **kw)


def _failure(job: "Job", exc: BaseException, what: str) -> dict:
    """The result entry of a failed job: its id, folders and a one-line error (with the type of an
    unexpected exception, whose traceback the caller logs)."""
    msg = error_line(exc)
    return {
        "id": job.id,
        "clip": job.clip_dir,
        "run": job.run_dir,
        "metrics": None,
        "steps": [],
        "error": f"{what}: {msg}",
    }


def failed_jobs(results: Sequence[dict]) -> List[dict]:
    """The results of `run_suite` that failed (those with an "error" entry)."""
    return [r for r in results if r.get("error")]


def run_suite(
    suite,
    out,
    preset: str = "small",
    jobs: int = 1,
    scenes: Optional[Sequence[str]] = None,
    force: bool = False,
    *,
    lpips_weights=None,
    device: str = "auto",
    progress: bool = True,
    clips_only: bool = False,
    score_kw: Optional[dict] = None,
    log=None,
    seeds: int = 1,
    share: bool = True,
    fail_fast: bool = False,
    skip: Optional[Callable[[Job], bool]] = None,
    on_result: Optional[Callable[[Job, dict], None]] = None,
    retry_failed: bool = True,
    executor=None,
    rows: Optional[Sequence[str]] = None,
) -> List[dict]:
    """Make every missing clip, then train and score every (scene, row, seed) of a suite; resumable.

    skip(job) true: the job is recorded elsewhere (eval.experiments.campaign: scored in the runs
    CSV), so it is neither trained nor scored and its clip is made only if another job needs it; its
    result is {"id", "run", "steps": [], "recorded": True}. on_result(job, result) is called in this
    process after each job that finished (not after failed or skipped ones), e.g. to export it at
    once. retry_failed False: a job whose last attempt failed (<run>/failure.json) is not run again
    (a failure that repeats is a result of its configuration); its result is {"id", "run", "steps":
    [], "failed_before": the recorded error}, which failed_jobs does not count.

    jobs > 1: clips are made first (one process per distinct clip), then the runs in a process pool
    of `jobs` workers, each spending cpu_count / jobs threads as m4dgs.core.threads.use_threads
    does (torch 1, the compiled kernels all of them); jobs = 1 spends every CPU that way in this
    process while it trains. executor: where the clips and jobs run instead (an open
    m4dgs.core.executors.Executor, e.g. Ray or Slurm; `jobs` is then unused, and the caller
    closes it); outside this process the driver prints a progress line after each job. rows: only
    these rows (e.g. the full method and the calibration rows first, the rest later). Returns
    the per-job results (run_job) in job order; a job that failed has an "error" entry instead of
    metrics (and the jobs of a clip that failed to be made are not started), unless fail_fast,
    which raises the first failure."""
    every = job_list(suite, out, preset, scenes, seeds, rows)
    recorded = {j.id for j in every if skip is not None and skip(j)}
    kept: Dict[str, str] = {}  # job id -> error of its last attempt, not retried
    if not retry_failed:
        for j in every:
            err = None if j.id in recorded else read_failure(j.run_dir)
            if err is not None:
                kept[j.id] = err
    jl = [j for j in every if j.id not in recorded and j.id not in kept]
    say = log or (lambda msg: print(msg, file=sys.stderr))
    if recorded:
        say(f"[eval run] {len(recorded)} of {len(every)} jobs are recorded already: not run")
    if kept:
        say(
            f"[eval run] {len(kept)} of {len(every)} jobs failed at their last attempt: not "
            "retried (" + ", ".join(sorted(kept)[:3]) + (", ..." if len(kept) > 3 else "") + ")"
        )
    firsts: Dict[str, Job] = {}
    for j in jl:
        firsts.setdefault(j.clip_key, j)
    todo = [j for j in firsts.values() if not (Path(j.clip_dir) / "clip.json").exists()]
    say(
        f"[eval run] {len(jl)} jobs, {len(firsts)} clips ({len(todo)} to make), preset {preset}, "
        f"jobs {jobs}, "
        f"seeds {seeds}"
    )
    kw = dict(
        force=force, lpips_weights=lpips_weights, device=device, score_kw=score_kw, share=share
    )
    clip_errors: Dict[str, dict] = {}  # clip_key -> failure of making that clip

    def failed(job: Job, exc: BaseException, what: str, name: str) -> dict:
        if fail_fast:
            raise exc
        r = _failure(job, exc, what)
        say(f"[eval run] FAILED {name}: {r['error']}")
        if not isinstance(exc, M4DGSError):
            say("".join(traceback.format_exception(type(exc), exc, exc.__traceback__)).rstrip())
        elif getattr(exc, "remote_traceback", None):  # a worker's (m4dgs.core.executors)
            say(exc.remote_traceback.rstrip())
        return r

    def finished(job: Job, r: dict) -> dict:
        if on_result is not None:
            on_result(job, r)
        return r

    def in_order(results: List[dict]) -> List[dict]:
        by_id = {r["id"]: r for r in results}
        by_id.update(
            {
                j.id: {"id": j.id, "run": j.run_dir, "steps": [], "failed_before": kept[j.id]}
                for j in every
                if j.id in kept
            }
        )
        return [
            {"id": j.id, "run": j.run_dir, "steps": [], "recorded": True}
            if j.id in recorded
            else by_id[j.id]
            for j in every
        ]

    def skipped(job: Job) -> dict:
        r = dict(clip_errors[job.clip_key], id=job.id, run=job.run_dir)
        say(f"[eval run] skipped {job.id}: its clip {job.clip_key} could not be made")
        return r

    from m4dgs.core.executors import LocalExecutor

    own = executor is None
    ex = LocalExecutor(jobs, device=device) if own else executor
    try:
        res = _execute(
            ex, jl, todo, kw, progress, clip_errors, failed, finished, skipped, say, clips_only
        )
        return res if clips_only else in_order(res)
    finally:
        if own:
            ex.close()  # fail fast / Ctrl-C: nothing more starts


def _execute(ex, jl, todo, kw, progress, clip_errors, failed, finished, skipped, say, clips_only):
    """run_suite's work on an executor (m4dgs.core.executors): the missing clips (in this
    process one after another; elsewhere wave by wave, clip_waves), then the jobs, each result
    handed on as it finishes. Returns the clip list when clips_only, else the job results."""
    from m4dgs.core.executors import Progress, Task

    inline = ex.inline  # this process: progress bars, and a job counter before each job
    for wave in [todo] if inline else clip_waves(todo):
        tasks = [
            # in this process a clip is made with the threads the process has (as before jobs)
            Task(
                f"clip {j.clip_key}",
                make_job_clip,
                (j, progress and inline),
                {},
                None if inline else ex.threads,
                0,
            )
            for j in wave
        ]
        for o in ex.map(
            tasks, on_start=(lambda t: say(f"[eval run] {t.name}")) if inline else None
        ):
            if o.error is not None:
                j = o.task.args[0]
                clip_errors[j.clip_key] = failed(
                    j, o.error, "making the clip", f"clip {j.clip_key}"
                )
    if clips_only:
        return [{"id": j.id, "clip": j.clip_dir} for j in jl]
    results = [skipped(j) for j in jl if j.clip_key in clip_errors]
    number = {j.id: i + 1 for i, j in enumerate(jl)}
    tasks = [
        Task(
            j.id, _run_job_kw, (j, dict(kw, progress=progress and inline)), {}, ex.threads, ex.gpus
        )
        for j in jl
        if j.clip_key not in clip_errors
    ]
    bar = Progress(len(tasks), ex.slots)
    on_start = (
        (lambda t: say(f"[eval run] {number[t.name]}/{len(jl)} {t.name}")) if inline else None
    )
    for o in ex.map(tasks, on_start=on_start):  # as they finish: on_result exports each at once
        j = o.task.args[0]
        bar.add(o.error is None)
        if o.error is not None:
            results.append(failed(j, o.error, "the job", j.id))
        else:
            if not inline:
                steps = ", ".join(o.result["steps"]) or "nothing to do"
                say(f"[eval run] done {j.id} ({steps}, {o.result['seconds']} s)")
            results.append(finished(j, o.result))
        if not inline:
            say(f"[eval run] {bar.line()}")
    return results


def list_jobs_jsonl(
    suite,
    out,
    preset: str = "small",
    scenes=None,
    lpips_weights=None,
    device=None,
    seeds: int = 1,
    share: bool = True,
    rows=None,
) -> str:
    """The job list as JSON lines (one job per line, with its `python -m eval job ...` command)."""
    return "".join(
        json.dumps(j.to_json(lpips_weights=lpips_weights, device=device, share=share)) + "\n"
        for j in job_list(suite, out, preset, scenes, seeds, rows)
    )


def find_job(suite, out, preset: str, scene: str, row: str, seed: int = 0) -> Job:
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    for j in job_list(suite, out, preset, [scene], seed + 1):
        if j.row == row and j.seed == seed:
            return j
    s, _ = _suite_ref(suite)
    raise KeyError(f"suite {s.name!r} has no row {row!r} (rows: {[r.name for r in s.rows]})")


def seeds_present(suite, out, preset: str = "small", scenes=None) -> int:
    """1 + the largest trainer seed that has a run folder of this suite under OUT (1 when only seed
    0 exists)."""
    top = 0
    for j in job_list(suite, out, preset, scenes):
        parent = Path(j.run_dir).parent
        if not parent.is_dir():
            continue
        for p in parent.iterdir():
            row, seed = split_run_name(p.name)
            if row == j.row and p.is_dir():
                top = max(top, seed)
    return top + 1
