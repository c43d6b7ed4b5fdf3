"""Atomic file I/O for images, arrays and metadata.

Every writer writes to a temporary name in the destination folder and renames it into place
(`os.replace`), so a crash never leaves a half-written file under the final name. EXR goes through
the OpenEXR bindings as float32 (`np.ascontiguousarray` first: the bindings silently write garbage
from strided arrays); PNG through Pillow."""

from __future__ import annotations

import io as _io
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Optional, Tuple

import numpy as np
import OpenEXR
from PIL import Image

from m4dgs.core.errors import InputError


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
    untouched. Creates the parent folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
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


def write_exr(path, image: np.ndarray) -> None:
    """Write a float32 EXR: [H, W] as channel 'Z', [H, W, 3] as 'RGB', [H, W, C] as channels
    C0..C{C-1}."""
    path = Path(path)
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        channels = {"Z": np.ascontiguousarray(img)}
    elif img.ndim == 3 and img.shape[2] == 3:
        channels = {"RGB": np.ascontiguousarray(img)}
    elif img.ndim == 3:
        channels = {f"C{i}": np.ascontiguousarray(img[..., i]) for i in range(img.shape[2])}
    else:
        raise ValueError(f"write_exr({path}): expected [H, W] or [H, W, C], got shape {img.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_target(path, ".exr") as tmp:
        OpenEXR.File(header, channels).write(str(tmp))


def read_exr(path) -> np.ndarray:
    """Read an EXR written by `write_exr` (or any RGB / single-channel EXR) as float32 [H, W] or [H,
    W, C]."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: file missing")
    try:
        ch = OpenEXR.File(str(path)).channels()
    except Exception as e:
        raise FileFormatError(f"{path}: not a readable EXR ({e})") from e
    if "RGB" in ch:
        arr = ch["RGB"].pixels
    elif "RGBA" in ch:
        arr = ch["RGBA"].pixels[..., :3]
    elif "Z" in ch:
        arr = ch["Z"].pixels
    elif len(ch) == 1:
        arr = next(iter(ch.values())).pixels
    elif all(f"C{i}" in ch for i in range(len(ch))):
        arr = np.stack([ch[f"C{i}"].pixels for i in range(len(ch))], axis=-1)
    else:
        raise FileFormatError(f"{path}: unexpected EXR channels {sorted(ch)}")
    return np.asarray(arr, dtype=np.float32)


def write_png(path, image: np.ndarray) -> None:
    """Write an 8-bit PNG from uint8 [H, W] / [H, W, 3] (floats in [0, 1] are quantised with
    rounding)."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(np.round(img.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    buf = _io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img)).save(buf, format="PNG")
    write_bytes_atomic(path, buf.getvalue())


def read_png(path) -> np.ndarray:
    """Read an 8-bit PNG as uint8 [H, W] or [H, W, 3]."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: file missing")
    try:
        with Image.open(path) as im:
            if im.mode not in ("L", "RGB"):
                im = im.convert("RGB")
            return np.asarray(im).copy()
    except Exception as e:
        raise FileFormatError(f"{path}: not a readable PNG ({e})") from e


# --------------------------------------------------------------------------------------------------
# any image through OpenImageIO
# --------------------------------------------------------------------------------------------------
def read_image(path) -> Tuple[np.ndarray, str]:
    """(pixels [H, W, 3], kind) of an image file through OpenImageIO.

    Integer files come back as their integer type (uint8, uint16), float files as float32; kind is
    "uint8", "uint16" or "float". Channels: R, G, B by name when present, else the first three; a
    one-channel image is repeated to grey RGB. Raises InputError naming the file."""
    import OpenImageIO as oiio  # deferred: only external images need it (~0.1 s)

    path = Path(path)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"{path}: not a readable image ({oiio.geterror()})")
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
            raise InputError(f"{path}: could not read the pixels ({inp.geterror()})")
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
