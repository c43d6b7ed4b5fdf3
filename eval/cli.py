"""`m4dgs-eval` (also `python -m eval`; a plain `eval` typed in a shell runs the shell's builtin):
score runs, run experiment suites, print paper-style tables.

    m4dgs-eval score RUN
        write RUN/metrics.json (renders what is missing through m4dgs)
    m4dgs-eval score-frames --clip C --pred D --name N
        score another method's frames (no m4dgs model)
    m4dgs-eval suites
        the shipped experiment suites and their rows
    m4dgs-eval run tiny --preset tiny
        make clips, train and score every (scene, row) of a suite (resumable)
    m4dgs-eval run tiny --seeds 3
        ... with trainer seeds 0, 1, 2 (same clips; runs <row>, <row>-seed-n)
    m4dgs-eval run paper-main --list-jobs
        the job list as JSON lines (one `python -m eval job ...` per line)
    m4dgs-eval job paper-main --scene S --row R
        run ONE job (cluster fan-out: docs/cluster.md)
    m4dgs-eval regions RUN [RUN ...] --ref RUN --bright-above 20
        where each run's test-frame error sits (bright / moving / static pixels)
    m4dgs-eval region-pairs SUITE --root ROOT --ref full --rows no-x --seeds 2
        the same split differenced per (scene, seed) pair, with its mean and 95 % interval
    m4dgs-eval peaks RUN [RUN ...]
        the largest HDR value of each run's test renders against the ground truth's (runaways)
    m4dgs-eval table tiny
        the suite's tables (Markdown; --format latex|csv) and figures: mean +- 95 % CI over
        scenes x seeds, paired differences to the reference row, the paper's values and
        direction agreement

Details: docs/eval.md.
"""

from __future__ import annotations

import json
import math
import os
import shlex
from pathlib import Path

import click

from eval.experiments.collect import collect_runs_dir, collect_suite
from eval.inspect.pairs import DEFAULT_METRICS as DEFAULT_PAIR_METRICS
from eval.records.suite_data import build_tables
from m4dgs.core import io as mio
from m4dgs.core.errors import ReportingGroup

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# Each command imports the modules it runs when it runs: `eval --help` and the listing commands stay
# free of torch (scoring), the trainer and the renderer stack, and tests can replace the trainer's
# entry points.

DEFAULT_OUT = "experiments"
FORMATS = {"md": "markdown", "markdown": "markdown", "latex": "latex", "csv": "csv"}


def _scenes(text):
    return None if not text else [s.strip() for s in text.split(",") if s.strip()]


@click.group(cls=ReportingGroup, context_settings={"help_option_names": ["-h", "--help"]})
def main():
    """Evaluation of Mono4DGS-HDR runs: metrics, experiment suites, paper-style tables and
    figures."""


# --------------------------------------------------------------------------------------------------
# options of the scorers (`score`, `score-frames`); --lpips-weights also of `run`, `job`, `campaign`
_lpips_opt = click.option(
    "--lpips-weights",
    default=None,
    type=click.Path(exists=True, dir_okay=False),
    help="LPIPS weights file (AlexNet + linear heads, docs/metrics.md); without it LPIPS is n/a.",
)
_roundtrip_opt = click.option(
    "--roundtrip",
    type=click.Choice(["none", "png", "jpeg"]),
    default="none",
    show_default=True,
    help="8-bit round trip of the LDR frames before scoring (jpeg: as the authors scored).",
)
_flip_opt = click.option(
    "--flip", is_flag=True, help="Also compute HDR-FLIP on the test frames (slow)."
)


@main.command()
@click.argument("run", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--clip",
    "clip_dir",
    default=None,
    type=click.Path(exists=True, file_okay=False),
    help="Clip folder to score against (default: the 'clip' entry of RUN/run.json).",
)
@_lpips_opt
@_roundtrip_opt
@_flip_opt
@click.option(
    "--tae-train-test", is_flag=True, help="Also HDR-TAE over all frames (train + test, DIS flow)."
)
@click.option("--no-fps", is_flag=True, help="Skip the render-speed measurement.")
@click.option(
    "--no-model", is_flag=True, help="Do not load the trained model (no tracks, CRF curve or FPS)."
)
@click.option(
    "--device", default="auto", show_default=True, help="Device for the model: auto, cpu or cuda."
)
@click.option("--force", is_flag=True, help="Recompute metrics.json even if it exists.")
@click.option(
    "--add-missing",
    is_flag=True,
    help="Compute only the metrics an existing metrics.json lacks because it was written by an "
    "earlier version (today: hdr_tce), leaving every other value as it is; then re-export the "
    "suite to get them into a runs CSV.",
)
def score(
    run,
    clip_dir,
    lpips_weights,
    roundtrip,
    flip,
    tae_train_test,
    no_fps,
    no_model,
    device,
    force,
    add_missing,
):
    """Score one run folder and write RUN/metrics.json; prints the headline metrics as JSON."""
    from eval.experiments.score import add_missing_metrics, score_run

    mpath = Path(run) / "metrics.json"
    if add_missing:
        if force:
            raise click.UsageError("--add-missing and --force exclude each other")
        m, added = add_missing_metrics(run, clip=clip_dir)
        click.echo(
            f"{mpath}: added {', '.join(added)}" if added else f"{mpath}: nothing missing",
            err=True,
        )
    elif mpath.exists() and not force:
        m = mio.read_json(mpath)
        click.echo(f"{mpath} exists (use --force to recompute)", err=True)
    else:
        m = score_run(
            run,
            clip=clip_dir,
            lpips_weights=lpips_weights,
            roundtrip=None if roundtrip == "none" else roundtrip,
            flip=flip,
            fps=not no_fps,
            tae_train_test=tae_train_test,
            device=device,
            model=not no_model,
        )
    head = {
        k: m.get(k)
        for k in (
            "ldr_oe_psnr",
            "ldr_ne_psnr",
            "hdr_psnr",
            "hdr_ssim",
            "hdr_tae",
            "ate",
            "depth_absrel",
            "fps",
        )
    }
    click.echo(json.dumps(head))


