"""`m4dgs`: train Mono4DGS-HDR on a clip, render a run, export Gaussians.

m4dgs train --clip bench/syn-exp-3/<scene> --preset small --variant full --out runs/<scene>/full
m4dgs render runs/<scene>/full --videos
m4dgs export-ply runs/<scene>/full --frame 10 --out scene.ply
m4dgs variants --preset paper
m4dgs import-clip --frames my-video/ --exposures times.txt --depth depth/ --out clips/mine
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import click

from m4dgs.core.errors import ReportingGroup
from m4dgs.core.lock import FolderLock
from m4dgs.footage_options import prior_file_options

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# Each command imports the modules it runs when it runs: `m4dgs --help` and a mistyped option answer
# in a few hundredths of a second instead of loading torch and the trainer (~2 s).


def _parse_sets(sets):
    out = {}
    for s in sets:
        if "=" not in s:
            raise click.BadParameter(f"expected KEY=VALUE, got {s!r}", param_hint="--set")
        k, v = s.split("=", 1)
        out[k.strip()] = v.strip()
    return out


@click.group(cls=ReportingGroup, context_settings={"help_option_names": ["-h", "--help"]})
def main():
    """Mono4DGS-HDR: 4D HDR Gaussian splatting from unposed alternating-exposure monocular video."""


@main.command()
@click.option(
    "--clip",
    "clip_dir",
    required=True,
    type=click.Path(exists=True, file_okay=False),
    help="Clip folder (clip.json, input/, priors/; see docs/clip-format.md). Ground truth is "
    "never read.",
)
@click.option(
    "--preset",
    type=click.Choice(["tiny", "small", "paper"]),
    default="small",
    show_default=True,
    help="Iteration counts and sizes: tiny (tests, seconds), small (CPU, minutes), paper (4K + "
    "11K iterations).",
)
@click.option(
    "--variant",
    default="full",
    show_default=True,
    help="Full method, a paper ablation or an adapted baseline (see `m4dgs variants`).",
)
@click.option(
    "--out",
    "out_dir",
    default=None,
    type=click.Path(file_okay=False),
    help="Run folder. Default: runs/<clip name>/<variant>.",
)
@click.option(
    "--set",
    "sets",
    multiple=True,
    metavar="KEY=VALUE",
    help="Config override by dotted path, repeatable, e.g. --set stage1.iterations=500 --set "
    "exposure.perturb_ev=0.5.",
)
@click.option(
    "--device",
    default="auto",
    show_default=True,
    help="auto (CUDA when available), cpu, cuda, cuda:1 ...",
)
@click.option(
    "--backend",
    type=click.Choice(["auto", "gsplat", "cpu", "torch"]),
    default=None,
    help="Rasterizer backend (default from the config: auto = gsplat on CUDA, C++ on CPU).",
)
@click.option(
    "--force", is_flag=True, help="Delete an existing run folder first (otherwise it is resumed)."
)
@click.option("--quiet", is_flag=True, help="No progress bars.")
@click.option(
    "--threads",
    default=None,
    type=click.IntRange(min=1),
    help="CPU threads to use (default: every CPU of this process). torch's small operations run "
    "on one of them and the compiled rasterizer on all, the fastest split measured "
    "(docs/performance.md); the run records both counts.",
)
def train(clip_dir, preset, variant, out_dir, sets, device, backend, force, quiet, threads):
    """Train on a clip: camera init, stage 1, video-to-world, stage 2, renders. Resumes an
    interrupted run."""
    from m4dgs.core.threads import threads_for
    from m4dgs.training.pipeline import train as run_train
    from m4dgs.training.variants import VARIANTS

    if variant not in VARIANTS:
        raise click.BadParameter(
            f"unknown variant {variant!r}; known: {', '.join(VARIANTS)}", param_hint="--variant"
        )
    out = Path(out_dir) if out_dir else Path("runs") / Path(clip_dir).name / variant
    if force and out.exists():
        with FolderLock(out):  # never delete a run another process is writing
            shutil.rmtree(out)
    with threads_for(threads, device):
        p = run_train(
            clip_dir,
            out,
            preset=preset,
            variant=variant,
            overrides=_parse_sets(sets),
            device=device,
            progress=not quiet,
            backend=backend,
        )
    click.echo(str(p))


@main.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False))
@click.option("--force", is_flag=True, help="Re-render files that exist (otherwise they are kept).")
@click.option("--overwrite", is_flag=True, hidden=True, help="Old name of --force.")
@click.option(
    "--videos/--no-videos",
    default=False,
    show_default=True,
    help="Also write fix-view-change-time, fix-time-change-view and exposure-sweep videos (mp4).",
)
@click.option(
    "--tracks/--no-tracks",
    default=False,
    show_default=True,
    help="Also write induced 2D/3D tracks.",
)
@click.option(
    "--device",
    default="auto",
    show_default=True,
    help="Device to render on: auto (CUDA when available), cpu, cuda, cuda:1 ...",
)
def render(run_dir, force, overwrite, videos, tracks, device):
    """Render the train/test frames of a run (HDR EXR, LDR PNG at every level, depth) and optional
    videos."""
    from m4dgs.core.device import resolve_device
    from m4dgs.outputs.render import render_run

    if overwrite:
        click.echo("warning: --overwrite is now --force", err=True)
    device = str(resolve_device(device))
    n = render_run(run_dir, overwrite=force or overwrite, device=device)
    views = f" and {n['views']} held-out view frames" if n.get("views") else ""
    click.echo(f"rendered {n['train']} train and {n['test']} test frames{views}")
    if videos or tracks:
        from m4dgs.outputs.videos import render_tracks, render_videos

        if videos:
            for p in render_videos(run_dir, device=device):
                click.echo(str(p))
        if tracks:
            for p in render_tracks(run_dir, device=device):
                click.echo(str(p))


@main.command("export-ply")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--frame",
    "g",
    default=0,
    show_default=True,
    type=int,
    help="Global frame index whose time is exported.",
)
@click.option(
    "--exposure",
    default=None,
    type=float,
    help="Exposure dt used to bake the learned tone mapper into LDR colours (default: the unit "
    "exposure 1).",
)
@click.option(
    "--out", "out_path", required=True, type=click.Path(dir_okay=False), help="Output .ply file."
)
def export_ply_cmd(run_dir, g, exposure, out_path):
    """Export the Gaussians at one time as a standard 3DGS .ply (opens in common splat viewers)."""
    from m4dgs.outputs.export import export_run_ply

    p = export_run_ply(run_dir, g, out_path, exposure=exposure)
    click.echo(str(p))


@main.command()
@click.argument("target", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to listen on. Only this machine can connect by default; another address (e.g. "
    "0.0.0.0) lets anyone on that network connect.",
)
@click.option(
    "--port",
    default=8080,
    show_default=True,
    type=click.IntRange(1, 65535),
    help="Port to listen on (the next free one when it is taken).",
)
@click.option(
    "--device",
    default="auto",
    show_default=True,
    help="Device to render a run on: auto (CUDA when available), cpu, cuda, cuda:1 ...",
)
def view(target, host, port, device):
    """Interactive browser viewer of a run folder (free camera, time, exposure, display modes,
    ground truth) or of a clip folder (frames, priors, ground truth); docs/viewer.md."""
    from m4dgs.viewer.server import open_target
    from m4dgs.viewer.web import exposure_warning

    warning = exposure_warning(host)
    if warning:
        click.echo(warning, err=True)
    viewer = open_target(target, host=host, port=port, device=device)
    click.echo(
        f"m4dgs view: http://{'localhost' if host in ('127.0.0.1', '::1') else host}:"
        f"{viewer.port}  (Ctrl-C to stop)"
    )
    viewer.serve()


@main.command()
@click.option(
    "--preset",
    type=click.Choice(["tiny", "small", "paper"]),
    default="small",
    show_default=True,
    help="Preset whose iteration budgets are listed.",
)
def variants(preset):
    """List the variants (full method, ablations, adapted baselines) with their stage-1 / stage-2 /
    total iterations under a preset. Every variant gets full's total; one without stage 1 spends it
    in stage 2."""
    from m4dgs.training.variants import VARIANTS, budget, describe

    click.echo(f"{'variant':24s} {'stage1':>7s} {'stage2':>7s} {'total':>7s}  (preset {preset})")
    for name in VARIANTS:
        s1, s2, tot = budget(preset, name)
        click.echo(f"{name:24s} {s1:7d} {s2:7d} {tot:7d}  {describe(name)}")


@main.command("import-clip")
@click.argument(
    "source",
    required=False,
    type=click.Path(exists=True, file_okay=False, path_type=Path),
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["footage", "mono4dgs-hdr", "nerfies"]),
    default="footage",
    show_default=True,
    help="footage: your own frames (--frames or --video) and exposure times. mono4dgs-hdr: the "
    "folder SOURCE in the official Mono4DGS-HDR code's layout (the paper's preprocessed "
    "Syn-Exp / Real-Exp data; images/, exposures.json, test/, test_ne/, train_exr/, test_exr/). "
    "nerfies: the folder SOURCE in the Nerfies / DyCheck layout (dataset.json, metadata.json, "
    "camera/, rgb/<f>x/). The folder's depth and tracks are kept; --depth and --tracks replace "
    'them (docs/clip-format.md, "Other formats").',
)
@click.option(
    "--frames",
    default=None,
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    help="Folder of frames (PNG, JPEG, TIFF, EXR; sorted by name with numbers in order; more than "
    "8 bits are rounded to 8). Give this or --video.",
)
@click.option(
    "--video",
    default=None,
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Video file (read with ffmpeg). Give this or --frames.",
)
@click.option(
    "--exposures",
    default=None,
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Exposure times: one number per frame (e.g. 0.004 or 1/250), or 'name value' lines, or "
    "a JSON list / {name: value}. Default: the EXIF ExposureTime of every frame.",
)
@click.option(
    "--depth",
    default=None,
    type=click.Path(exists=True, path_type=Path),
    help="Depth prior (required): one [T, H, W] .npy/.npz, or a folder with one .npy/.npz/.exr/"
    "16-bit .png/.tif per frame, from a monocular depth model; any scale.",
)
@prior_file_options
@click.option(
    "--every",
    default=1,
    show_default=True,
    type=click.IntRange(min=1),
    help="Keep every n-th frame.",
)
@click.option(
    "--max-frames", default=None, type=click.IntRange(min=3), help="Keep at most this many frames."
)
@click.option(
    "--width",
    default=None,
    type=click.IntRange(min=16),
    help="Resize the frames to this width, the height keeping the aspect ratio (the paper trains "
    "at 864x480; training time grows with the pixel count). Tracks and flow given at the "
    "original size are scaled with them; depth is resized at any size. Default: the frames' own "
    "size.",
)
@click.option(
    "--fps",
    default=None,
    type=click.FloatRange(min=0, min_open=True),
    help="Frame rate written to clip.json (videos of the run play at it). Default: 30, or the "
    "exported clip's own for a folder written by `benchgen export`.",
)
@click.option("--name", default=None, help="Clip name (default: the --out folder name).")
@click.option(
    "--split",
    type=click.Choice(["all", "alternate"]),
    default="all",
    show_default=True,
    help="all: every frame trains (nothing to score but the training frames, the paper's "
    "Real-Exp-2). alternate: even frames train and odd frames are held out as test frames, "
    "scored at the exposure they were captured at (LDR-OE; the paper's Real-Exp-3); --depth may "
    "then hold a map per frame (the training ones are taken), --tracks and --flow refer to the "
    "training frames.",
)
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Clip folder to write (written elsewhere first and moved into place when complete).",
)
@click.option("--force", is_flag=True, help="Replace a clip already at --out.")
def import_clip_cmd(
    source,
    fmt,
    frames,
    video,
    exposures,
    depth,
    depth_kind,
    tracks,
    visibility,
    track_pixel_centre,
    flow,
    every,
    max_frames,
    width,
    fps,
    name,
    split,
    out_dir,
    force,
):
    """Make a clip from your own footage: frames or a video, exposure times, a depth prior and
    optionally tracks and flow (docs/clip-format.md, "Your own footage"). Then: m4dgs train --clip
    OUT. With --format mono4dgs-hdr or nerfies: the dataset folder SOURCE in that layout."""
    from m4dgs.core.errors import InputError
    from m4dgs.footage import ImportOptions, import_clip

    if fmt != "footage":
        given = [
            n
            for n, v in (("--frames", frames), ("--video", video), ("--exposures", exposures))
            if v is not None
        ]
        if source is None or given or every != 1 or max_frames or width or split != "all":
            raise InputError(
                f"--format {fmt}: give the dataset folder as SOURCE, without --frames, --video, "
                "--exposures, --every, --max-frames, --width or --split (the folder has them)"
            )
        from m4dgs.footage_formats import import_format

        opt = ImportOptions(
            depth=depth,
            depth_kind=depth_kind,
            tracks=tracks,
            visibility=visibility,
            track_pixel_centre=float(track_pixel_centre),
            flow=flow,
            fps=fps,
            name=name,
        )
        click.echo(str(import_format(fmt, source, out_dir, opt, force=force)))
        return
    if source is not None:
        raise InputError(f"{source}: a folder argument needs --format mono4dgs-hdr or nerfies")
    opt = ImportOptions(
        frames=frames,
        video=video,
        every=every,
        max_frames=max_frames,
        width=width,
        exposures=exposures,
        depth=depth,
        depth_kind=depth_kind,
        tracks=tracks,
        visibility=visibility,
        track_pixel_centre=float(track_pixel_centre),
        flow=flow,
        fps=30.0 if fps is None else fps,
        name=name,
        split=split,
    )
    p = import_clip(out_dir, opt, force=force)
    click.echo(str(p))


if __name__ == "__main__":
    sys.exit(main())
