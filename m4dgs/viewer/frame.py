"""The viewer's images: `view_frame(model, camera, time, ev, mode)` -> uint8 [H, W, 3].

`time` is a global frame index (fractional between frames; the model's own time axis is
`model.time_of(time)`), `ev` the exposure as log2 of the exposure time dt (clip.json's units: a
training frame with dt = 0.25 is ev = -2), `camera` a m4dgs.viewer.cameras.ViewCamera (its width x
height is the image size). Modes:

    ldr         the learned tone mapper at ev: model.tm(hdr, ev), 8 bits with rounding, as
                `m4dgs render` writes renders/*/ldr/*.png
    hdr-mulaw   mu-law (mu = 5000, m4dgs.core.hdr) of the HDR scaled by 2^ev and clipped to 1
    hdr-false   log2 luminance of the HDR (Rec. 709 weights) in false colour (turbo), the
                FALSE_STOPS stops below and above log2 L = -ev, with a scale bar in log2 L
    depth       z-depth in false colour (turbo, near = red, far = blue; the 2nd to 98th
                percentile of the covered pixels), with a scale bar in the run's units
    dynamic     static Gaussians blue, dynamic ones orange, over the LDR image in grey
    centres     the Gaussians' centres at that time, one dot each in its tone-mapped colour,
                nearest on top"""

from __future__ import annotations

import math
from typing import Tuple

import numpy as np
import torch

from m4dgs.core import camera as cam
from m4dgs.core.hdr import mu_law
from m4dgs.viewer.cameras import ViewCamera

MODES = ("ldr", "hdr-mulaw", "hdr-false", "depth", "dynamic", "centres")
MODE_LABELS = {
    "ldr": "LDR (tone mapper at EV)",
    "hdr-mulaw": "HDR mu-law",
    "hdr-false": "HDR log-luminance",
    "depth": "Depth",
    "dynamic": "Static / dynamic",
    "centres": "Gaussian centres",
}
#: log2-luminance range of the false-colour mode: -ev - FALSE_STOPS[0] .. -ev + FALSE_STOPS[1]
FALSE_STOPS = (10.0, 4.0)
STATIC_RGB = (0.25, 0.45, 1.0)
DYNAMIC_RGB = (1.0, 0.55, 0.05)


def to_uint8(x: np.ndarray) -> np.ndarray:
    """[0, 1] floats -> uint8 codes round(255 x), clipped (m4dgs.core.io.write_png's rounding)."""
    return np.clip(np.round(np.asarray(x, np.float64) * 255.0), 0, 255).astype(np.uint8)


def turbo(v: np.ndarray) -> np.ndarray:
    """[...] values in [0, 1] -> [..., 3] RGB floats of matplotlib's turbo colour map."""
    from matplotlib import colormaps

    return colormaps["turbo"](np.clip(v, 0.0, 1.0))[..., :3]


