"""Campaigns: suites run one after another into one experiment root, each exported into the results
CSV as soon as it is done, so that what a session finished survives it (docs/eval.md,
"m4dgs-eval campaign").

A campaign file (eval/campaigns/<name>.yaml) names the preset, the trainer seeds, named scene sets
and the steps in order:

    name: results-small
    preset: small
    seeds: 2
    scene_sets: {TWO: [lamp-room-orbit, pendulum-lamp-handheld]}
    steps:
      - {suite: crf, scenes: TWO}
      - {suite: paper-main}               # every scene of the suite
      - {suite: priors, scenes: [a, b], seeds: 1}
      - {suite: confirm, seeds: [2, 3]}    # trainer seeds 2 and 3 only: seeds no earlier run used

Each step is `m4dgs-eval run SUITE --scenes ... --seeds ...` followed by `m4dgs-eval export`; a step
whose runs are all scored is only exported again. Each job is exported into the runs CSV as soon
as it is scored, and a job whose row the CSV holds as scored (same preset, clips of this benchgen
generator version) counts as finished even without its run folder: the CSV is the record that
survives a lost root, so a campaign restarted into a new root trains only what the CSV lacks.
Before a step trains anything, the m4dgs code of its finished runs (run.json `code`, or the CSV's
`code` column) is compared with this checkout's: a step is never finished with other code than it
was started with (its paired differences would compare code versions), unless allow_mixed_code.
A job that fails (a diverged run, a bug) does not hold the campaign up: its step is exported (the
run becomes a "failed" row with its error, eval.experiments.runner.record_failure), the later steps
run, and the campaign ends with an error naming every failed job; running it again retries them,
unless told not to (retry_failed False, `--no-retry-failed`: a failure that repeats is a result of
its configuration, and its row stays "failed")."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

import yaml

from eval.experiments.export import export
from eval.experiments.runner import failed_jobs, job_list, read_failure, run_suite, seed_list
from eval.records.runs_csv import read_runs_csv
from eval.records.suite import SuiteError, load_eval_suite, scene_suite_names
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError

CAMPAIGNS_DIR = Path(__file__).resolve().parents[1] / "campaigns"
_TOP_KEYS = {"name", "description", "preset", "seeds", "scene_sets", "steps"}
_STEP_KEYS = {"suite", "scenes", "seeds"}


class CampaignError(SuiteError):
    """A malformed campaign file; the message names the file and the field (path, key, problem)."""


@dataclass(frozen=True)
class Step:
    suite: str
    scenes: Optional[List[str]]  # None: every scene of the suite
    seeds: Union[int, Tuple[int, ...]]  # N: seeds 0 .. N-1; a tuple: those seeds


@dataclass(frozen=True)
class Campaign:
    name: str
    description: str
    preset: str
    steps: List[Step]
    path: Path


def builtin_campaigns() -> List[str]:
    return sorted(p.stem for p in CAMPAIGNS_DIR.glob("*.yaml"))


def load_campaign(name_or_path) -> Campaign:
    """Load a shipped campaign by name (eval/campaigns/<name>.yaml) or any campaign file by path;
    raises CampaignError naming the file and the field of what is wrong."""
    path = mio.find_file(name_or_path, CAMPAIGNS_DIR)
    if path is None:
        raise InputError(
            f"no campaign {name_or_path!r}: not a file, and not one of the shipped campaigns "
            f"({', '.join(builtin_campaigns()) or 'none'})"
        )
    return parse_campaign(mio.read_yaml(path), path)


def parse_campaign(d, path="<campaign>") -> Campaign:
    if not isinstance(d, dict):
        raise CampaignError(path, "<top level>", "expected a mapping")
    extra = set(d) - _TOP_KEYS
    if extra:
        raise CampaignError(path, sorted(extra)[0], f"unknown key (known: {sorted(_TOP_KEYS)})")
    preset = d.get("preset", "small")
    if preset not in ("tiny", "small", "paper"):
        raise CampaignError(path, "preset", f"{preset!r} is not tiny, small or paper")
    seeds = _seeds(d.get("seeds", 1), path, "seeds")
    sets = d.get("scene_sets") or {}
    if not isinstance(sets, dict) or not all(
        isinstance(v, list) and all(isinstance(s, str) for s in v) for v in sets.values()
    ):
        raise CampaignError(path, "scene_sets", "expected {NAME: [scene, ...]}")
    raw = d.get("steps")
    if not isinstance(raw, list) or not raw:
        raise CampaignError(path, "steps", "expected a non-empty list of {suite, scenes, seeds}")
    steps = []
    for i, st in enumerate(raw):
        key = f"steps[{i}]"
        if not isinstance(st, dict) or "suite" not in st:
            raise CampaignError(path, key, "expected a mapping with 'suite'")
        extra = set(st) - _STEP_KEYS
        if extra:
            raise CampaignError(path, f"{key}.{sorted(extra)[0]}", f"unknown key ({_STEP_KEYS})")
        try:
            suite = load_eval_suite(st["suite"])
        except InputError as e:
            raise CampaignError(path, f"{key}.suite", str(e)) from None
        scenes = st.get("scenes")
        if isinstance(scenes, str):
            if scenes not in sets:
                raise CampaignError(path, f"{key}.scenes", f"no scene set {scenes!r} in scene_sets")
            scenes = list(sets[scenes])
        if scenes is not None:
            known = scene_suite_names(suite)
            bad = [s for s in scenes if s not in known]
            if bad:
                raise CampaignError(
                    path, f"{key}.scenes", f"{bad} not in suite {suite.name!r}'s scenes {known}"
                )
        steps.append(Step(st["suite"], scenes, _seeds(st.get("seeds", seeds), path, key)))
    return Campaign(
        str(d.get("name") or Path(str(path)).stem),
        str(d.get("description") or ""),
        preset,
        steps,
        Path(str(path)),
    )


def _seeds(v, path, key) -> Union[int, Tuple[int, ...]]:
    try:
        seed_list(v)
    except ValueError:
        raise CampaignError(
            path,
            key,
            f"seeds must be an integer >= 1 (seeds 0 .. N-1) or a list of distinct seeds >= 0, "
            f"got {v!r}",
        ) from None
    return v if isinstance(v, int) else tuple(seed_list(v))


def seeds_text(seeds) -> str:
    """'2 seed(s)' for seeds 0 .. 1, 'seeds 2, 3' for a list."""
    if isinstance(seeds, int):
        return f"{seeds} seed(s)"
    return "seeds " + ", ".join(str(v) for v in seeds)


def job_iterations(job) -> int:
    """Optimisation iterations of a job (stage 1, when trained, + stage 2) under its resolved
    configuration: the unit of the campaign's time estimate."""
    _, s1, s2 = job_cost(job)
    return s1 + s2