# --------------------------------------------------------------------------------------------------
@main.command("score-frames")
@click.option(
    "--clip",
    "clip_dir",
    required=True,
    type=click.Path(exists=True, file_okay=False),
    help="Clip folder the frames are scored against (it must have ground truth).",
)
@click.option(
    "--pred",
    required=True,
    type=click.Path(exists=True, file_okay=False),
    help="Prediction folder: test/hdr/<g>.exr and test/ldr/<level>/<g>.png|exr|tif for every test "
    "frame and level; optional train/hdr, train/ldr, test/depth, cameras.json (docs/eval.md).",
)
@click.option(
    "--name",
    required=True,
    help="Method name: the row label in `m4dgs-eval table` and the folder name under runs/<clip>/.",
)
@click.option(
    "--out",
    default=None,
    type=click.Path(file_okay=False),
    help="Score folder (default: runs/<clip name>/<NAME>; `m4dgs-eval table runs/<clip name>` "
    "shows it beside the m4dgs runs there).",
)
@_lpips_opt
@_roundtrip_opt
@_flip_opt
@click.option(
    "--tae-train-test", is_flag=True, help="Also HDR-TAE over all frames (needs train/hdr)."
)
@click.option("--force", is_flag=True, help="Replace an earlier score folder of the same name.")
def score_frames_cmd(
    clip_dir, pred, name, out, lpips_weights, roundtrip, flip, tae_train_test, force
):
    """Score another method's rendered frames against a clip with every frame-based metric of an
    m4dgs run (no m4dgs model needed); writes OUT/metrics.json and prints the headline metrics."""
    from eval.experiments.frames import score_frames

    run_dir, m = score_frames(
        clip_dir,
        pred,
        name,
        out,
        force=force,
        lpips_weights=lpips_weights,
        roundtrip=None if roundtrip == "none" else roundtrip,
        flip=flip,
        tae_train_test=tae_train_test,
    )
    click.echo(f"scored {name}: {run_dir / 'metrics.json'}", err=True)
    keys = ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_ssim", "hdr_tae", "ate", "depth_absrel")
    click.echo(json.dumps({k: m.get(k) for k in keys}))


# --------------------------------------------------------------------------------------------------
@main.command()
def suites():
    """List the shipped experiment suites, their rows (name: variant + overrides, clip setting) and
    tables."""
    from eval.records.suite import builtin_suites, check_variants, load_eval_suite

    for name in builtin_suites():
        s = load_eval_suite(name)
        click.echo(f"{s.name}: {s.description}  [scenes: {s.scenes}]")
        for r in s.rows:
            ov = f" {r.overrides}" if r.overrides else ""
            click.echo(f"  - {r.name}: variant {r.variant}{ov}, clip {r.clip}  ({r.label})")
        bad = check_variants(s)
        if bad:
            click.echo(f"  ! variants unknown to m4dgs.training.variants: {bad}")


# --------------------------------------------------------------------------------------------------
_out_opt = click.option(
    "--root",
    "--out",
    "out",
    default=DEFAULT_OUT,
    show_default=True,
    type=click.Path(file_okay=False),
    metavar="ROOT",
    help="Experiment root (the same as --root of `table` and `export`; --out is its older name): "
    "clips in ROOT/clips/<setting>/<scene>, runs in ROOT/runs/<suite>/<scene>/<row>, figures in "
    "ROOT/figures/<suite>. One ROOT per preset.",
)
_scenes_opt = click.option(
    "--scenes",
    default=None,
    help="Comma-separated subset of the scenes (default: all of each suite's scenes).",
)
_preset_opt = click.option(
    "--preset",
    type=click.Choice(["tiny", "small", "paper"]),
    default="small",
    show_default=True,
    help="Clip preset AND training preset (tiny: tests and the demo).",
)
_device_opt = click.option(
    "--device",
    default="auto",
    show_default=True,
    help="Training / scoring device: auto, cpu or cuda.",
)

_jobs_opt = click.option(
    "--jobs",
    default=1,
    show_default=True,
    type=click.IntRange(min=1),
    help="Local worker processes, each with cpu_count / N threads (torch's operations on one, "
    "the compiled rasterizer on all of them: the fastest split measured, docs/performance.md).",
)
_no_share_opt = click.option(
    "--no-share",
    is_flag=True,
    help="Compute every trainer phase in every run. By default the runs of one clip share camera "
    "initialisation, stage 1, the V2W transform and stage 2 through ROOT/.shared wherever their "
    "configurations agree on what that phase reads (stage 2: the whole configuration and the "
    "variant, e.g. the full row of two suites; never across trainer seeds; docs/eval.md).",
)


