"""Command-line options for the prior files a clip can be built from.

`m4dgs import-clip` (your own footage) and `benchgen from-hdr` (an HDR video) read the same prior
files through the same readers (m4dgs.footage: read_tracks, read_flow, the depth reader), so they
declare the options once, here; each command keeps its own --depth, whose help says which frames
the maps belong to.
"""

from __future__ import annotations

from pathlib import Path

import click


def prior_file_options(f):
    """Add --depth-kind, --tracks, --visibility, --track-pixel-centre and --flow to a command.

    The values reach the command as depth_kind (str), tracks / visibility / flow (Path or None)
    and track_pixel_centre ("0" or "0.5")."""
    options = [
        click.option(
            "--depth-kind",
            type=click.Choice(["depth", "disparity"]),
            default="depth",
            show_default=True,
            help="What --depth holds: depth, or disparity (inverse depth, as many models write).",
        ),
        click.option(
            "--tracks",
            default=None,
            type=click.Path(exists=True, dir_okay=False, path_type=Path),
            help="Point tracks over the training frames [T, N, 2] in pixels ([T, N, 3] x, y, depth "
            "tracks are read as x, y): an .npz with 'tracks' and 'visibility' (or 'visible'), or "
            "an .npy (visibility: --visibility). Default: long tracks chained through DIS optical "
            "flow with a forward-backward check.",
        ),
        click.option(
            "--visibility",
            default=None,
            type=click.Path(exists=True, dir_okay=False, path_type=Path),
            help="[T, N] visibility .npy for a --tracks .npy (default: all visible).",
        ),
        click.option(
            "--track-pixel-centre",
            type=click.Choice(["0", "0.5"]),
            default="0",
            show_default=True,
            help="Coordinate of the first pixel's centre in the given tracks (0: integer pixel "
            "centres).",
        ),
        click.option(
            "--flow",
            default=None,
            type=click.Path(exists=True, file_okay=False, path_type=Path),
            help="Optional flow prior: a folder of <a>_<b>.flo or <a>_<b>.npy files between "
            "training-frame positions a and b (0 = the first training frame; default: the "
            "trainer computes DIS flow).",
        ),
    ]
    for option in reversed(options):
        f = option(f)
    return f