def job_cost(job) -> Tuple[Optional[str], int, int]:
    """(stage-1 share key, stage-1 iterations, stage-2 iterations) of a job
    (m4dgs.training.variants.stage1_plan with the job's clip folder standing for the clip): the
    key groups the jobs whose stage 1 is one computation shared through ROOT/.shared; None for a
    variant without stage 1."""
    return job_plan(job)[:3]


def job_training_key(job) -> str:
    """The share key of a job's whole training (m4dgs.training.variants.training_key)."""
    return job_plan(job)[3]


def job_plan(job) -> Tuple[Optional[str], int, int, str]:
    """job_cost's three values and job_training_key, from one resolution of the job's
    configuration (m4dgs.training.variants.run_plan)."""
    if getattr(job, "calibration", None) is not None:
        return None, 0, 0, ""  # a calibration row trains nothing
    from m4dgs.training.variants import run_plan

    return run_plan(job.preset, job.variant, job.overrides, str(job.clip_dir))


def todo_iterations(statuses: Sequence[dict]) -> List[int]:
    """Per step (in campaign order), the iterations still to train, counting a stage 1 that rows
    share once: not at all when a finished job of the campaign has it (it is in the share
    folder), else for the first job that needs it; and a whole training that jobs of different
    suites share (the same clip, variant, overrides and seed: e.g. a control's row that repeats
    another suite's run) not at all when a finished run under ROOT has it, else once.

    `job_costs` entries: (finished, stage-1 key, stage-1 iterations, stage-2 iterations[,
    training key, finished with its run folder under ROOT]); without the last two a job shares
    only its stage 1, and a finished one counts as under ROOT."""
    have = {c[1] for s in statuses for c in s["job_costs"] if c[0] and c[1]}
    trained = {
        c[4] for s in statuses for c in s["job_costs"] if len(c) > 5 and c[4] and c[0] and c[5]
    }
    out = []
    for s in statuses:
        n = 0
        for c in s["job_costs"]:
            done, key, s1, s2 = c[:4]
            run_key = c[4] if len(c) > 4 else None
            if done:
                continue
            if run_key is not None:
                if run_key in trained:
                    continue
                trained.add(run_key)
            n += s2
            if key is None or key not in have:
                n += s1
                if key is not None:
                    have.add(key)
        out.append(n)
    return out


