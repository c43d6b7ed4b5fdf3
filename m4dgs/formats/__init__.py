"""Other projects' dataset layouts, both directions (docs/clip-format.md, "Other formats").

One module per format holds what both sides share: the file and folder names, the JSON fields and
the camera conversion. `benchgen export` (benchgen/formats/) writes a clip in a format;
`m4dgs import-clip --format` (m4dgs/footage_formats.py) reads one into a clip. The modules here
import only m4dgs.core, so that both sides can use them."""

from __future__ import annotations

from pathlib import Path

from m4dgs.core import io as mio
from m4dgs.core.errors import InputError

FORMATS = ("mono4dgs-hdr", "nerfies")

# the source clip's clip.json, kept beside an export so that an import of it gets its metadata
# (crf, unit-exposure value, HDR scale, levels); no other tool reads it
CLIP_META_FILE = "m4dgs_clip.json"


def copy_file(src: Path, dst: Path) -> None:
    """Copy a file byte for byte, atomically (frames keep their exact bytes both ways)."""
    mio.write_bytes_atomic(dst, Path(src).read_bytes())


def field(d, key: str, path, kind=None):
    """d[key], or an InputError naming the file and the field; `kind` a type (or tuple) the value
    must have."""
    if not isinstance(d, dict) or key not in d:
        raise InputError(f"{path}: field '{key}': missing")
    v = d[key]
    if kind is not None and not isinstance(v, kind):
        raise InputError(f"{path}: field '{key}': expected {_kind_name(kind)}, got {v!r:.60}")
    return v


def _kind_name(kind) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join(
        {dict: "an object", list: "a list", str: "a string"}.get(k, k.__name__) for k in kinds
    )


def read_json_file(path) -> dict:
    """A JSON file's object, or an InputError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: missing")
    d = mio.read_json(path)
    if not isinstance(d, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(d).__name__}")
    return d
