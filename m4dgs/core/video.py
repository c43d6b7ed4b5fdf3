"""Encoding frames as a video: H.264 / yuv420p mp4 through imageio-ffmpeg, written atomically.

Shared by the renders' videos (m4dgs.outputs.videos) and the evaluation's error-map videos
(eval.inspect.errormaps), so it sits with the other file formats in core."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np

from m4dgs.core.io import atomic_target


def caption(frame: np.ndarray, text: str) -> np.ndarray:
    """A uint8 frame [H, W, 3] with `text` in white on a black box at its top-left."""
    from PIL import Image, ImageDraw  # deferred: only frames with captions need it

    im = Image.fromarray(frame)
    d = ImageDraw.Draw(im)
    x0, y0, x1, y1 = d.textbbox((4, 3), text)
    d.rectangle((x0 - 2, y0 - 2, x1 + 2, y1 + 2), fill=(0, 0, 0))
    d.text((4, 3), text, fill=(255, 255, 255))
    return np.asarray(im)


def pad_even(frame: np.ndarray) -> np.ndarray:
    """Pad [H, W, C] with black on the bottom / right to even H and W (yuv420p needs them)."""
    h, w = frame.shape[:2]
    ph, pw = h % 2, w % 2
    if ph == 0 and pw == 0:
        return frame
    return np.pad(frame, ((0, ph), (0, pw), (0, 0)))


def write_mp4(path, frames: Iterable[np.ndarray], fps: float) -> Path:
    """Encode uint8 frames [H, W, 3] (all the same size; padded to even sizes here) as H.264 /
    yuv420p mp4, atomically. Returns the path."""
    import imageio.v2 as imageio  # deferred: imageio + ffmpeg plugin, only to encode videos

    path = Path(path)
    with atomic_target(path, ".mp4") as tmp:
        writer = imageio.get_writer(
            str(tmp),
            format="FFMPEG",
            mode="I",
            fps=float(fps),
            codec="libx264",
            pixelformat="yuv420p",
            macro_block_size=1,
            quality=8,
            ffmpeg_log_level="error",
        )
        n = 0
        try:
            for fr in frames:
                writer.append_data(pad_even(np.ascontiguousarray(fr, dtype=np.uint8)))
                n += 1
        finally:
            writer.close()
        if n == 0:
            raise ValueError(f"write_mp4({path}): no frames")
    return path
