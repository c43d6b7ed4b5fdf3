"""`m4dgs-eval calibration CLIP ROW --out DIR`: write a calibration row's 2D prediction of a clip
(eval.calibration, eval.experiments.dibr_views) as a folder that `m4dgs-eval score-frames` scores
like any other method's frames (docs/eval.md, "Calibration rows")."""

from __future__ import annotations

from pathlib import Path

import click

from eval.calibration import ROWS, TEMPORAL_ROWS


@click.command("calibration")
@click.argument("clip_dir", metavar="CLIP", type=click.Path(exists=True, file_okay=False))
@click.argument("row", metavar="ROW", type=click.Choice(ROWS))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(file_okay=False),
    help="Folder to write the prediction into (the score-frames layout: test/ and views/), with "
    "the estimated response as response.json.",
)
@click.option(
    "--preset",
    default="small",
    show_default=True,
    type=click.Choice(["tiny", "small", "paper"]),
    help="dibr only: the training preset whose camera initialisation places the depth priors "
    "(the one the compared runs trained with).",
)
@click.option(
    "--seed",
    default=0,
    show_default=True,
    type=int,
    help="dibr only: the trainer seed of that camera initialisation.",
)
def calibration_cmd(clip_dir, row, out, preset, seed):
    """Write calibration row ROW's prediction of CLIP into --out.

    ROW is copy-nearest (the nearest training frame), flow-merge (the nearest frame of each
    exposure warped to the test time with DIS flow and merged) or dibr (the nearest training
    frame forward-warped into each held-out view with its depth prior). All three estimate the
    camera response from the bracketed training frames (Debevec-Malik) and use nothing a method
    does not get. Then score it: m4dgs-eval score-frames --clip CLIP --pred OUT --name ROW."""
    from m4dgs.clip import Clip

    out = Path(out)
    if row in TEMPORAL_ROWS:
        from eval.calibration.frames import write_prediction

        write_prediction(Clip.open(clip_dir), out, row)
    else:
        from eval.experiments.dibr_views import write_dibr_views

        write_dibr_views(
            clip_dir,
            out / "views",
            preset=preset,
            overrides={"seed": seed} if seed else None,
            response_json=out / "response.json",
        )
    click.echo(f"wrote {out}")
    click.echo(f"next: m4dgs-eval score-frames --clip {clip_dir} --pred {out} --name {row}")
