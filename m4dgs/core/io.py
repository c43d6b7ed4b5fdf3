"""Atomic file I/O for images, arrays and metadata.

Every writer writes to a temporary name in the destination folder and renames it into place
(`os.replace`), so a crash never leaves a half-written file under the final name. Images (EXR as
float32 with zip compression, 8-bit PNG, and any other format for external files: `read_image`) go
through OpenImageIO, which reads channels by name and reports the bit depth, so nothing is
quantised silently."""

from __future__ import annotations

import io as _io
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Optional, Tuple

import numpy as np

from m4dgs.core.errors import InputError, one_line, with_path


class FileFormatError(InputError):
    """A file exists but its content is not what the clip contract says (the message names file and
    field)."""


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_target(path, suffix: str = ".tmp") -> Iterator[Path]:
    """The one atomic-write mechanism: yield a temporary path beside `path` (same folder, so the
    rename cannot cross file systems; named `.<name>.<random><suffix>`, so format-sniffing writers
    see the right extension); on normal exit the file gets normal permissions (mkstemp makes it
    0600) and is renamed onto `path` (os.replace), on an exception it is removed and `path` is
    untouched (an OSError of the write is re-raised naming `path`). Creates the parent folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as e:
        # a failed write (no space, a file-size limit) names no file, or the temporary one: name
        # the file the caller writes (m4dgs.core.errors.os_error_line reports it in one line)
        new = with_path(e, path)
        if new is e:
            raise
        raise new from e
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_bytes_atomic(path, data: bytes) -> None:
    """Write bytes to `path` atomically (temporary file in the same folder, then rename)."""
    with atomic_target(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path, text: str) -> None:
    """Write UTF-8 text to `path` atomically (`write_bytes_atomic`)."""
    write_bytes_atomic(path, text.encode())


def find_file(name_or_path, folder, suffix: str = ".yaml") -> Optional[Path]:
    """Look up a file given by path or by the name of a shipped one: `name_or_path` itself when it
    is an existing file, else `<folder>/<name_or_path><suffix>` when that exists, else None (the
    caller raises its own error, naming what it was looking for)."""
    p = Path(str(name_or_path))
    if p.is_file():
        return p
    cand = Path(folder) / f"{name_or_path}{suffix}"
    return cand if cand.is_file() else None


class YAMLSyntaxError(FileFormatError):
    """A YAML file that does not parse: `name`, `where` ("line L, column C", or "") and `what`."""

    def __init__(self, name: str, where: str, what: str):
        self.name, self.where, self.what = name, where, what
        super().__init__(f"{name}{', ' + where if where else ''}: not valid YAML ({what})")


def parse_yaml(text: str, name: str) -> Any:
    """The YAML document `text` (from the file or place called `name`); a syntax error becomes one
    line naming `name`, the line and column and the problem (yaml's own message spans lines and
    names "<unicode string>" for text)."""
    import yaml  # deferred with the other readers' libraries

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
        where = f", line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        parts = [getattr(e, "context", None), getattr(e, "problem", None)]
        what = "; ".join(p for p in parts if p) or " ".join(str(e).split())
        raise YAMLSyntaxError(name, where.lstrip(", "), what) from None


def read_yaml(path) -> Any:
    """The parsed YAML file `path` (`parse_yaml`: a syntax error in one line naming the file, the
    line and the column)."""
    path = Path(path)
    return parse_yaml(path.read_text(encoding="utf-8"), str(path))


def write_json(path, obj: Any) -> None:
    write_bytes_atomic(path, (json.dumps(obj, indent=2, sort_keys=False) + "\n").encode())


def read_json(path) -> Any:
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise
    except json.JSONDecodeError as e:
        raise FileFormatError(f"{path}: not valid JSON ({e})") from e


def write_npz(path, compressed: bool = True, **arrays) -> None:
    buf = _io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(
        buf, **{k: np.ascontiguousarray(v) for k, v in arrays.items()}
    )
    write_bytes_atomic(path, buf.getvalue())


def read_npz(path) -> dict:
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise
    except Exception as e:  # zipfile / pickle errors
        raise FileFormatError(f"{path}: not a readable .npz archive ({e})") from e


_FORK_HOOK_INSTALLED = False


def _oiio():
    import OpenImageIO as oiio  # deferred (~0.1 s): `--help` and the listing commands stay light

    global _FORK_HOOK_INSTALLED
    if not _FORK_HOOK_INSTALLED and hasattr(os, "register_at_fork"):
        _FORK_HOOK_INSTALLED = True
        _install_fork_hook(oiio)
    return oiio


def _install_fork_hook(oiio) -> None:
    """Make OpenImageIO safe across `fork` (process pools, data loader workers).

    OpenImageIO and its OpenEXR reader/writer keep thread pools; a forked child inherits the pools
    but not their threads, so its first EXR write waits forever, and resizing the pools in the
    child crashes (both seen). Before a fork the pools are shrunk to the calling thread, so the
    child starts without one (its I/O runs single-threaded); the parent gets its sizes back at
    its next EXR read or write."""
    saved: dict = {}

    def before() -> None:
        saved["threads"] = oiio.get_int_attribute("threads")
        saved["exr_threads"] = oiio.get_int_attribute("exr_threads")
        oiio.attribute("exr_threads", -1)  # -1: no OpenEXR pool, the calling thread does the work
        oiio.attribute("threads", 1)
        # OpenImageIO resizes OpenEXR's pool lazily, when it next creates an EXR reader or
        # writer; do it now, in the parent, so the child does not join threads it never had
        oiio.ImageOutput.create("fork.exr")

    def after_in_parent() -> None:
        if saved:
            oiio.attribute("threads", saved["threads"])
            oiio.attribute("exr_threads", saved["exr_threads"])

    os.register_at_fork(before=before, after_in_parent=after_in_parent)


def _write_oiio(path, img: np.ndarray, names, pixel_type: str, attrs: dict) -> None:
    """Write one image through OpenImageIO, atomically (the temporary name keeps the extension,
    which selects the format)."""
    oiio = _oiio()
    h, w = img.shape[:2]
    c = 1 if img.ndim == 2 else img.shape[2]
    fmt = {"float": oiio.FLOAT, "uint8": oiio.UINT8}[pixel_type]
    spec = oiio.ImageSpec(w, h, c, fmt)
    spec.channelnames = tuple(names)
    for k, v in attrs.items():
        spec.attribute(k, v)
    with atomic_target(path, Path(path).suffix) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise OSError(f"{path}: cannot write ({oiio.geterror() or (out and out.geterror())})")
        try:
            # always [H, W, C]: a 2-D array is not laid out as one channel by the bindings
            ok = out.write_image(np.ascontiguousarray(img.reshape(h, w, c)))
        finally:
            out.close()
        if not ok:
            raise OSError(f"{path}: cannot write ({out.geterror()})")


def write_exr(path, image: np.ndarray) -> None:
    """Write a float32 EXR (zip compression): [H, W] as channel 'Z', [H, W, 3] as 'R', 'G', 'B',
    [H, W, C] as channels C0..C{C-1}."""
    path = Path(path)
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        names = ["Z"]
    elif img.ndim == 3 and img.shape[2] == 3:
        names = ["R", "G", "B"]
    elif img.ndim == 3:
        names = [f"C{i}" for i in range(img.shape[2])]
    else:
        raise ValueError(f"write_exr({path}): expected [H, W] or [H, W, C], got shape {img.shape}")
    # no DateTime attribute: the same image gives the same bytes (clips are byte-reproducible)
    _write_oiio(path, img, names, "float", {"compression": "zip", "DateTime": ""})


def _read_oiio(path, what: str):
    """(pixels [H, W, C] in the file's own type, channel names, base type) of an image file."""
    oiio = _oiio()
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: file missing")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise FileFormatError(f"{path}: not a readable {what} ({one_line(oiio.geterror())})")
    try:
        spec = inp.spec()
        px = inp.read_image(spec.format)
        if px is None:
            raise FileFormatError(f"{path}: not a readable {what} ({one_line(inp.geterror())})")
        names = list(spec.channelnames)
        base = spec.format.basetype
    finally:
        inp.close()
    px = np.asarray(px)
    return (px[..., None] if px.ndim == 2 else px), names, base


def read_exr(path) -> np.ndarray:
    """Read an EXR written by `write_exr` (or any RGB / RGBA / single-channel EXR) as float32 [H, W]
    or [H, W, C]."""
    px, names, _ = _read_oiio(path, "EXR")
    px = px.astype(np.float32, copy=False)
    if all(c in names for c in ("R", "G", "B")):
        return np.ascontiguousarray(px[..., [names.index(c) for c in ("R", "G", "B")]])
    if "Z" in names:
        return np.ascontiguousarray(px[..., names.index("Z")])
    if len(names) == 1:
        return np.ascontiguousarray(px[..., 0])
    if all(f"C{i}" in names for i in range(len(names))):
        return np.ascontiguousarray(px[..., [names.index(f"C{i}") for i in range(len(names))]])
    raise FileFormatError(f"{path}: unexpected EXR channels {sorted(names)}")


def write_png(path, image: np.ndarray) -> None:
    """Write an 8-bit PNG from uint8 [H, W] / [H, W, 3] (floats in [0, 1] are quantised with
    rounding)."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(np.round(img.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    names = ["Y"] if img.ndim == 2 else ["R", "G", "B", "A"][: img.shape[2]]
    _write_oiio(path, img, names, "uint8", {"DateTime": ""})


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"IEND\xaeB`\x82"  # the IEND chunk's type and CRC: the last 8 bytes of every PNG
# the first bytes of the formats a frame named .png most often really is
_MAGIC = {
    b"\xff\xd8\xff": "JPEG",
    b"GIF8": "GIF",
    b"BM": "BMP",
    b"II*\x00": "TIFF",
    b"MM\x00*": "TIFF",
    b"RIFF": "WebP",
    b"v/1\x01": "OpenEXR",
}


def check_png_bytes(path, other_formats: bool = False) -> None:
    """Refuse, in one line naming the file, a file named .png that is not a complete PNG: another
    format (a JPEG renamed: lossy, its 8-bit codes are not the camera's) or a truncated PNG (no
    IEND chunk at its end; an image library would decode what is there, or print its own lines).
    Reads the first and last 8 bytes only. `other_formats`: a file of another format passes (for
    external images, which are converted); a truncated PNG never does."""
    path = Path(path)
    with open(path, "rb") as f:
        head = f.read(8)
        f.seek(0, os.SEEK_END)
        size = f.tell()
        f.seek(max(size - 8, 0))
        tail = f.read(8)
    if head != PNG_SIGNATURE:
        if other_formats:
            return
        kind = next((k for m, k in _MAGIC.items() if head.startswith(m)), None)
        what = f"a {kind} file" if kind else "not a PNG file (no PNG signature)"
        raise FileFormatError(
            f"{path}: {what} named .png; clip frames are lossless 8-bit PNGs (`m4dgs import-clip` "
            "converts other formats)"
        )
    if tail != PNG_END:
        raise FileFormatError(
            f"{path}: a truncated PNG ({size} bytes, no IEND chunk at the end: an interrupted copy "
            "or download?)"
        )


def read_png(path) -> np.ndarray:
    """Read an 8-bit PNG as uint8 [H, W] (grey) or [H, W, 3] (RGB; alpha dropped, palettes
    expanded). A 16-bit PNG is refused, not quantised (m4dgs.core.io.read_image reads it), and so
    are a truncated PNG and another format named .png (`check_png_bytes`)."""
    oiio = _oiio()
    if Path(path).exists():
        check_png_bytes(path)
    px, names, base = _read_oiio(path, "PNG")
    if base != oiio.UINT8:
        raise FileFormatError(
            f"{path}: a {16 if base == oiio.UINT16 else 'non-8'}-bit PNG where 8-bit is expected "
            "(clip frames and renders are 8-bit; `m4dgs import-clip` and `m4dgs-eval score-frames` "
            "convert other bit depths)"
        )
    if px.shape[-1] <= 2:  # grey, grey + alpha
        return np.ascontiguousarray(px[..., 0])
    return np.ascontiguousarray(px[..., :3])


# --------------------------------------------------------------------------------------------------
# any image through OpenImageIO
# --------------------------------------------------------------------------------------------------
def read_image(path) -> Tuple[np.ndarray, str]:
    """(pixels [H, W, 3], kind) of an image file through OpenImageIO.

    Integer files come back as their integer type (uint8, uint16), float files as float32; kind is
    "uint8", "uint16" or "float". Channels: R, G, B by name when present, else the first three; a
    one-channel image is repeated to grey RGB. Raises InputError naming the file."""
    oiio = _oiio()
    path = Path(path)
    if path.suffix.lower() == ".png" and path.is_file():
        check_png_bytes(path, other_formats=True)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"{path}: not a readable image ({one_line(oiio.geterror())})")
    try:
        spec = inp.spec()
        base = spec.format.basetype
        if base == oiio.UINT8:
            kind, fmt = "uint8", oiio.UINT8
        elif base == oiio.UINT16:
            kind, fmt = "uint16", oiio.UINT16
        elif base in (oiio.HALF, oiio.FLOAT, oiio.DOUBLE):
            kind, fmt = "float", oiio.FLOAT
        else:
            raise InputError(
                f"{path}: pixel type {spec.format} is not supported (8 or 16 bit, half or float)"
            )
        px = inp.read_image(fmt)
        if px is None:
            raise InputError(f"{path}: could not read the pixels ({one_line(inp.geterror())})")
        names = list(spec.channelnames)
    finally:
        inp.close()
    px = np.asarray(px)
    if px.ndim == 2:
        px = px[..., None]
    if px.shape[-1] == 1:
        return np.repeat(px, 3, axis=-1), kind
    if all(c in names for c in ("R", "G", "B")):
        idx = [names.index(c) for c in ("R", "G", "B")]
    elif px.shape[-1] >= 3:
        idx = [0, 1, 2]
    else:
        raise InputError(f"{path}: {px.shape[-1]} channels {names}; need RGB, RGBA or grey")
    return np.ascontiguousarray(px[..., idx]), kind


def ldr_to_8bit(px: np.ndarray, kind: str, path) -> np.ndarray:
    """An LDR image of any kind as uint8: 8 bit as is, 16 bit and float (clipped to [0, 1]) as
    round(255 x)."""
    if kind == "uint8":
        return px.astype(np.uint8)
    if kind == "uint16":
        x = px.astype(np.float64) / 65535.0
    else:
        x = px.astype(np.float64)
        if not np.isfinite(x).all():
            raise InputError(f"{path}: NaN or infinite values in an LDR image")
        x = np.clip(x, 0.0, 1.0)
    return np.round(x * 255.0).astype(np.uint8)