def recorded_runs(
    csv_path, preset: str, generator: Optional[str] = None, status: str = "scored"
) -> Dict[tuple, dict]:
    """{(suite, scene, row, seed): CSV row} of the runs CSV's runs of `status` ("scored", or
    "failed": the last attempt failed) at `preset` (and, when `generator` is given, not on clips
    of another benchgen generator version; a failed row without a preset counts at every preset):
    the record of finished (or failed) runs that survives the loss of their run folders (empty
    without a CSV)."""
    if csv_path is None:
        return {}
    out = {}
    for r in read_runs_csv(csv_path):
        if r.get("status") != status:
            continue
        # a failed row without a preset: exported before export read it from run.json, or the run
        # failed before run.json was written
        if r.get("preset") != preset and not (status == "failed" and not r.get("preset")):
            continue
        made_by = str(r.get("generator") or "")  # "" for clips benchgen did not make
        if generator is not None and made_by and made_by != str(generator):
            continue  # runs on clips of another generator version: another benchmark
        out[(r["suite"], r["scene"], r["row"], int(r["seed"]))] = r
    return out


def job_key(job) -> tuple:
    """A job's key in the runs CSV: (suite, scene, row, trainer seed)."""
    return (job.suite_name, job.scene, job.row, int(job.seed))