_no_retry_failed_opt = click.option(
    "--no-retry-failed",
    is_flag=True,
    help="Do not run again a job whose last attempt failed (<run>/failure.json, or, for `campaign` "
    "when the run folder is gone, the runs CSV's `failed` row): a failure that repeats is a "
    "result of its configuration, and its row stays `failed`. By default such jobs are retried.",
)


@main.command()
@click.argument("suite")
@_out_opt
@_preset_opt
@_jobs_opt
@_scenes_opt
@click.option(
    "--seeds",
    default=1,
    show_default=True,
    type=click.IntRange(min=1),
    help="Trainer seeds 0..N-1 per (scene, row), same clip; seed 0 trains into <row>, seed n into "
    "<row>-seed-n.",
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
@_lpips_opt
@_device_opt
@_no_share_opt
@click.option(
    "--fail-fast",
    is_flag=True,
    help="Stop at the first failed job. By default a failed job is reported and the others go "
    "on; the command then exits with status 1 naming the failed jobs.",
)
@_no_retry_failed_opt
def run(
    suite,
    out,
    preset,
    jobs,
    scenes,
    seeds,
    force,
    list_jobs,
    clips_only,
    lpips_weights,
    device,
    no_share,
    fail_fast,
    no_retry_failed,
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
                _scenes(scenes),
                lpips_weights=lpips_weights,
                device=None if device == "auto" else device,
                seeds=seeds,
                share=not no_share,
            ),
            nl=False,
        )
        return
    res = run_suite(
        suite,
        out,
        preset,
        jobs=jobs,
        scenes=_scenes(scenes),
        force=force,
        lpips_weights=lpips_weights,
        device=device,
        clips_only=clips_only,
        log=lambda s: click.echo(s, err=True),
        seeds=seeds,
        share=not no_share,
        fail_fast=fail_fast,
        retry_failed=not no_retry_failed,
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


@main.command()
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
@_out_opt
@_preset_opt
@click.option(
    "--clip-only",
    is_flag=True,
    help="Only make the job's clip (run this once per clip before fan-out).",
)
@click.option("--force", is_flag=True, help="Recompute metrics.json even if it exists.")
@_lpips_opt
@_device_opt
@_no_share_opt
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


def _no_scored_runs(target: str, name: str, root, entries: list) -> str:
    """One line for `table SUITE` when none of the suite's runs under ROOT has a metrics.json:
    the folder it searched, what it looked for there, and what to run."""
    where = os.path.join(os.path.abspath(root), "runs", name)
    todo = f"m4dgs-eval run {shlex.quote(target)} --root {shlex.quote(str(root))}"
    made = [e for e in entries if Path(e["run_dir"]).is_dir()]
    if made:
        return (
            f"{len(made)} of the {len(entries)} run folder(s) of suite {name!r} exist under "
            f"{where} but none has a metrics.json yet (searched <scene>/<row>/metrics.json); "
            f"finish and score them with `{todo}`"
        )
    why = ""
    if not os.path.isdir(root):
        why = "; the experiment root does not exist"
    elif not os.path.isdir(where):
        why = "; that folder does not exist"
    return (
        f"no runs of suite {name!r} under {where} (searched <scene>/<row>/metrics.json for its "
        f"{len(entries)} job(s){why}); train them with `{todo}`"
    )


@main.command()
@click.argument("target")
@click.option(
    "--root",
    "out",
    default=DEFAULT_OUT,
    show_default=True,
    type=click.Path(file_okay=False),
    metavar="ROOT",
    help="Experiment root of a suite (runs in ROOT/runs/<suite>, figures to ROOT/figures/<suite>).",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["md", "latex", "csv"]),
    default="md",
    show_default=True,
    help="Table format (Markdown with bold best values; LaTeX booktabs; CSV without bold).",
)
@click.option(
    "--out",
    "out_file",
    default=None,
    type=click.Path(dir_okay=False),
    help="Write the tables to this file (atomically) instead of stdout.",
)
@_scenes_opt
@click.option(
    "--seeds",
    default=None,
    type=click.IntRange(min=1),
    help="Trainer seeds 0..N-1 to tabulate (default: up to the largest seed with a run folder).",
)
@click.option(
    "--no-figures",
    is_flag=True,
    help="Do not write the figures (CRF curves, loss curves, image grids).",
)
@click.option(
    "--figures-dir",
    default=None,
    type=click.Path(file_okay=False),
    help="Folder for the figures (default ROOT/figures/<suite>, or <runs dir>/../figures/<name>).",
)
def table(target, out, fmt, out_file, scenes, seeds, no_figures, figures_dir):
    """Print the paper-style tables of TARGET: a suite (name or YAML; runs under ROOT) or a folder
    of runs (linked run and scene folders count like real ones)."""
    from eval.records.suite import TableDef, load_eval_suite
    from m4dgs.core.errors import InputError

    if Path(target).is_dir():
        entries = collect_runs_dir(target)
        if not entries:
            raise InputError(
                f"no scored runs under {os.path.abspath(target)} (searched it and every folder "
                "below it, links included, for metrics.json); score a run folder with "
                "`m4dgs-eval score RUN`, or give a suite's name with --root ROOT"
            )
        reference = "full" if any(e["row"] == "full" for e in entries) else None
        defs = [
            TableDef(f"Runs under {target}", "paper"),
            TableDef("Training frames", "train"),
            TableDef("Geometry", "geometry"),
            TableDef("Cost", "cost"),
        ]
        # beside the folder as named (a linked folder's figures stay in this tree)
        given = Path(os.path.abspath(target))
        fig_dir = Path(figures_dir) if figures_dir else given.parent / "figures" / given.name
    else:
        if os.sep in target and not Path(target).exists():
            raise InputError(
                f"{target}: no such folder of runs ({os.path.abspath(target)}) nor suite file; "
                "give a folder of runs, a suite YAML file or a built-in suite's name "
                "(`m4dgs-eval suites`)"
            )
        s = load_eval_suite(target)
        entries = collect_suite(target, out, _scenes(scenes), seeds=seeds)
        defs, reference = s.tables, s.reference
        fig_dir = Path(figures_dir) if figures_dir else Path(out) / "figures" / s.name
        if not any(e["metrics"] for e in entries):
            raise InputError(_no_scored_runs(target, s.name, out, entries))
    text = build_tables(entries, defs, fmt, reference)
    if out_file:
        mio.write_text_atomic(out_file, text)
        click.echo(f"wrote {out_file}", err=True)
    else:
        click.echo(text, nl=False)
    if not no_figures:
        from eval.figures import suite_figures

        # seed 0 only
        paths = suite_figures([e for e in entries if e["metrics"] and not e.get("seed")], fig_dir)
        click.echo(f"wrote {len(paths)} figure(s) to {fig_dir}", err=True)


