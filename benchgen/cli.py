"""`benchgen`: render procedural dynamic HDR scenes into alternating-exposure clips with exact
ground truth.

benchgen make --exposures 3                      the syn-exp-3 suite at the small preset into bench/
benchgen make --suite tiny --preset tiny         the two tiny scenes (seconds each)
benchgen list                                    shipped suites and scenes
benchgen show bench/syn-exp-3/<scene>            summary + contact sheet PNG
benchgen export bench/syn-exp-3/<scene> --format nerfies --out DIR   in another method's layout
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import click

from benchgen.exposure import SCHEDULES
from m4dgs.core.errors import InputError, ReportingGroup
from m4dgs.core.executor_options import executor_options
from m4dgs.footage_options import prior_file_options

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# Each command imports the modules it runs when it runs: `benchgen --help` and `benchgen list` stay
# free of torch and the renderer stack (~2 s), and tests can replace benchgen.make's functions.


def _levels(text):
    if text is None:
        return None
    from .exposure import parse_levels

    return parse_levels(text)


@click.group(cls=ReportingGroup, context_settings={"help_option_names": ["-h", "--help"]})
def main():
    """Synthetic benchmark generator for Mono4DGS-HDR (Mitsuba 3 renders, exact ground truth,
    degraded priors)."""


# benchgen.priors.PROFILES (not imported here: it pulls scipy into every --help)
BUILTIN_PRIORS = ("oracle", "realistic", "harsh", "realistic-exact-depth", "realistic-exact-motion")


class PriorsParam(click.ParamType):
    """A built-in prior profile name, or an existing .yaml / .yml / .json profile file (read and
    checked, so that a bad file fails before anything renders)."""

    name = "PROFILE"

    def convert(self, value, param, ctx):
        v = str(value)
        if v in BUILTIN_PRIORS:
            return v
        from .priors import PROFILE_FILE_SUFFIXES, load_profile

        if not v.endswith(PROFILE_FILE_SUFFIXES):
            self.fail(
                f"{v!r} is neither a built-in profile ({', '.join(BUILTIN_PRIORS)}) nor a "
                ".yaml / .json profile file",
                param,
                ctx,
            )
        try:
            load_profile(v)  # a missing file is named by its read error
        except InputError as e:
            self.fail(str(e), param, ctx)
        return v


@main.command()
@click.option(
    "--suite",
    default="syn-exp-3",
    show_default=True,
    help="Built-in suite name (see `benchgen list`) or a path to a suite YAML file.",
)
@click.option("--scenes", default=None, help="Comma-separated subset of the suite's scene names.")
@click.option(
    "--exposures",
    "num_exposures",
    type=click.Choice(["2", "3"]),
    default=None,
    help="Number of observed exposure levels: 3 = {0.125, 2, 32} (novel {0.5, 8}); 2 = two "
    "observed levels "
    "(docs/exposure.md). Default: the suite's levels.",
)
@click.option("--observed", default=None, help="Override the observed levels, e.g. '0.125,2,32'.")
@click.option("--novel", default=None, help="Override the novel (test-only) levels, e.g. '0.5,8'.")
@click.option(
    "--schedule",
    type=click.Choice(list(SCHEDULES)),
    default=None,
    help="Exposure schedule of the training frames (default: the suite's, normally alternating).",
)
@click.option(
    "--preset",
    type=click.Choice(["tiny", "small", "paper"]),
    default="small",
    show_default=True,
    help="Clip size: tiny 72x40 (tests), small 216x120 (CPU default), paper 864x480.",
)
@click.option(
    "--priors",
    type=PriorsParam(),
    default="realistic",
    show_default=True,
    help="Prior degradation profile (docs/priors.md): oracle (exact), realistic, harsh, "
    "realistic with the depth (realistic-exact-depth) or the tracks and flow "
    "(realistic-exact-motion) exact, or a profile file (.yaml / .json: a base profile and the "
    "parameters that differ from it, e.g. `base: realistic` and `depth_disp_shift: 0.08`).",
)
@click.option(
    "--out",
    default="bench",
    show_default=True,
    type=click.Path(file_okay=False),
    help="Output root; clips go to OUT/<suite>/<scene>/.",
)
@click.option(
    "--jobs", default=1, show_default=True, type=int, help="Clips rendered in parallel (processes)."
)
@click.option(
    "--seed", default=0, show_default=True, type=int, help="Seed of schedules, jitter and priors."
)
@click.option(
    "--force", is_flag=True, help="Regenerate finished clips (otherwise they are skipped)."
)
@click.option(
    "--crf",
    default="hdrnerf",
    show_default=True,
    help="Camera response the clips are tone-mapped with (docs/exposure.md): hdrnerf (the "
    "paper's), "
    "srgb-shoulder, aces-filmic, hdrnerf-g1.8, hdrnerf-g2.4, hdrnerf-rgb. Recorded in clip.json; "
    "give clips of another response their own --out.",
)
@click.option(
    "--spp",
    type=click.IntRange(min=1),
    default=None,
    help="Samples per pixel of the HDR renders (default: the preset's, tiny 64 / small 64 / paper "
    "1024; the "
    "low-discrepancy sampler rounds to a power of 4). At small, 256 lowers the render noise 2-4x "
    "and "
    "takes ~4x longer (docs/rendering.md).",
)
@click.option(
    "--allow-misplaced",
    is_flag=True,
    help="Keep clips that miss their exposure-placement targets (median of the middle level in "
    "[0.35, 0.65], highlights observed at the shortest level, saturation at the longest, dark "
    "pixels "
    "at the shortest; docs/exposure.md) with a warning instead of failing.",
)
@click.option(
    "--reuse-renders",
    "reuse_root",
    default=None,
    type=click.Path(file_okay=False, exists=True),
    help="Output root of earlier `benchgen make` runs: a scene whose finished clip there "
    "(ROOT/<any suite>/<scene>) has the same render (scene spec, preset, samples, generator "
    "version) takes its ground truth and HDR frames instead of rendering again, e.g. the clips "
    "of another --crf, --schedule or --priors. Without it, clips under --out are reused.",
)
@executor_options(
    where="Where the HDR frames render: local (this process, or --jobs clip processes), ray "
    "(frame-range render tasks on a Ray cluster: --address, or one started on this machine) or "
    "slurm (the render tasks as job arrays through submitit); this process then makes every clip "
    "from the rendered frames, and the clips are the same bytes as local ones. docs/cluster.md.",
    cpus="ray and slurm: CPU threads of one render task (default 2): Ray's num_cpus, Slurm's "
    "--cpus-per-task and Mitsuba's threads in the task. A task also asks for one GPU when "
    "BENCHGEN_MI_VARIANT names a CUDA variant of Mitsuba (e.g. cuda_ad_rgb).",
    gpus=None,
    task="render task",
)
@click.option(
    "--frames-per-task",
    type=click.IntRange(min=1),
    default=None,
    help="ray and slurm: frames of one render task (default 8; the held-out views go in tasks of "
    "as many test frames). Smaller tasks spread a clip over more workers; each task loads the "
    "scene once.",
)
@click.option(
    "--render-only",
    is_flag=True,
    help="Only render the HDR frames and held-out views (into each clip's .benchgen/hdr_unit/, as "
    "render tasks on --executor; local: --jobs task processes), print each clip's render seconds "
    "a frame, and stop; the same command without it then makes the clips from those frames. For "
    "rendering on GPU or render nodes and making the clips (ray casts, priors) elsewhere.",
)
def make(
    suite,
    scenes,
    num_exposures,
    observed,
    novel,
    schedule,
    preset,
    priors,
    out,
    jobs,
    seed,
    force,
    crf,
    spp,
    allow_misplaced,
    reuse_root,
    frames_per_task,
    render_only,
    **executor,
):
    """Generate the clips of a suite (resumable: finished clips and frames are skipped). With
    --executor ray or slurm the HDR frames and views render as tasks on a cluster and this process
    makes the clips from them (docs/cluster.md)."""
    from m4dgs.core.crf import CLIP_CRFS

    from .make import make_suite

    if crf not in CLIP_CRFS:
        raise click.BadParameter(
            f"{crf!r} is not a clip response; choose one of {', '.join(CLIP_CRFS)}",
            param_hint="--crf",
        )

    from .make import PlacementError

    ex = _render_executor(executor, jobs, frames_per_task, render_only)
    if render_only and executor["executor"] == "local":
        jobs = 1  # the --jobs render processes are the executor's
    try:
        paths = make_suite(
            suite,
            out,
            preset=preset,
            scenes=None if scenes is None else [s.strip() for s in scenes.split(",") if s.strip()],
            priors=priors,
            schedule=schedule,
            num_exposures=None if num_exposures is None else int(num_exposures),
            observed=_levels(observed),
            novel=_levels(novel),
            seed=seed,
            jobs=jobs,
            force=force,
            spp=spp,
            crf=crf,
            allow_misplaced=allow_misplaced,
            reuse_root=reuse_root,
            executor=ex,
            frames_per_task=frames_per_task,
            render_only=render_only,
        )
    except PlacementError as e:
        raise click.ClickException(str(e)) from None
    finally:
        if ex is not None:
            ex.close()
    if render_only:
        return  # make_suite summarised each clip's renders
    for p in paths:
        click.echo(str(p))


def _render_executor(opts: dict, jobs: int, frames_per_task, render_only: bool = False):
    """The executor of `benchgen make`'s --executor options, None for local (the clips render in
    this process or in --jobs clip processes, as they always did) unless render_only (then a
    local executor of --jobs processes of --cpus-per-job threads runs the render tasks); a
    misplaced option is a click.UsageError naming it."""
    from m4dgs.core.executor_options import make_executor_from

    if opts["executor"] == "local" and not render_only:
        local_only = [
            o
            for o, v in (
                ("--cpus-per-job", opts["cpus_per_job"]),
                ("--frames-per-task", frames_per_task),
            )
            if v is not None
        ]
        if local_only:
            raise click.UsageError(
                f"{', '.join(local_only)} appl{'ies' if len(local_only) == 1 else 'y'} to "
                "--executor ray and slurm (render tasks) and to --render-only; the local "
                "executor renders each clip in one process (--jobs clips at once)"
            )
    # a task renders on the GPU when the Mitsuba variant is a CUDA one (benchgen.render)
    cuda = os.environ.get("BENCHGEN_MI_VARIANT", "").startswith("cuda")
    local = opts["executor"] == "local"
    # checks the misplaced options (a local --jobs 0 stays what it was: one clip at a time)
    ex = make_executor_from(opts, max(1, jobs) if local else jobs, "cuda" if cuda else "cpu")
    if local and not render_only:
        ex.close()
        return None
    return ex


@main.command("from-hdr")
@click.option(
    "--hdr",
    "hdr_dir",
    required=True,
    type=click.Path(file_okay=False, exists=True),
    help="Folder of linear HDR frames (.exr or .hdr, sorted by name with numbers in numeric "
    "order), e.g. one of the HDR videos the paper's Syn-Exp-3 was made from.",
)
@click.option(
    "--out",
    required=True,
    type=click.Path(file_okay=False),
    help="Clip folder to write (written beside it first and moved into place when complete).",
)
@click.option(
    "--depth",
    default=None,
    type=click.Path(exists=True),
    help="Depth prior of the training frames (the PNGs of OUT/input/ldr/, which --ldr-only "
    "writes first): one [T, H, W] .npy/.npz or a folder with one .npy/.npz/.exr/16-bit "
    ".png/.tif per frame, from a monocular depth model; one map per HDR frame also works (the "
    "training ones are taken), as does one per HDR file of --hdr when --every / --max-frames drop "
    "frames. Required unless --ldr-only.",
)
@prior_file_options
@click.option(
    "--gt-flow",
    default=None,
    type=click.Path(file_okay=False, exists=True),
    help="Flow computed on the ground-truth HDR frames between consecutive training frames "
    "(positions a_b and b_a, the --flow layout; e.g. RAFT, as the paper did), written as the "
    "clip's gt/flow.npz for HDR-TAE. Default: eval computes DIS flow on the ground truth.",
)
@click.option(
    "--exposures",
    "num_exposures",
    type=click.Choice(["2", "3"]),
    default="3",
    show_default=True,
    help="Observed exposure levels: 3 = {0.125, 2, 32} (novel {0.5, 8}), 2 = two levels "
    "(docs/exposure.md).",
)
@click.option("--observed", default=None, help="Override the observed levels, e.g. '0.125,2,32'.")
@click.option("--novel", default=None, help="Override the novel (test-only) levels, e.g. '0.5,8'.")
@click.option(
    "--schedule",
    type=click.Choice(list(SCHEDULES)),
    default="alternating",
    show_default=True,
    help="Exposure schedule of the training frames.",
)
@click.option(
    "--crf",
    default="hdrnerf",
    show_default=True,
    help="Camera response the frames are tone-mapped with (docs/exposure.md): hdrnerf (the "
    "paper's), srgb-shoulder, aces-filmic, hdrnerf-g1.8, hdrnerf-g2.4, hdrnerf-rgb.",
)
@click.option(
    "--scale",
    type=float,
    default=None,
    help="HDR scale (the frames are multiplied by it before tone mapping). Default: chosen for "
    "the exposure-placement targets, as benchgen make does (docs/exposure.md).",
)
@click.option(
    "--every",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Keep every n-th HDR frame.",
)
@click.option(
    "--max-frames",
    type=click.IntRange(min=6),
    default=None,
    help="Keep at most this many HDR frames.",
)
@click.option(
    "--width",
    type=click.IntRange(min=16),
    default=None,
    help="Resize the frames to this width (area averaging; the height keeps the aspect ratio). "
    "Default: their own size.",
)
@click.option(
    "--fps",
    type=click.FloatRange(min=0, min_open=True),
    default=30.0,
    show_default=True,
    help="Frame rate written to clip.json.",
)
@click.option("--name", default=None, help="Clip name (default: the --out folder name).")
@click.option(
    "--seed",
    default=0,
    show_default=True,
    type=int,
    help="Seed of the random schedules (unused by alternating).",
)
@click.option(
    "--ldr-only",
    is_flag=True,
    help="Write only the training frames (OUT/input/ldr/, no clip.json) for the depth model and "
    "tracker to run on; then run again with --depth.",
)
@click.option(
    "--allow-misplaced",
    is_flag=True,
    help="Keep a clip that misses its exposure-placement targets with a warning instead of "
    "failing.",
)
@click.option("--force", is_flag=True, help="Replace a clip already at --out.")
def from_hdr(
    hdr_dir,
    out,
    depth,
    depth_kind,
    tracks,
    visibility,
    track_pixel_centre,
    flow,
    gt_flow,
    num_exposures,
    observed,
    novel,
    schedule,
    crf,
    scale,
    every,
    max_frames,
    width,
    fps,
    name,
    seed,
    ldr_only,
    allow_misplaced,
    force,
):
    """An evaluation clip from an HDR video, the paper's Syn-Exp-3 recipe: even frames train,
    odd frames test, the training frames tone-mapped at alternating exposures, the test frames at
    every observed and novel exposure, the HDR frames kept as ground truth (docs/clip-format.md,
    "From an HDR video"). Prints a summary of the clip and the next commands (m4dgs train --clip
    OUT, m4dgs-eval score RUN) on stderr, and the clip's path on stdout."""
    from pathlib import Path as P

    from .from_hdr import HdrVideoOptions, clip_from_hdr_video
    from .make import PlacementError

    opt = HdrVideoOptions(
        hdr=P(hdr_dir),
        depth=None if depth is None else P(depth),
        depth_kind=depth_kind,
        tracks=tracks,
        visibility=visibility,
        track_pixel_centre=float(track_pixel_centre),
        flow=flow,
        gt_flow=None if gt_flow is None else P(gt_flow),
        exposures=int(num_exposures),
        observed=_levels(observed),
        novel=_levels(novel),
        schedule=schedule,
        crf=crf,
        scale=scale,
        every=every,
        max_frames=max_frames,
        width=width,
        fps=fps,
        name=name,
        seed=seed,
        ldr_only=ldr_only,
        allow_misplaced=allow_misplaced,
    )
    try:
        path = clip_from_hdr_video(out, opt, force=force)
    except PlacementError as e:
        raise click.ClickException(str(e)) from None
    if ldr_only:
        click.echo(
            f"{path}/input/ldr: the training frames; run a depth model (and a tracker) on them, "
            "then run this command again with --depth"
        )
    else:
        from .from_hdr import summary_lines

        # the summary and the next steps on stderr, the clip's path alone on stdout (for scripts)
        for line in summary_lines(path):
            click.echo(line, err=True)
        click.echo(str(path))


