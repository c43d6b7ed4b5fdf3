"""`m4dgs-eval score RUN` and `m4dgs-eval score-frames`: score one run folder, or another
method's frames, against a clip (eval.experiments.score)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from eval.cli._options import flip_opt, lpips_opt, roundtrip_opt
from m4dgs.core import io as mio


@click.command()
@click.argument("run", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--clip",
    "clip_dir",
    default=None,
    type=click.Path(exists=True, file_okay=False),
    help="Clip folder to score against (default: the 'clip' entry of RUN/run.json).",
)
@lpips_opt
@roundtrip_opt
@flip_opt
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
    "earlier version (today: hdr_tce, hdr_psnr_p99, highlight_stops, highlight_peak_ratio and "
    "highlight_peak_ratio_resolved, the held-out views' nv_* and the camera motion), leaving every "
    "other value as it is; the views of an m4dgs run are rendered first when missing. Then "
    "re-export the suite to get them into a runs CSV.",
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
        info = Path(run) / "run.json"
        external = not info.exists() or bool(mio.read_json(info).get("external"))
        m, added = add_missing_metrics(run, clip=clip_dir, render_missing=not external)
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
@click.command("score-frames")
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
    "frame and level and/or views/<view>/{hdr,ldr/<level>}/<g>.* for held-out views; optional "
    "train/hdr, train/ldr, test/depth, views/<view>/depth, cameras.json (docs/eval.md).",
)
@click.option(
    "--layout",
    type=click.Choice(["m4dgs", "mono4dgs-hdr", "nerfies"]),
    default="m4dgs",
    show_default=True,
    help="How PRED is laid out: m4dgs (above); mono4dgs-hdr, the official code's render folder "
    "(<workspace>/<experiment>/world_gs: test_ldr, test_ne_ldr, test_hdr_exr, train_ldr, "
    "train_hdr_exr); nerfies, a DyCheck-style method's results/rgb/<camera>_<frame>.png for a clip "
    "exported with `benchgen export --format nerfies` (no HDR).",
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
@lpips_opt
@roundtrip_opt
@flip_opt
@click.option(
    "--tae-train-test", is_flag=True, help="Also HDR-TAE over all frames (needs train/hdr)."
)
@click.option("--force", is_flag=True, help="Replace an earlier score folder of the same name.")
def score_frames_cmd(
    clip_dir, pred, layout, name, out, lpips_weights, roundtrip, flip, tae_train_test, force
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
        layout=layout,
    )
    click.echo(f"scored {name}: {run_dir / 'metrics.json'}", err=True)
    keys = ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_ssim", "hdr_tae", "ate", "depth_absrel")
    click.echo(json.dumps({k: m.get(k) for k in keys}))