def scale_bar(
    img: np.ndarray, lo: float, hi: float, unit: str, reverse: bool = False
) -> np.ndarray:
    """Draw a turbo colour bar from lo to hi (labelled at both ends and the middle, `unit` after
    the last label) over the bottom of uint8 img [H, W, 3]; returns a new image. reverse: the bar
    runs from the map's top (red) to its bottom (blue), as the depth mode colours near to far."""
    from PIL import Image, ImageDraw

    H, W = img.shape[:2]
    bh = max(3, H // 24)
    x0, x1 = W // 10, W - W // 10
    if x1 - x0 < 4:
        return img
    out = img.copy()
    ramp = np.linspace(0.0, 1.0, x1 - x0)
    colours = to_uint8(turbo(1.0 - ramp if reverse else ramp))
    y1 = H - max(2, H // 40)
    y0 = y1 - bh
    out[max(0, y0 - 1) : y1 + 1, max(0, x0 - 1) : x1 + 1] = 0
    out[y0:y1, x0:x1] = colours[None]
    if H >= 48:
        pil = Image.fromarray(out)
        draw = ImageDraw.Draw(pil)
        for frac, v in ((0.0, lo), (0.5, (lo + hi) / 2), (1.0, hi)):
            text = f"{v:.3g}" + (f" {unit}" if frac == 1.0 else "")
            tw = draw.textlength(text)
            x = min(max(0, x0 + frac * (x1 - x0) - tw / 2), W - tw)
            y = max(0, y0 - 12)
            draw.text((x + 1, y + 1), text, fill=(0, 0, 0))
            draw.text((x, y), text, fill=(255, 255, 255))
        out = np.asarray(pil)
    return out


def _t(v: float, like: torch.Tensor) -> torch.Tensor:
    return torch.tensor(float(v), dtype=like.dtype, device=like.device)


def render_maps(model, camera: ViewCamera, time: float):
    """model.render at global time `time` from `camera`: {"hdr" [H, W, 3], "depth" [H, W],
    "alpha" [H, W]} torch tensors."""
    return model.render(model.time_of(time), camera.c2w, camera.K, camera.width, camera.height)


def ldr_image(model, hdr: torch.Tensor, ev: float) -> np.ndarray:
    """uint8 [H, W, 3]: the learned tone mapper at ev, as `m4dgs render` writes it."""
    return to_uint8(model.tm(hdr, _t(ev, hdr)).clamp(0, 1).cpu().numpy())


def false_colour_range(ev: float) -> Tuple[float, float]:
    """The log2-luminance range shown by the hdr-false mode at ev."""
    return -float(ev) - FALSE_STOPS[0], -float(ev) + FALSE_STOPS[1]


def _luminance(hdr: np.ndarray) -> np.ndarray:
    return hdr[..., 0] * 0.2126 + hdr[..., 1] * 0.7152 + hdr[..., 2] * 0.0722


def _gauss_time_state(model, time: float):
    t = model.time_of(time)
    g = model.gauss
    return g.positions(t), g.quats(t), g.scales(), g.opacities()


def _split_image(model, camera: ViewCamera, time: float, ldr: np.ndarray) -> np.ndarray:
    from m4dgs.raster import render

    means, quats, scales, opac = _gauss_time_state(model, time)
    dyn = model.gauss.is_dynamic.to(means.dtype)[:, None]
    s = torch.tensor(STATIC_RGB, dtype=means.dtype, device=means.device)
    d = torch.tensor(DYNAMIC_RGB, dtype=means.dtype, device=means.device)
    feats = s * (1 - dyn) + d * dyn
    c2w = torch.as_tensor(camera.c2w, dtype=torch.float32, device=means.device)
    K = torch.as_tensor(camera.K, dtype=torch.float32, device=means.device)
    out = render(
        means,
        quats,
        scales,
        opac,
        feats,
        cam.invert_rigid(c2w),
        K,
        camera.width,
        camera.height,
        backend=model.backend,
        background=means.new_zeros(3),
    )
    split = out.features.clamp(0, 1).cpu().numpy()
    grey = ldr.astype(np.float64).mean(-1, keepdims=True) / 255.0
    return to_uint8(0.35 * grey + 0.65 * split)


def _centres_image(model, camera: ViewCamera, time: float, ev: float) -> np.ndarray:
    from m4dgs.model.color import color_directions
    from m4dgs.model.render import gaussian_colors

    means, quats, scales, opac = _gauss_time_state(model, time)
    c2w = torch.as_tensor(camera.c2w, dtype=torch.float32, device=means.device)
    dirs = color_directions(model.color, means, quats, scales, c2w[:3, 3])
    hdr = gaussian_colors(model.gauss, model.color, model.time_of(time), dirs)
    rgb = model.tm(hdr, _t(ev, hdr)).clamp(0, 1).cpu().numpy()
    w2c = cam.invert_rigid(c2w)
    pc = cam.transform_points(w2c, means)
    z = pc[:, 2].cpu().numpy()
    K = torch.as_tensor(camera.K, dtype=torch.float32, device=means.device)
    uv = cam.project_pinhole(pc, K).cpu().numpy()
    W, H = camera.width, camera.height
    img = np.zeros((H, W, 3), np.float64)
    x = np.floor(uv[:, 0]).astype(np.int64)
    y = np.floor(uv[:, 1]).astype(np.int64)
    ok = (z > 1e-6) & (x >= 0) & (x < W) & (y >= 0) & (y < H) & np.isfinite(uv).all(1)
    order = np.argsort(-z[ok], kind="stable")  # far first: the nearest is written last
    img[y[ok][order], x[ok][order]] = rgb[ok][order]
    return to_uint8(img)


@torch.no_grad()
def view_frame(model, camera: ViewCamera, time: float, ev: float, mode: str = "ldr") -> np.ndarray:
    """The image the viewer shows: uint8 [camera.height, camera.width, 3] of `model` (a
    m4dgs.model.trained.TrainedModel) at global frame time `time` and exposure log2 dt = ev, in
    `mode` (module docstring; MODES)."""
    if mode not in MODES:
        raise ValueError(f"unknown view mode {mode!r}; known: {', '.join(MODES)}")
    if not (math.isfinite(float(time)) and math.isfinite(float(ev))):
        raise ValueError(f"view_frame: time and ev must be finite, got {time!r}, {ev!r}")
    if mode == "centres":
        return _centres_image(model, camera, time, ev)
    r = render_maps(model, camera, time)
    if mode == "ldr":
        return ldr_image(model, r["hdr"], ev)
    if mode == "dynamic":
        return _split_image(model, camera, time, ldr_image(model, r["hdr"], ev))
    hdr = r["hdr"].cpu().numpy().astype(np.float64)
    if mode == "hdr-mulaw":
        return to_uint8(mu_law(hdr * 2.0 ** float(ev)))
    if mode == "hdr-false":
        lo, hi = false_colour_range(ev)
        stops = np.log2(np.maximum(_luminance(hdr), 1e-30))
        img = to_uint8(turbo((stops - lo) / (hi - lo)))
        return scale_bar(img, lo, hi, "log2 L")
    # depth: near red, far blue over the covered pixels; uncovered pixels fade to black
    depth = r["depth"].cpu().numpy().astype(np.float64)
    alpha = r["alpha"].cpu().numpy().astype(np.float64)
    cov = alpha > 0.5
    vals = depth[cov] if cov.any() else depth.reshape(-1)
    near, far = (float(v) for v in np.percentile(vals, [2.0, 98.0]))
    far = far if far > near else near + 1e-6
    img = turbo(1.0 - (depth - near) / (far - near)) * np.clip(alpha, 0, 1)[..., None]
    return scale_bar(to_uint8(img), near, far, "depth", reverse=True)
