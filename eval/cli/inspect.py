"""`m4dgs-eval inspect pairs|repeats|regions|region-pairs|peaks|highlights|crf|error-maps`: look
closer at runs (eval.inspect). The old flat names are hidden aliases (eval.cli)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from eval.cli._options import out_opt, parse_names, read_csv_opt, runs_clip_opt, scenes_opt
from eval.inspect.pairs import DEFAULT_METRICS as DEFAULT_PAIR_METRICS
from m4dgs.core import io as mio


@click.group(
    "inspect",
    short_help="Look closer at runs: pairs, repeats, regions, peaks, crf, ...",
    context_settings={"help_option_names": ["-h", "--help"]},
)
def group():
    """Look closer at runs: paired differences, repeats, where the error sits,
    error maps, HDR peaks, learned camera responses."""


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


@group.command()
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
    help="Comma-separated rows to compare with --ref (default: every other trained row of the "
    "suite in the CSV; the 2D calibration rows, e.g. flow-merge, only when named here).",
)
@click.option(
    "--metrics",
    default=",".join(DEFAULT_PAIR_METRICS),
    show_default=True,
    help="Comma-separated metric columns of the CSV (e.g. hdr_tce, track_epe, mask_iou).",
)
@read_csv_opt
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


@group.command()
@click.argument("side_a", metavar="SUITE_A:ROW")
@click.argument("side_b", metavar="SUITE_B:ROW")
@click.option(
    "--metrics",
    default=None,
    help="Comma-separated metric columns to compare (default: every quality column of the CSV, "
    "i.e. all but training minutes, FPS, Gaussian count and peak memory).",
)
@read_csv_opt
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


@group.command()
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
@runs_clip_opt
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
    from eval.experiments.run_files import resolve_clip_dir
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


# --json of the commands that read run folders one by one (peaks, highlights)
runs_json_opt = click.option(
    "--json",
    "json_path",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also write each run's figures to this JSON file.",
)


def _json_clean(v):
    """v with every infinite or NaN float as None and dict keys as strings (standard JSON)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {str(k): _json_clean(x) for k, x in v.items()}
    return v


def _each_run(runs, clip_dir, read, fmt, json_path) -> None:
    """read(run, clip) for every run folder (its clip: clip_dir or run.json's), fmt(results)
    printed as one table; a run that cannot be read is named on stderr with the reason, --json gets
    {"runs", "not_read"}, and the command fails only when no run could be read."""
    from eval.experiments.run_files import resolve_clip_dir
    from m4dgs.clip import Clip
    from m4dgs.core.errors import InputError

    out, unread = [], []
    for r in runs:
        try:
            out.append(read(r, Clip.open(resolve_clip_dir(r, clip_dir))))
        except (InputError, FileNotFoundError) as e:
            unread.append(str(e))
    if out:
        click.echo(fmt(out), nl=False)
    for e in unread:
        click.echo(f"not read: {e}", err=True)
    if json_path:
        mio.write_json(json_path, {"runs": [_json_clean(r) for r in out], "not_read": unread})
    if not out:
        raise click.ClickException(f"none of the {len(runs)} run(s) could be read")


@group.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@runs_clip_opt
@runs_json_opt
def peaks(runs, clip_dir, json_path):
    """The largest HDR value of each run's test renders against the ground truth's largest, and
    the share of rendered values above it: highlights that ran away, which the headline HDR PSNR
    (normalised by the ground truth's maximum and clipped) does not see. A run that cannot be
    read (no renders: e.g. a failed run) is named after the table with the reason; the exit status
    is 1 only when no run could be read."""
    from eval.inspect.peaks import format_peaks, run_peaks

    _each_run(runs, clip_dir, run_peaks, format_peaks, json_path)


@group.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@runs_clip_opt
@click.option(
    "--split",
    type=click.Choice(["test", "train"]),
    default="test",
    show_default=True,
    help="Score the test renders (as metrics.json does) or the training renders (also split by "
    "each frame's exposure).",
)
@click.option(
    "--max-code",
    type=click.IntRange(1, 254),
    default=254,
    show_default=True,
    help="Count only pixels the shortest exposure shows at this code or below in every channel "
    "(254: every unclipped one, as metrics.json). Near clipping one code spans a wide range of "
    "HDR values (code 254 about 3x with the benchmark's response), so e.g. 250 keeps the pixels "
    "it measures finely.",
)
@runs_json_opt
def highlights(runs, clip_dir, split, max_code, json_path):
    """The highlights only exposure fusion recovers (pixels the longest exposure saturates and
    the shortest measures), scored on each run's test or training renders: the error in stops and
    the peak ratio (render max / truth max over those pixels, geometric mean over frames). On the
    training frames, whose own pixels measure the highlight, a low peak ratio is a fit the model
    does not make rather than a highlight the test frame's neighbours do not show. A run that
    cannot be read is named after the table with the reason; the exit status is 1 only when no
    run could be read."""
    from eval.inspect.highlights import format_highlights, run_highlights

    def read(run, clip):
        return run_highlights(run, clip, split, max_code)

    _each_run(runs, clip_dir, read, format_highlights, json_path)


@group.command("crf")
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
    from eval.experiments.run_files import resolve_clip_dir
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


@group.command("region-pairs")
@click.argument("suite")
@out_opt
@click.option("--ref", required=True, help="Reference row.")
@click.option(
    "--rows", "row_names", required=True, help="Comma-separated rows to compare with --ref."
)
@scenes_opt
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
        scenes=parse_names(scenes),
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


@group.command("error-maps")
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
@runs_clip_opt
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