def step_status(
    step: Step,
    root,
    preset: str,
    recorded: Optional[Dict[tuple, dict]] = None,
    retry_failed: bool = True,
    recorded_failed: Optional[Dict[tuple, dict]] = None,
) -> dict:
    """{"total", "scored", "recorded", "failed", "codes", "todo_iterations", "sec_per_iteration",
    "job_costs"}: the step's jobs, how many are finished (metrics.json under ROOT, or, for a job
    without a run folder under ROOT, a scored row of `recorded`, the runs CSV: recorded_runs),
    how many of those only the CSV holds, how many unfinished ones failed at their last attempt
    (<run>/failure.json: eval.experiments.runner.record_failure, or, for a job without a run folder,
    a failed row of `recorded_failed`, the CSV's record of it), a Counter of the m4dgs code
    (run.json / CSV `code`, 12 hex digits) of the finished ones, the iterations of the jobs still to
    train, and the recorded training seconds per iteration of each finished run (run.json
    `train_seconds`, or the CSV's `train_minutes`: the method's cost, shared phases counted at their
    producer's time), and per job (finished, stage-1 share key, stage-1 iterations, stage-2
    iterations) for todo_iterations (todo_iterations here counts every job in full), with its
    whole-training share key and whether it finished with a run folder under ROOT. retry_failed
    False: a job whose last attempt failed will not run again, so it adds nothing to
    todo_iterations."""
    jl = job_list(step.suite, root, preset, step.scenes, step.seeds)
    recorded = recorded or {}
    recorded_failed = recorded_failed or {}

    def last_failed(j, run: Path) -> bool:
        if run.exists():
            return read_failure(run) is not None
        return job_key(j) in recorded_failed

    codes: Counter = Counter()
    scored, in_csv, failed, todo, rates, costs = 0, 0, 0, 0, [], []
    for j in jl:
        run = Path(j.run_dir)
        row = recorded.get(job_key(j))
        done = (row is not None and not run.exists()) or (run / "metrics.json").exists()
        key, s1, s2, tkey = job_plan(j)
        if not (done or retry_failed) and last_failed(j, run):
            failed += 1  # kept as it is: nothing to train, nothing shared
            continue
        costs.append((done, key, s1, s2, tkey, (run / "metrics.json").exists()))
        # a calibration row trains nothing: it has no m4dgs code to mix with the trained rows'
        trained = getattr(j, "calibration", None) is None
        if row is not None and not run.exists():  # a run folder, even unscored, wins
            scored += 1
            in_csv += 1
            if trained:
                codes[str(row.get("code") or "unknown")[:12]] += 1
            minutes = row.get("train_minutes")
            if isinstance(minutes, (int, float)) and minutes > 0:
                rates.append(60.0 * float(minutes) / max(s1 + s2, 1))
        elif (run / "metrics.json").exists():
            scored += 1
            info = mio.read_json(run / "run.json") if (run / "run.json").exists() else {}
            if trained:
                codes[str(info.get("code") or "unknown")[:12]] += 1
            sec = info.get("train_seconds")
            if isinstance(sec, (int, float)) and sec > 0:
                rates.append(float(sec) / max(s1 + s2, 1))
        else:
            todo += s1 + s2
            failed += last_failed(j, run)
    return {
        "total": len(jl),
        "scored": scored,
        "recorded": in_csv,
        "failed": failed,
        "codes": codes,
        "todo_iterations": todo,
        "sec_per_iteration": rates,
        "job_costs": costs,
    }


def root_rates(root, preset: str) -> List[float]:
    """Recorded training seconds per iteration of every scored run under ROOT/runs/<suite>/<scene>/
    <row> at `preset`, whatever its suite: run.json `train_seconds` over the iterations its
    config.yaml names (stage 1's only where run.json's `stage_seconds` has a stage 1). The
    campaign's estimate falls back on these when none of its own runs has finished."""
    rates = []
    for info_path in sorted(Path(root, "runs").glob("*/*/*/run.json")):
        run = info_path.parent
        if not (run / "metrics.json").exists() or not (run / "config.yaml").exists():
            continue
        try:
            info = mio.read_json(info_path)
            cfg = yaml.safe_load((run / "config.yaml").read_text()) or {}
            sec = info.get("train_seconds")
            s1 = int(cfg["stage1"]["iterations"]) if "stage1" in info["stage_seconds"] else 0
            s2 = int(cfg["stage2"]["iterations"])
        except (OSError, ValueError, KeyError, TypeError, yaml.YAMLError):
            continue  # a run folder of another layout: no rate, not an error of the campaign
        if info.get("preset") == preset and isinstance(sec, (int, float)) and sec > 0:
            rates.append(float(sec) / max(s1 + s2, 1))
    return rates


def estimate_hours(todo_iterations: int, sec_per_iteration: float, jobs: int) -> float:
    """Hours for `todo_iterations` at the recorded seconds per iteration of one run, `jobs` runs
    at a time."""
    return todo_iterations * sec_per_iteration / max(jobs, 1) / 3600.0