@main.command("list")
def list_cmd():
    """List the shipped suites and scene specs."""
    from .suite import builtin_suites, load_suite

    for name in builtin_suites():
        s = load_suite(name)
        click.echo(
            f"suite {s.name}: {len(s.scenes)} scenes, observed {s.observed}, novel {s.novel}, "
            f"{s.schedule}"
        )
        for p in s.scenes:
            click.echo(f"  - {p.stem}")


@main.command()
@click.argument("clip", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--sheet/--no-sheet", default=True, show_default=True, help="Write CLIP/contact_sheet.png."
)
def show(clip, sheet):
    """Print a clip's summary and write a contact sheet (LDR per level, HDR, depth, flow, tracks,
    masks)."""
    from m4dgs.clip import Clip

    from .show import contact_sheet, summary

    c = Clip.open(clip)
    click.echo(json.dumps(summary(c), indent=2))
    if sheet:
        p = contact_sheet(c, Path(clip) / "contact_sheet.png")
        click.echo(f"contact sheet: {p}")


@main.command("export")
@click.argument("clip", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "--format",
    "fmt",
    required=True,
    type=click.Choice(["mono4dgs-hdr", "nerfies"]),
    help="mono4dgs-hdr: the official Mono4DGS-HDR code's layout (images/, exposures.json, "
    "test/, test_ne/, train_exr/, test_exr/). nerfies: the Nerfies / DyCheck layout (dataset.json, "
    "metadata.json, scene.json, camera/, rgb/1x/; the held-out views as validation cameras). "
    'What maps where: docs/clip-format.md, "Other formats".',
)
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Folder to write (written elsewhere first and moved into place when complete).",
)
@click.option("--force", is_flag=True, help="Replace a folder that is not empty at --out.")
@click.option(
    "--cameras",
    "cameras",
    default=None,
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="nerfies only: estimated cameras to export instead of the ground truth's, an m4dgs "
    "cameras.json covering at least the training frames (e.g. RUN/cameras_ba.json, the "
    "camera initialisation of `m4dgs train`). The other images' cameras, depths and points are "
    "the truth's carried into that frame by the similarity fitted on the training cameras.",
)
def export(clip, fmt, out_dir, force, cameras):
    """Write CLIP in the layout another method reads: frames, exposures, test frames at every
    level, HDR ground truth, cameras, depth and tracks where the layout has a place for them
    (`m4dgs import-clip --format` reads it back). The cameras are the ground truth's unless
    --cameras gives estimated ones."""
    from .formats import export_clip

    click.echo(str(export_clip(clip, fmt, out_dir, force=force, cameras=cameras)))


if __name__ == "__main__":
    sys.exit(main())
