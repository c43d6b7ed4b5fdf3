"""`m4dgs-eval suite list|run|job|campaign|export`: the experiment suites (eval.experiments).
The old flat names (`suites`, `run`, `job`, `campaign`, `export`) are hidden aliases (eval.cli)."""

from __future__ import annotations

import json

import click

from eval.cli._options import (
    DEFAULT_OUT,
    SEEDS,
    device_opt,
    executor_opts,
    found_seeds_opt,
    jobs_opt,
    lpips_opt,
    no_retry_failed_opt,
    no_share_opt,
    out_opt,
    parse_names,
    preset_opt,
    rows_opt,
    runs_csv_opt,
    scenes_opt,
)
from m4dgs.core.executor_options import make_executor_from


@click.group(
    "suite",
    short_help="Experiment suites: list, run, job, campaign, export, merge.",
    context_settings={"help_option_names": ["-h", "--help"]},
)
def group():
    """Experiment suites: list them, run them (or one job of one, or a campaign of
    several), export their runs into the runs CSV, merge another runs CSV into it."""


# --------------------------------------------------------------------------------------------------
@group.command("list")
def suites():
    """List the shipped experiment suites, their rows (name: variant + overrides, clip setting) and
    tables."""
    from eval.records.suite import builtin_suites, check_variants, load_eval_suite

    for name in builtin_suites():
        s = load_eval_suite(name)
        click.echo(f"{s.name}: {s.description}  [scenes: {s.scenes}]")
        for r in s.rows:
            ov = f" {r.overrides}" if r.overrides else ""
            what = (
                f"calibration row {r.calibration}"
                if r.calibration is not None
                else f"variant {r.variant}{ov}"
            )
            click.echo(f"  - {r.name}: {what}, clip {r.clip}  ({r.label})")
        bad = check_variants(s)
        if bad:
            click.echo(f"  ! variants unknown to m4dgs.training.variants: {bad}")


@group.command()
@click.argument("suite")
@out_opt
@preset_opt
@jobs_opt
@scenes_opt
@rows_opt
@click.option(
    "--seeds",
    default="1",
    show_default=True,
    type=SEEDS,
    help="Trainer seeds per (scene, row), same clip: N for 0..N-1, or a list such as 2,3 (seeds no "
    "earlier run used); seed 0 trains into <row>, seed n into <row>-seed-n.",
)
@click.option(
    "--force", is_flag=True, help="Recompute metrics.json of finished runs (never retrains)."
)
@click.option(
    "--list-jobs",
    is_flag=True,
    help="Print the job list as JSON lines (with each job's `python -m eval job` command) and "
    "exit.",
)
@click.option("--clips-only", is_flag=True, help="Only make the missing clips.")
@lpips_opt
@device_opt
@no_share_opt
@click.option(
    "--fail-fast",
    is_flag=True,
    help="Stop at the first failed job. By default a failed job is reported and the others go "
    "on; the command then exits with status 1 naming the failed jobs.",
)
@no_retry_failed_opt
@executor_opts
def run(
    suite,
    out,
    preset,
    jobs,
    scenes,
    rows,
    seeds,
    force,
    list_jobs,
    clips_only,
    lpips_weights,
    device,
    no_share,
    fail_fast,
    no_retry_failed,
    **executor,
):
    """Make missing clips, train missing runs and score missing metrics of SUITE (name or YAML
    path); resumable."""
    from eval.experiments.runner import failed_jobs, list_jobs_jsonl, run_suite
    from m4dgs.core.errors import M4DGSError

    if list_jobs:
        click.echo(
            list_jobs_jsonl(
                suite,
                out,
                preset,
                parse_names(scenes),
                lpips_weights=lpips_weights,
                device=None if device == "auto" else device,
                seeds=seeds,
                share=not no_share,
                rows=parse_names(rows),
            ),
            nl=False,
        )
        return
    with make_executor_from(executor, jobs, device) as ex:
        res = run_suite(
            suite,
            out,
            preset,
            jobs=jobs,
            scenes=parse_names(scenes),
            force=force,
            lpips_weights=lpips_weights,
            device=device,
            clips_only=clips_only,
            log=lambda s: click.echo(s, err=True),
            seeds=seeds,
            share=not no_share,
            fail_fast=fail_fast,
            retry_failed=not no_retry_failed,
            executor=ex,
            rows=parse_names(rows),
        )
    for r in res:
        click.echo(json.dumps(r))
    bad = failed_jobs(res)
    if bad:
        raise M4DGSError(
            f"{len(bad)} of {len(res)} jobs failed: "
            + "; ".join(f"{r['id']} ({r['error']})" for r in bad[:5])
            + (f"; ... and {len(bad) - 5} more" if len(bad) > 5 else "")
            + ". Finished runs are kept: run the same command again to retry the failed ones."
        )


@group.command()
@click.argument("suite")
@click.option("--scene", required=True, help="Scene name of the job.")
@click.option("--row", required=True, help="Row name of the job (see `m4dgs-eval suites`).")
@click.option(
    "--seed",
    default=0,
    show_default=True,
    type=click.IntRange(min=0),
    help="Trainer seed index of the job (0: the run folder <row>; n: <row>-seed-n).",
)
@out_opt
@preset_opt
@click.option(
    "--clip-only",
    is_flag=True,
    help="Only make the job's clip (run this once per clip before fan-out).",
)
@click.option("--force", is_flag=True, help="Recompute metrics.json even if it exists.")
@lpips_opt
@device_opt
@no_share_opt
def job(suite, scene, row, seed, out, preset, clip_only, force, lpips_weights, device, no_share):
    """Run ONE job of SUITE: make its clip if missing, train (resumes), score. Prints a JSON result
    line."""
    from eval.experiments.runner import find_job, run_job
    from m4dgs.core.threads import threads_for

    j = find_job(suite, out, preset, scene, row, seed)
    # one job per process: every CPU, split as the workers of `run` split theirs
    with threads_for(device=device):
        res = run_job(
            j,
            force=force,
            lpips_weights=lpips_weights,
            device=device,
            clip_only=clip_only,
            share=not no_share,
        )
    click.echo(json.dumps(res))