def run_campaign(
    campaign: Campaign,
    root,
    csv_path,
    *,
    jobs: int = 1,
    dry_run: bool = False,
    allow_mixed_code: bool = False,
    retry_failed: bool = True,
    code: Optional[str] = None,
    log: Optional[Callable[[str], None]] = None,
    run_kw: Optional[dict] = None,
) -> List[Dict]:
    """Run and export every step in order (see the module docstring); returns one summary per step
    ({"suite", "scenes", "seeds", "total", "scored", "recorded", "codes", "ran"}). dry_run: only
    the summaries. csv_path: the runs CSV the steps are exported into; its scored runs (this
    preset, this generator's clips) count as finished, so a campaign resumes from it after its root
    is lost.
    code: the fingerprint of this checkout's m4dgs sources (default: computed). Raises InputError
    before a step whose finished runs have other code (unless allow_mixed_code) and, after the
    last step, M4DGSError naming the jobs that failed in any step (each step exported first, the
    failed runs as "failed" rows). retry_failed False: a job whose last attempt failed counts as
    finished (its row stays "failed"; it is not run again, so neither the mixed-code check nor the
    final error concerns it)."""
    from m4dgs.core.errors import M4DGSError

    say = log or print
    if code is None:
        # the fingerprint the trainer records in run.json (through its entry point)
        from m4dgs.training.pipeline import code_fingerprint

        code = code_fingerprint()
    code = code[:12]
    out = []
    n = len(campaign.steps)
    from benchgen.make import GENERATOR_VERSION

    # the runs CSV is the record that outlives the root: a job scored there (same preset, clips of
    # this generator) is finished even when its run folder is gone
    recorded = recorded_runs(csv_path, campaign.preset, str(GENERATOR_VERSION))
    # ... and a job whose failed attempt it records (no run folder) failed at its last attempt
    recorded_failed = recorded_runs(csv_path, campaign.preset, str(GENERATOR_VERSION), "failed")
    # the time estimate: the median recorded seconds per iteration over every finished run of the
    # campaign, in this root or in the CSV (one machine, one --jobs setting make it meaningful)
    statuses = [
        step_status(st, root, campaign.preset, recorded, retry_failed, recorded_failed)
        for st in campaign.steps
    ]
    rates = sorted(r for s in statuses for r in s["sec_per_iteration"])
    rate_source = "scored run(s) of this campaign in this root or the CSV"
    if not rates and any(s["todo_iterations"] for s in statuses):
        # none of its own runs has finished: the other suites' runs in this root (same preset,
        # same machine as far as the root goes) say at least how fast this machine trains
        rates = sorted(root_rates(root, campaign.preset))
        rate_source = "scored run(s) of other suites in this root (none of this campaign's yet)"
    rate = rates[len(rates) // 2] if rates else None
    # a stage 1 that rows share (in the share folder already, or made by an earlier job) counts once
    for s, todo in zip(statuses, todo_iterations(statuses)):
        s["todo_iterations"] = todo
    left = 0.0
    failures: List[str] = []  # "step i (suite): job ids" of the steps with failed jobs
    for i, st in enumerate(campaign.steps, 1):
        if i == 1 or dry_run:
            s = statuses[i - 1]
        else:  # earlier steps have run since: this step's state now
            s = statuses[i - 1] = step_status(
                st, root, campaign.preset, recorded, retry_failed, recorded_failed
            )
            # the earlier steps' statuses from the start still name what they share: a stage 1 or
            # a training they had to do was counted there, so this step counts it once at most
            s["todo_iterations"] = todo_iterations(statuses[:i])[-1]
        summary = dict(suite=st.suite, scenes=st.scenes, seeds=st.seeds, ran=False, **s)
        where = "all scenes" if st.scenes is None else ",".join(st.scenes)
        eta = ""
        if rate is not None and s["todo_iterations"]:
            hours = estimate_hours(s["todo_iterations"], rate, jobs)
            left += hours
            summary["estimate_hours"] = hours
            eta = f", ~{hours:.1f} h left at --jobs {jobs}"
        say(
            f"[campaign {campaign.name}] step {i}/{n}: {st.suite} "
            f"({where}, {seeds_text(st.seeds)}): "
            f"{s['scored']} of {s['total']} runs scored"
            + (f" ({s['recorded']} of them only in {csv_path})" if s["recorded"] else "")
            + (f"; {s['failed']} failed at their last attempt" if s.get("failed") else "")
            + (" (not retried)" if s.get("failed") and not retry_failed else "")
            + eta
        )
        if dry_run:
            out.append(summary)
            continue
        # the jobs this step would run: not the scored ones, nor the failed ones when not retried
        settled = s["scored"] + (0 if retry_failed else s["failed"])
        other = {c: k for c, k in s["codes"].items() if c != code}
        if other and settled < s["total"] and not allow_mixed_code:
            raise InputError(
                f"campaign {campaign.name}, step {i} ({st.suite}): "
                + ", ".join(f"{k} finished run(s) with m4dgs code {c}" for c, k in other.items())
                + f"; this checkout is {code}. Finishing the suite would mix code versions in "
                "one table: use a new --root (or check out that code), or pass --allow-mixed-code."
            )

        def export_step(st=st, quiet=False):
            try:
                export([st.suite], root, csv_path, st.scenes, st.seeds, log=say)
            except InputError as e:  # nothing of the step scored under ROOT yet
                if not quiet:
                    say(f"[campaign {campaign.name}] not exported: {e}")

        res = []
        if settled < s["total"]:
            res = run_suite(
                st.suite,
                root,
                campaign.preset,
                jobs=jobs,
                scenes=st.scenes,
                seeds=st.seeds,
                log=say,
                # a job the CSV records is not run again; each finished job is exported at once,
                # so that a lost root loses at most the runs in progress
                # (nor, when failures are not retried, one whose failure only the CSV records)
                skip=lambda j: not Path(j.run_dir).exists()
                and (
                    job_key(j) in recorded or (not retry_failed and job_key(j) in recorded_failed)
                ),
                on_result=lambda j, r: export_step(quiet=True),
                retry_failed=retry_failed,
                **(run_kw or {}),
            )
            summary["ran"] = True
        summary.update(
            step_status(st, root, campaign.preset, recorded, retry_failed, recorded_failed)
        )
        bad = failed_jobs(res)
        if summary["scored"] > summary["recorded"] or bad:
            export_step()  # with failed jobs: their rows say "failed" and why
        out.append(summary)
        if bad:
            failures.append(
                f"step {i} ({st.suite}): {len(bad)} job(s) ({'; '.join(r['id'] for r in bad[:3])}"
                + (f" and {len(bad) - 3} more" if len(bad) > 3 else "")
                + ")"
            )
            say(
                f"[campaign {campaign.name}] step {i} ({st.suite}): {len(bad)} job(s) failed; "
                "exported as failed rows, going on with the next step"
            )
    if dry_run and rate is None and any(s["todo_iterations"] for s in statuses):
        say(
            f"[campaign {campaign.name}] no time estimate: none of its runs has finished yet, nor "
            "any other run at this preset in this root (the estimate is their median recorded "
            "seconds per iteration)"
        )
    if failures:
        raise M4DGSError(
            f"campaign {campaign.name}: jobs failed in "
            + "; ".join(failures)
            + "; every step ran and the finished runs are exported. Run the same command again "
            "to retry the failed jobs."
        )
    if dry_run and left:
        say(
            f"[campaign {campaign.name}] estimate: ~{left:.1f} h of training left at --jobs {jobs} "
            f"(median {rate:.3f} s per iteration over {len(rates)} {rate_source}; a stage 1 that "
            "rows share counted once, a run another suite repeats too)"
        )
    return out