# --------------------------------------------------------------------------------------------------
_runs_csv_opt = click.option(
    "--csv",
    "csv_path",
    default="results/runs.csv",
    show_default=True,
    type=click.Path(dir_okay=False),
    help="Runs CSV to create or merge into (learned CRF curves go to <stem>-crf.csv beside it).",
)


@main.command()
@click.argument("campaign")
@_out_opt
@_jobs_opt
@_runs_csv_opt
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
@_no_retry_failed_opt
@_lpips_opt
@_device_opt
@_no_share_opt
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
):
    """Run the suites of CAMPAIGN (a name from eval/campaigns or a YAML path) one after another
    into ROOT, exporting each into the runs CSV as soon as it is done; resumable (run the same
    command again). See docs/eval.md."""
    from eval.experiments.campaign import load_campaign, run_campaign

    c = load_campaign(campaign)
    res = run_campaign(
        c,
        out,
        csv_path,
        jobs=jobs,
        dry_run=dry_run,
        allow_mixed_code=allow_mixed_code,
        retry_failed=not no_retry_failed,
        log=lambda s: click.echo(s, err=True),
        run_kw=dict(lpips_weights=lpips_weights, device=device, share=not no_share),
    )
    # a step is complete when each job scored, or failed and is not to be retried
    done = sum(
        r["scored"] + (r.get("failed", 0) if no_retry_failed else 0) == r["total"] for r in res
    )
    click.echo(f"[campaign {c.name}] {done} of {len(res)} steps complete", err=True)


@main.command()
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
@_runs_csv_opt
@_scenes_opt
@click.option(
    "--seeds",
    default=None,
    type=click.IntRange(min=1),
    help="Trainer seeds 0..N-1 to collect (default: up to the largest seed with a run folder).",
)
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
        _scenes(scenes),
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


# --csv of the commands that read the runs CSV alone (pairs, repeats)
_read_csv_opt = click.option(
    "--csv",
    "csv_path",
    default="results/runs.csv",
    show_default=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Runs CSV written by `export`.",
)


def _against_spec(against):
    """[suite, ref, row] of an --against SUITE:REF:ROW value (None without one); a usage error
    otherwise."""
    from eval.inspect.pairs import split_spec

    if against is None:
        return None
    try:
        return split_spec(against, ("SUITE", "REF", "ROW"), "control-tlr-priors:full:full-tlr-0.1")
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--against") from None


@main.command()
@click.argument("suite")
@click.option(
    "--ref",
    default=None,
    help="Reference row (default: the suite file's reference row).",
)
@click.option(
    "--rows",
    "row_names",
    default=None,
    help="Comma-separated rows to compare with --ref (default: every other row of the suite in "
    "the CSV).",
)
@click.option(
    "--metrics",
    default=",".join(DEFAULT_PAIR_METRICS),
    show_default=True,
    help="Comma-separated metric columns of the CSV (e.g. hdr_tce, track_epe, mask_iou).",
)
@_read_csv_opt
@click.option(
    "--by-seed",
    is_flag=True,
    help="Also the mean and interval at each trainer seed alone, and a one-way ANOVA of the "
    "differences across scenes (F, p): whether the effect differs between scenes by more than its "
    "seeds scatter, i.e. whether a per-scene pattern of one seed replicated.",
)
@click.option(
    "--holm",
    is_flag=True,
    help="Also each comparison's paired t-test p-value adjusted by Holm's method over every "
    "comparison printed (rows x metrics; † below 0.05), and how many survive.",
)
@click.option(
    "--against",
    default=None,
    metavar="SUITE:REF:ROW",
    help="Print instead each difference's change against SUITE's ROW - REF of the same (scene, "
    "seed) pairs (a control's difference in differences, as results.md's Controls read it; e.g. "
    "control-tlr-priors:full:full-tlr-0.1).",
)
@click.option(
    "--rows-differ",
    "differ",
    is_flag=True,
    help="Also whether the rows compared (two or more: levels of one factor, such as three draws "
    "or three weights) differ from one another by more than the pairs scatter: a two-way "
    "analysis of variance over the (scene, seed) pairs every row has (F, p per metric).",
)
def pairs(suite, ref, row_names, metrics, csv_path, by_seed, holm, against, differ):
    """Print the paired differences row - ref of SUITE (a built-in suite's name or a suite YAML
    file) per (scene, seed) from the runs CSV, with their mean and 95 % interval: the per-scene
    values the hand-written results notes quote."""
    from eval.inspect.pairs import pairs_markdown
    from eval.records.runs_csv import read_runs_csv

    names = [n.strip() for n in row_names.split(",") if n.strip()] if row_names else None
    mets = [m.strip() for m in metrics.split(",") if m.strip()]
    spec = _against_spec(against)
    try:
        text = pairs_markdown(
            read_runs_csv(csv_path),
            suite,
            ref,
            names,
            mets,
            by_seed=by_seed,
            holm=holm,
            against=spec,
            differ=differ,
        )
    except ValueError as e:
        raise click.UsageError(f"{csv_path}: {e}") from e
    click.echo(text)


