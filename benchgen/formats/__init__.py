"""`benchgen export`: a clip in the layouts other methods read (docs/clip-format.md, "Other
formats"). One module per format; the names and conversions both directions share are in
m4dgs.formats, the import is m4dgs.footage_formats."""

from __future__ import annotations

import shutil
from pathlib import Path

from m4dgs.clip import Clip
from m4dgs.core.errors import InputError
from m4dgs.formats import FORMATS


def export_clip(clip_dir, fmt: str, out, force: bool = False, cameras=None) -> Path:
    """Write the clip at `clip_dir` in format `fmt` into the folder `out` (written into a hidden
    folder beside it and renamed into place when complete); returns `out`. `cameras`: estimated
    cameras (an m4dgs cameras.json) for a format that carries cameras (nerfies)."""
    from . import mono4dgs_hdr, nerfies

    writers = {"mono4dgs-hdr": mono4dgs_hdr.export, "nerfies": nerfies.export}
    if fmt not in writers:
        raise InputError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")
    if cameras is not None and fmt != "nerfies":
        raise InputError(
            f"--cameras {cameras}: the {fmt} layout carries no cameras (the official code "
            "estimates its own in its preprocessing)"
        )
    clip = Clip.open(clip_dir, validate="meta")
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not force:
        raise InputError(f"{out}: not empty; use --force to replace it")
    if out.resolve() == clip.root.resolve() or clip.root.resolve() in out.resolve().parents:
        raise InputError(f"{out}: inside the clip {clip.root}; export somewhere else")
    tmp = out.parent / f".{out.name}.writing"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    try:
        writers[fmt](clip, tmp, **({"cameras": cameras} if cameras is not None else {}))
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    return out