@group.command()
@click.argument("campaign")
@out_opt
@jobs_opt
@runs_csv_opt
@click.option(
    "--dry-run",
    is_flag=True,
    help="Print each step with its scored / total runs and the hours left at --jobs, and exit.",
)
@click.option(
    "--allow-mixed-code",
    is_flag=True,
    help="Finish a step whose finished runs were trained with other m4dgs code than this "
    "checkout's (by default the campaign stops there: one table, one code version).",
)
@no_retry_failed_opt
@lpips_opt
@device_opt
@no_share_opt
@executor_opts
def campaign(
    campaign,
    out,
    jobs,
    csv_path,
    dry_run,
    allow_mixed_code,
    no_retry_failed,
    lpips_weights,
    device,
    no_share,
    **executor,
):
    """Run the suites of CAMPAIGN (a name from eval/campaigns or a YAML path) one after another
    into ROOT, exporting each into the runs CSV as soon as it is done; resumable (run the same
    command again). See docs/eval.md."""
    from eval.experiments.campaign import load_campaign, run_campaign

    c = load_campaign(campaign)
    run_kw = dict(lpips_weights=lpips_weights, device=device, share=not no_share)
    # one executor (one Ray cluster, one Slurm folder) for every step; a dry run starts none
    ex = None if dry_run else make_executor_from(executor, jobs, device)
    try:
        res = run_campaign(
            c,
            out,
            csv_path,
            jobs=jobs,
            dry_run=dry_run,
            allow_mixed_code=allow_mixed_code,
            retry_failed=not no_retry_failed,
            log=lambda s: click.echo(s, err=True),
            run_kw=dict(run_kw, executor=ex) if ex is not None else run_kw,
        )
    finally:
        if ex is not None:
            ex.close()
    # a step is complete when each job scored, or failed and is not to be retried
    done = sum(
        r["scored"] + (r.get("failed", 0) if no_retry_failed else 0) == r["total"] for r in res
    )
    click.echo(f"[campaign {c.name}] {done} of {len(res)} steps complete", err=True)


@group.command()
@click.argument("suites", nargs=-1, required=True)
@click.option(
    "--root",
    "out",
    default=DEFAULT_OUT,
    show_default=True,
    type=click.Path(file_okay=False),
    metavar="ROOT",
    help="Experiment root of the suites (runs in ROOT/runs/<suite>).",
)
@runs_csv_opt
@scenes_opt
@found_seeds_opt("collect")
@click.option(
    "--add-missing",
    is_flag=True,
    help="First compute, in every scored run, the metrics its metrics.json lacks because an "
    "earlier version scored it (as `score RUN --add-missing`; today: hdr_tce).",
)
def export(suites, out, csv_path, scenes, seeds, add_missing):
    """Collect the scored runs of SUITES under ROOT into one CSV of per-run metrics (one row per
    suite, scene, row, seed), merging with the existing CSV: a scored run replaces the row of
    the same key, a run without metrics.json never replaces a scored one, other rows stay (a run
    whose last attempt failed gets status "failed" and its error, from <run>/failure.json). Beside
    it, <name>-crf.csv holds the learned tone curves and <name>-floors.csv the clips'
    ground-truth HDR-TAE floors (one row per scene and generator version)."""
    from eval.experiments.export import export as export_runs

    summary = export_runs(
        suites,
        out,
        csv_path,
        parse_names(scenes),
        seeds,
        log=lambda s: click.echo(s, err=True),
        add_missing=add_missing,
    )
    for name, c in summary.items():
        failed = f", {c['failed']} failed" if c.get("failed") else ""
        click.echo(
            f"{name}: {c['scored']} scored{failed}, {c['missing']} without metrics.json", err=True
        )
    click.echo(f"wrote {csv_path}", err=True)


@group.command()
@click.argument("src", type=click.Path(dir_okay=False), metavar="SRC_CSV")
@runs_csv_opt
@click.option(
    "--suites",
    default=None,
    metavar="a,b",
    help="Comma-separated suites whose rows to take from SRC_CSV (default: all of them).",
)
def merge(src, csv_path, suites):
    """Merge the rows of another runs CSV (SRC_CSV: another machine's `export`, or a campaign's
    rows kept in their own CSV until it ends) into --csv, with the learned CRF curves and clip
    floors beside it, by export's rules: a scored row replaces the row of the same (suite, scene,
    row, seed), a missing or failed one never replaces a scored one, other rows stay. A clip floor
    is added only where --csv has none for that scene and generator version."""
    from eval.experiments.export import merge_csv

    summary = merge_csv(src, csv_path, parse_names(suites), log=lambda s: click.echo(s, err=True))
    for name, c in summary.items():
        failed = f", {c['failed']} failed" if c.get("failed") else ""
        click.echo(f"{name}: {c['scored']} scored{failed}, {c['missing']} missing rows", err=True)
    click.echo(f"wrote {csv_path}", err=True)