@main.command()
@click.argument("side_a", metavar="SUITE_A:ROW")
@click.argument("side_b", metavar="SUITE_B:ROW")
@click.option(
    "--metrics",
    default=None,
    help="Comma-separated metric columns to compare (default: every quality column of the CSV, "
    "i.e. all but training minutes, FPS, Gaussian count and peak memory).",
)
@_read_csv_opt
@click.option(
    "--check",
    is_flag=True,
    help="Exit with status 1 unless every (scene, seed) pair is equal in every compared column.",
)
def repeats(side_a, side_b, metrics, csv_path, check):
    """Check whether one configuration's runs repeat in another suite: for each (scene, seed)
    that both SUITE_A:ROW and SUITE_B:ROW scored, how many quality columns are equal as the CSV
    stores them, the largest differences B - A, each side's code and host, and the headline
    metrics' B - A over the pairs that differ (to set beside the suite's seed noise)."""
    from eval.inspect.repeats import repeats_markdown
    from eval.records.runs_csv import read_runs_csv

    mets = [m.strip() for m in metrics.split(",") if m.strip()] if metrics else None
    try:
        text, got = repeats_markdown(read_runs_csv(csv_path), side_a, side_b, mets)
    except ValueError as e:
        raise click.UsageError(f"{csv_path}: {e}") from e
    click.echo(text)
    if check and not all(p.equal for p in got):
        raise SystemExit(1)


# --clip of the commands that read several runs' renders (regions, error-maps)
_runs_clip_opt = click.option(
    "--clip",
    "clip_dir",
    default=None,
    type=click.Path(exists=True, file_okay=False),
    help="Clip folder for every run (default: the 'clip' entry of each RUN/run.json); needed for "
    "a prediction folder of `score-frames`.",
)


def _region_options(f):
    """The region options of `regions` and `region-pairs` (--bright-above, --bright-top,
    --dilate, --edges)."""
    f = click.option(
        "--edges",
        type=click.FloatRange(min=0.0, min_open=True),
        default=None,
        help="Add an edge region: both pixels of every pair of 4-neighbours whose ground-truth "
        "depths differ by more than this fraction (e.g. 0.05), less the bright region: the "
        "occlusion boundaries.",
    )(f)
    f = click.option(
        "--dilate",
        type=click.IntRange(min=0),
        default=0,
        show_default=True,
        help="Grow the bright region by this many pixels (4-connected steps).",
    )(f)
    f = click.option(
        "--bright-top",
        type=float,
        default=None,
        help="The bright region: each frame's brightest fraction of pixels, in (0, 1) (e.g. "
        "0.01); instead of --bright-above.",
    )(f)
    return click.option(
        "--bright-above",
        type=float,
        default=None,
        help="The bright region: pixels whose ground-truth HDR (max over channels, clip units) "
        "exceeds this (e.g. 20 for the scenes' lamps).",
    )(f)


def _check_bright(bright_above, bright_top) -> None:
    """Usage errors for the bright region's options: at most one, --bright-top in (0, 1)."""
    if bright_above is not None and bright_top is not None:
        raise click.UsageError("give --bright-above or --bright-top, not both")
    if bright_top is not None and not 0.0 < bright_top < 1.0:
        raise click.UsageError(f"--bright-top must lie in (0, 1), got {bright_top}")


@main.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@click.option(
    "--ref",
    "ref_run",
    default=None,
    type=click.Path(exists=True, file_okay=False),
    help="A reference run of the same scene, frames and levels (its clip may differ in priors or "
    "exposure schedule): also print how each run's change in squared error splits over the "
    "regions.",
)
@_runs_clip_opt
@_region_options
@click.option(
    "--json",
    "json_path",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also write every split (and the reference's) to this JSON file.",
)
def regions(runs, ref_run, clip_dir, bright_above, bright_top, dilate, edges, json_path):
    """Where each run's test-frame error sits: per LDR level and for HDR (mu-law), each region's
    share of the pixels and of the squared error, and the PSNR with the region left out; regions
    are bright (--bright-above / --bright-top), depth edges (--edges), the ground truth's dynamic
    mask, and the rest."""
    from eval.experiments.score import resolve_clip_dir
    from eval.inspect.regions import (
        check_comparable,
        describe_regions,
        format_extra,
        format_split,
        split_run,
    )
    from m4dgs.clip import Clip
    from m4dgs.core.errors import InputError

    _check_bright(bright_above, bright_top)
    opts = dict(bright_above=bright_above, bright_top=bright_top, dilate=dilate, edges=edges)
    caches: dict = {}

    def split(run, clip):
        click.echo(f"splitting {run} ...", err=True)
        return split_run(run, clip, masks_cache=caches.setdefault(str(clip.root), {}), **opts)

    try:
        # every clip opened and checked before the first (slow) split
        clips = [Clip.open(resolve_clip_dir(r, clip_dir)) for r in runs]
        if ref_run is not None:
            ref_clip = Clip.open(resolve_clip_dir(ref_run, clip_dir))
            for c in clips:
                check_comparable(ref_clip, c)
        ref = split(ref_run, ref_clip) if ref_run is not None else None
        out = [split(r, c) for r, c in zip(runs, clips)]
    except (InputError, FileNotFoundError) as e:
        raise click.ClickException(str(e)) from e
    click.echo(describe_regions(bright_above, bright_top, dilate, edges))
    for res in out:
        click.echo(f"\n{res['run']} (clip {res['clip_name']}, {res['test_frames']} test frames)\n")
        click.echo(format_split(res))
        if ref is not None:
            click.echo(f"\nagainst {ref['run']}:\n")
            click.echo(format_extra(res, ref))
    if json_path:
        mio.write_json(json_path, {"runs": out, "ref": ref})


@main.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@_runs_clip_opt
@click.option(
    "--json",
    "json_path",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also write each run's figures to this JSON file.",
)
def peaks(runs, clip_dir, json_path):
    """The largest HDR value of each run's test renders against the ground truth's largest, and
    the share of rendered values above it: highlights that ran away, which the headline HDR PSNR
    (normalised by the ground truth's maximum and clipped) does not see. A run that cannot be
    read (no renders: e.g. a failed run) is named after the table with the reason; the exit status
    is 1 only when no run could be read."""
    from eval.experiments.score import resolve_clip_dir
    from eval.inspect.peaks import format_peaks, run_peaks
    from m4dgs.clip import Clip
    from m4dgs.core.errors import InputError

    out, unread = [], []
    for r in runs:
        try:
            out.append(run_peaks(r, Clip.open(resolve_clip_dir(r, clip_dir))))
        except (InputError, FileNotFoundError) as e:
            unread.append(str(e))
    if out:
        click.echo(format_peaks(out), nl=False)
    for e in unread:
        click.echo(f"not read: {e}", err=True)
    if json_path:  # standard JSON: an infinite or NaN figure is null
        clean = [
            {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in r.items()}
            for r in out
        ]
        mio.write_json(json_path, {"runs": clean, "not_read": unread})
    if not out:
        raise click.ClickException(f"none of the {len(runs)} run(s) could be read")


@main.command("crf")
@click.argument("runs", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@click.option(
    "--clip",
    "clip_dir",
    default=None,
    type=click.Path(exists=True, file_okay=False),
    help="Clip folder for every run (default: the 'clip' entry of each RUN/run.json).",
)
@click.option(
    "--bands",
    default=6,
    show_default=True,
    type=click.IntRange(min=1),
    help="Equal log2 bands of the recorded exposure range for the signed error, dark to bright.",
)
@click.option(
    "--plot",
    "plot_path",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also draw the learned responses over the true one and their signed difference (PNG).",
)
@click.option(
    "--json",
    "json_path",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also write each run's figures (and the drawn curves) to this JSON file.",
)
def crf_cmd(runs, clip_dir, bands, plot_path, json_path):
    """Each run's learned camera response against its clip's true one: the CRF error of
    metrics.json, the exposure shift that fits the learned curve best and the error left after it
    (a curve slid along the exposure axis, i.e. a mis-set HDR scale, against a curve of another
    shape), and the signed error per band of the recorded exposure range. A run that cannot be read
    (no final model: e.g. a failed run) is named after the table with the reason; the exit status is
    1 only when no run could be read."""
    from eval.experiments.score import resolve_clip_dir
    from eval.inspect.responses import clip_ranges, format_responses, plot_responses, run_response
    from m4dgs.clip import Clip
    from m4dgs.core.errors import InputError

    out, unread, ranges = [], [], {}
    for r in runs:
        try:
            cdir = resolve_clip_dir(r, clip_dir)
            clip = Clip.open(cdir)
            key = str(Path(cdir).resolve())
            if key not in ranges:  # the recorded ranges read every training frame: once per clip
                ranges[key] = clip_ranges(clip)[1]
            out.append(run_response(r, clip, bands=bands, ranges=ranges[key]))
        except (InputError, FileNotFoundError) as e:
            unread.append(str(e))
    if out:
        click.echo(format_responses(out), nl=False)
    for e in unread:
        click.echo(f"not read: {e}", err=True)
    if out and plot_path:
        click.echo(f"wrote {plot_responses(out, plot_path)}")
    if json_path:
        mio.write_json(json_path, {"runs": out, "not_read": unread})
    if not out:
        raise click.ClickException(f"none of the {len(runs)} run(s) could be read")


@main.command("region-pairs")
@click.argument("suite")
@_out_opt
@click.option("--ref", required=True, help="Reference row.")
@click.option(
    "--rows", "row_names", required=True, help="Comma-separated rows to compare with --ref."
)
@_scenes_opt
@click.option(
    "--seeds",
    default=1,
    show_default=True,
    type=click.IntRange(min=1),
    help="Trainer seeds 0..N-1 (a pair per scene and seed).",
)
@click.option(
    "--domain",
    default="LDR-OE",
    show_default=True,
    help="Which split to difference: LDR-OE / LDR-NE (the levels pooled as the scores are), "
    "'ldr <level>' (e.g. 'ldr 0.125') or hdr.",
)
@_region_options
@click.option(
    "--against",
    default=None,
    metavar="SUITE:REF:ROW",
    help="Also print each row's change against another effect in the same root: (row - --ref) "
    "minus (ROW - REF) of SUITE, per (scene, seed) pair that both have, per region (a control's "
    "difference in differences, e.g. control-tlr-priors:full:full-tlr-0.1).",
)
@click.option(
    "--json",
    "json_path",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also write every pair's differences (and, with --against, changes) to this JSON file.",
)
def region_pairs(
    suite,
    out,
    ref,
    row_names,
    scenes,
    seeds,
    domain,
    bright_above,
    bright_top,
    dilate,
    edges,
    against,
    json_path,
):
    """Paired region differences over SUITE's (scene, seed) pairs: for each row, how its PSNR of
    each region alone and with each region left out (as `regions` splits a run) differs from
    --ref's, per pair and as the mean with its Student-t 95 % interval over the pairs (as
    `pairs` gives the scores'). Reads the runs' test renders, so it needs the suite's root.
    --against: each row's change against another suite's effect (a control's reading by region)."""
    from eval.inspect.regions import format_region_pairs, region_changes, suite_region_pairs
    from m4dgs.core.errors import InputError

    _check_bright(bright_above, bright_top)
    rows = [n.strip() for n in row_names.split(",") if n.strip()]
    base_spec = _against_spec(against)
    kw = dict(
        scenes=_scenes(scenes),
        seeds=seeds,
        domain=domain,
        bright_above=bright_above,
        bright_top=bright_top,
        dilate=dilate,
        edges=edges,
        log=lambda s: click.echo(s, err=True),
    )
    try:
        res = suite_region_pairs(suite, out, ref, rows, **kw)
        changes = None
        if base_spec is not None:
            b_suite, b_ref, b_row = base_spec
            base = suite_region_pairs(b_suite, out, b_ref, [b_row], **kw)
            changes = region_changes(res, base, b_suite, b_row)
    except (InputError, KeyError, ValueError, FileNotFoundError) as e:
        raise click.ClickException(str(e.args[0]) if isinstance(e, KeyError) else str(e)) from e
    click.echo(format_region_pairs(res), nl=False)
    if changes is not None:
        click.echo("\nChange against " + against + ":\n")
        click.echo(format_region_pairs(changes, describe=False), nl=False)

    def pairs_of(r):
        return [
            {"row": row, "scene": scene, "seed": seed, "diffs": d}
            for row, per in r["diffs"].items()
            for (scene, seed), d in per.items()
        ]

    if json_path:
        doc = {k: res[k] for k in ("domain", "ref", "regions", "missing")}
        doc["pairs"] = pairs_of(res)
        if changes is not None:
            doc["against"] = against
            doc["changes"] = pairs_of(changes)
        mio.write_json(json_path, doc)


@main.command("error-maps")
@click.argument("runs", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@click.option(
    "--out",
    "out_png",
    default=None,
    type=click.Path(dir_okay=False),
    help="The figure of one test frame to write (PNG).",
)
@click.option(
    "--video",
    "out_mp4",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also (or instead) write the same grid over every test frame of the domain as an mp4, "
    "with one colour scale for the whole video and each tile's PSNR in its caption.",
)
@click.option(
    "--fps",
    default=None,
    type=click.FloatRange(min=0.1),
    help="Frame rate of --video (default: a quarter of the clip's, about 7.5).",
)
@click.option(
    "--ref",
    "ref_run",
    default=None,
    type=click.Path(exists=True, file_okay=False),
    help="A reference run of the same scene, frames and levels: drawn beside the runs, with a row "
    "of where each run's squared error grew (red) or shrank (blue) against it.",
)
@click.option(
    "--domain",
    default=None,
    help="'ldr <level>' (a test level of the clip, e.g. 'ldr 0.125') or 'hdr' (mu-law, as the "
    "HDR PSNR). Default: the clip's first observed level.",
)
@click.option(
    "--frame",
    default=None,
    type=click.IntRange(min=0),
    help="Global index of the test frame to draw. Default: the frame where the first run's PSNR "
    "falls furthest below --ref's (without --ref: the first run's worst frame).",
)
@click.option(
    "--labels",
    default=None,
    help="Comma-separated column titles for the runs (default: their folder names).",
)
@_runs_clip_opt
def error_maps(runs, out_png, out_mp4, fps, ref_run, domain, frame, labels, clip_dir):
    """Draw one test frame of RUNS (one scene): the ground truth, each run's render, its error
    map on one colour scale and, with --ref, where its error grew or shrank against the
    reference; titles give each frame's PSNR as the scores compute it. --video: the same grid
    over every test frame."""
    from eval.inspect.errormaps import error_maps as draw
    from eval.inspect.errormaps import error_video
    from m4dgs.core.errors import InputError

    if out_png is None and out_mp4 is None:
        raise click.UsageError("give --out PNG, --video MP4 or both")
    names = None
    if labels is not None:
        names = [x.strip() for x in labels.split(",")]
        if len(names) != len(runs):
            raise click.UsageError(f"--labels: {len(names)} label(s) for {len(runs)} run(s)")
    try:
        if out_mp4 is not None:
            vid = error_video(
                runs, out_mp4, ref=ref_run, domain=domain, clip_dir=clip_dir, labels=names, fps=fps
            )
            means = ", ".join(f"{k} {sum(v) / len(v):.2f} dB" for k, v in vid["psnr"].items() if v)
            click.echo(
                f"wrote {vid['mp4']} ({len(vid['frames'])} frames, {vid['domain']}; mean PSNR "
                f"over them: {means})"
            )
            if out_png is None:
                return
        res = draw(
            runs, out_png, ref=ref_run, domain=domain, frame=frame, clip_dir=clip_dir, labels=names
        )
    except (InputError, FileNotFoundError) as e:
        raise click.ClickException(str(e)) from e
    how = ""
    if res["picked_from"] is not None:
        how = " (picked: " + ("largest PSNR drop against --ref)" if ref_run else "lowest PSNR)")
    click.echo(f"frame {res['frame']}, {res['domain']}{how}")
    for p in ([res["ref"]] if res["ref"] else []) + res["runs"]:
        d = f" ({p['d_psnr']:+.2f} against the reference)" if "d_psnr" in p else ""
        click.echo(f"  {p['label']}: {p['psnr']:.2f} dB{d}")
    click.echo(f"wrote {res['png']}")


@main.command()
@click.option(
    "--csv",
    "csv_path",
    default="results/runs.csv",
    show_default=True,
    type=click.Path(dir_okay=False),
    help="Runs CSV written by `export`, with its <name>-crf.csv and <name>-floors.csv beside it "
    "(a missing file gives a page that says the runs are pending).",
)
@click.option(
    "--out",
    "out_md",
    default="docs/results.md",
    show_default=True,
    type=click.Path(dir_okay=False),
    help="The results page to write.",
)
@click.option(
    "--figures",
    "figures_dir",
    default=None,
    type=click.Path(file_okay=False),
    help="Folder for the figures; PNGs in it named as the page's figures (<suite>_<kind>.png) that "
    "it no longer makes are removed (default: <folder of --out>/figures/<name of --out without "
    ".md>, e.g. docs/figures/results).",
)
@click.option("--no-figures", is_flag=True, help="Write no figures (and link none).")
@click.option(
    "--readme",
    default="README.md",
    show_default=True,
    type=click.Path(dir_okay=False),
    help="README whose block between <!-- results:main:start --> and <!-- results:main:end --> "
    "is replaced by the main table.",
)
@click.option("--no-readme", is_flag=True, help="Leave the README alone.")
@click.option(
    "--title",
    default="Results",
    show_default=True,
    help="The page's heading (e.g. for a page of runs on an earlier benchmark version).",
)
@click.option(
    "--notes",
    default=None,
    type=click.Path(dir_okay=False),
    help="Hand-written notes linked from the page (default: results-notes.md beside --out, "
    "when it exists).",
)
@click.option(
    "--suite",
    "suite_files",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False),
    help="YAML file of a suite of the CSV that is not built in (repeat for several): its section "
    "then shows the definition, the reference row and the row order. A CSV of only such suites "
    "gets no sections on the paper's findings and controls.",
)
def results(
    csv_path, out_md, figures_dir, no_figures, readme, no_readme, title, notes, suite_files
):
    """Regenerate the results page (every suite's tables with intervals, the paper's values and
    the agreement column, figures, findings) and the README's main table from the runs CSV."""
    from eval.report.page import render_results

    notes_given = notes is not None
    if notes is None:
        cand = Path(out_md).parent / "results-notes.md"
        notes = str(cand) if cand.exists() else None
    default_fig = str(Path(out_md).parent / "figures" / Path(out_md).stem)
    fig = None if no_figures else (figures_dir or default_fig)
    # the command written into the page regenerates it as it is
    q = shlex.quote
    cmd = f"m4dgs-eval results --csv {q(str(csv_path))} --out {q(str(out_md))}"
    if no_figures:
        cmd += " --no-figures"
    elif figures_dir and figures_dir != default_fig:
        cmd += f" --figures {q(str(figures_dir))}"
    if no_readme:
        cmd += " --no-readme"
    elif readme != "README.md":
        cmd += f" --readme {q(str(readme))}"
    if title != "Results":
        cmd += f" --title {q(title)}"
    if notes_given:
        cmd += f" --notes {q(str(notes))}"
    for f in suite_files:
        cmd += f" --suite {q(str(f))}"
    res = render_results(
        csv_path,
        out_md,
        figures_dir=fig,
        readme=None if no_readme else readme,
        notes=notes,
        command=cmd,
        title=title,
        suite_files=suite_files,
    )
    click.echo(
        f"wrote {out_md} ({len(res['suites'])} suite(s), {len(res['figures'])} figure(s))"
        + (f"; updated {res['readme']}" if res["readme"] else ""),
        err=True,
    )
    for name, pm in res["partial_metrics"].items():
        click.echo(
            f"warning: suite {name}: some scored runs lack metrics their rows report elsewhere: "
            + ", ".join(f"{k} in {h} of {n} runs" for k, (h, n) in pm.items())
            + " (scored before the metric existed, or rows written back by an older export: "
            "re-export them with `m4dgs-eval export` while their run folders exist)",
            err=True,
        )


if __name__ == "__main__":  # pragma: no cover
    main()
