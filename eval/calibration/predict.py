"""2D predictions of a test frame that reconstruct nothing in 3D: the calibration rows.

Each is scored exactly like a method and gets no more than a method gets: the training frames,
their exposure times, the clip's unit exposure value (the anchor of the estimated response,
eval.calibration.response) and, for the warps, DIS optical flow computed here on those frames. The
clip's true response, its ground truth and its priors are not read.

- `copy_nearest`: the training frame nearest in time, its radiance through the estimated
  response (saturated codes give the response's end values), re-exposed at each level asked for.
- `flow_merge`: a classical HDR-video reconstruction: the nearest training frame of every exposure
  level, warped to it with flow interpolated from the flow between
  the two training frames around it (linear motion: F_t->n = (t_n - t) / (t_b - t_a) F_a->b,
  with F_a->b sampled at the test pixel), merged with the hat weights of their own codes (a
  frame's weight is 0 where its warp leaves the image).
- `dibr`, for the held-out views: the nearest training frame forward-warped into the view with its
  depth prior and the camera initialisation's cameras, aligned to the truth like a method
  (depth-image-based rendering with a z-buffer; holes take their nearest splatted pixel).

Shapes: frames [H, W, 3] uint8, radiance [H, W, 3] float32. Pure functions of arrays, plus
`ClipFrames`, the training frames of a clip.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List, Sequence, Tuple

import numpy as np

from .response import estimate_response, expose, merge_radiance, radiance


@dataclass
class ClipFrames:
    """What a calibration row may read of a clip: the training frames (global indices, 8-bit
    images, exposure times) and the unit exposure value (the code of radiance x time = 1)."""

    frames: List[int]
    ldr: List[np.ndarray]
    dt: List[float]
    unit_exposure_value: float

    @staticmethod
    def of(clip) -> "ClipFrames":
        """From an m4dgs.clip.Clip: input/ldr/ and clip.json's exposures, nothing else."""
        return ClipFrames(
            list(clip.train_frames),
            [clip.load_ldr(g) for g in clip.train_frames],
            [float(d) for d in clip.train_dt],
            float(clip.meta.unit_exposure_value),
        )

    @property
    def anchor(self) -> int:
        return int(round(255.0 * self.unit_exposure_value))


def response_of(cf: ClipFrames, max_groups: int = 12) -> np.ndarray:
    """g [3, 256] (eval.calibration.response.estimate_response) from runs of consecutive training
    frames that hold every observed level once (a bracket), at most `max_groups` of them spread
    over the clip."""
    levels = sorted(set(cf.dt))
    n = len(levels)
    starts = [i for i in range(len(cf.frames) - n + 1) if sorted(cf.dt[i : i + n]) == levels]
    if not starts:
        raise ValueError("no run of consecutive training frames holds every exposure level")
    pick = [starts[int(k)] for k in np.linspace(0, len(starts) - 1, min(max_groups, len(starts)))]
    groups = [np.stack(cf.ldr[i : i + n]) for i in pick]
    dts = [cf.dt[i : i + n] for i in pick]
    return estimate_response(groups, dts, anchor=cf.anchor)


def copy_nearest(cf: ClipFrames, g: float, response: np.ndarray) -> np.ndarray:
    """Radiance [H, W, 3] at global time g: the nearest training frame's (the earlier one on a
    tie) through the response."""
    i = int(np.argmin([abs(t - g) + 1e-9 * (t > g) for t in cf.frames]))
    return radiance(cf.ldr[i], cf.dt[i], response).astype(np.float32)


def dis_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[H, W, 2] flow F_a->b (pixels) between two 8-bit grey images: OpenCV DIS, preset MEDIUM."""
    import cv2  # deferred: only the warping rows need OpenCV

    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    return dis.calc(np.ascontiguousarray(a), np.ascontiguousarray(b), None).astype(np.float32)


def grey_of_radiance(hdr: np.ndarray, scale: float) -> np.ndarray:
    """8-bit grey image of radiance for flow: luminance x scale through a gamma of 2.2 (frames of
    different exposures look alike to the flow once their exposure is divided out)."""
    y = hdr[..., 0] * 0.299 + hdr[..., 1] * 0.587 + hdr[..., 2] * 0.114
    return np.round(np.clip(y * scale, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)


def warp(image: np.ndarray, flow: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """(image sampled at x + flow(x), bilinear; inside [H, W] bool: the sample point lies in the
    image)."""
    import cv2

    H, W = flow.shape[:2]
    xs, ys = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    mx, my = xs + flow[..., 0], ys + flow[..., 1]
    out = cv2.remap(
        np.asarray(image, np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    inside = (mx >= 0) & (mx <= W - 1) & (my >= 0) & (my <= H - 1)
    return out, inside


def neighbours(cf: ClipFrames, g: float) -> List[int]:
    """Indices of the training frames flow_merge uses at time g: for each exposure level, the
    training frame of that level nearest in time (the earlier one on a tie). Frames further away
    only add the flow's extrapolation error (measured on the tiny clips: taking the nearest of
    each level on both sides scored 0.2-1.0 dB lower in HDR PSNR)."""
    out = []
    for lv in sorted(set(cf.dt)):
        idx = [i for i, d in enumerate(cf.dt) if d == lv]
        out.append(min(idx, key=lambda i: (abs(cf.frames[i] - g), cf.frames[i])))
    return sorted(out)


def flow_merge(cf: ClipFrames, g: float, response: np.ndarray) -> np.ndarray:
    """Radiance [H, W, 3] at global time g (module docstring): the neighbours of every exposure
    warped to g and merged with exposure weights. At a training frame's own time it is that
    frame's radiance merged with its warped neighbours."""
    t = np.asarray(cf.frames, np.float64)
    a = int(np.searchsorted(t, g, side="right") - 1)
    b = a + 1
    if a < 0 or b >= len(t):  # before the first or after the last training frame
        return copy_nearest(cf, g, response)
    rad = {i: radiance(cf.ldr[i], cf.dt[i], response) for i in {a, b, *neighbours(cf, g)}}
    scale = 1.0 / max(float(np.median([np.median(r) for r in rad.values()])) * 4, 1e-12)
    f_ab = dis_flow(grey_of_radiance(rad[a], scale), grey_of_radiance(rad[b], scale))
    ldrs, dts, weights = [], [], []
    for i in neighbours(cf, g):
        f = f_ab * float((t[i] - g) / (t[b] - t[a]))
        z, inside = warp(cf.ldr[i], f)
        ldrs.append(np.clip(np.round(z), 0, 255).astype(np.uint8))
        dts.append(cf.dt[i])
        weights.append(inside.astype(np.float64))
    return merge_radiance(ldrs, dts, response, weights).astype(np.float32)


def dibr(
    image: np.ndarray,
    depth: np.ndarray,
    K_src: np.ndarray,
    c2w_src: np.ndarray,
    K_dst: np.ndarray,
    c2w_dst: np.ndarray,
    width: int,
    height: int,
) -> Tuple[np.ndarray, np.ndarray]:
    """Depth-image-based rendering: `image` [H, W, C] with z-depth `depth` [H, W] (0 or less: no
    surface) of an OpenCV camera (K_src, c2w_src) forward-warped into (K_dst, c2w_dst) at width x
    height: each source pixel centre lifted to 3D, projected, and splatted to the destination
    pixel holding it, the nearest surface winning (a z-buffer). Returns (image [height, width, C]
    with the holes filled by their nearest splatted pixel, splatted [height, width] bool)."""
    from scipy import ndimage

    H, W = depth.shape
    v, u = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")
    z = np.asarray(depth, np.float64).ravel()
    ok = np.isfinite(z) & (z > 0)
    x = np.stack([u.ravel(), v.ravel(), np.ones(H * W)], 0)
    pc = np.linalg.inv(np.asarray(K_src, np.float64)) @ x * z  # [3, HW] source camera
    c2w_src, c2w_dst = np.asarray(c2w_src, np.float64), np.asarray(c2w_dst, np.float64)
    pw = c2w_src[:3, :3] @ pc + c2w_src[:3, 3:4]
    pd = c2w_dst[:3, :3].T @ (pw - c2w_dst[:3, 3:4])
    zd = pd[2]
    ok &= zd > 1e-9
    uv = (np.asarray(K_dst, np.float64) @ pd)[:2] / np.where(ok, zd, 1.0)
    iu, iv = np.floor(uv[0]).astype(np.int64), np.floor(uv[1]).astype(np.int64)
    ok &= (iu >= 0) & (iu < width) & (iv >= 0) & (iv < height)
    src = np.flatnonzero(ok)
    dst = iv[src] * width + iu[src]
    order = np.lexsort((zd[src], dst))  # by destination pixel, nearest first
    dst_sorted = dst[order]
    first = np.ones(dst_sorted.size, bool)
    first[1:] = dst_sorted[1:] != dst_sorted[:-1]
    win_src, win_dst = src[order][first], dst_sorted[first]
    img = np.asarray(image).reshape(H * W, -1)
    out = np.zeros((height * width, img.shape[1]), img.dtype)
    out[win_dst] = img[win_src]
    hit = np.zeros(height * width, bool)
    hit[win_dst] = True
    hit = hit.reshape(height, width)
    out = out.reshape(height, width, -1)
    if hit.any() and not hit.all():
        _, (iy, ix) = ndimage.distance_transform_edt(~hit, return_indices=True)
        out = out[iy, ix]
    return out.reshape((height, width) + np.asarray(image).shape[2:]), hit


def predict(cf: ClipFrames, frames: Sequence[int], row: str, response: np.ndarray) -> Dict:
    """{g: radiance [H, W, 3]} of calibration row `row` ("copy-nearest" or "flow-merge") at the
    global frames `frames`."""
    fn = {"copy-nearest": copy_nearest, "flow-merge": flow_merge}.get(row)
    if fn is None:
        raise ValueError(f"unknown calibration row {row!r} (copy-nearest, flow-merge)")
    return {int(g): fn(cf, float(g), response) for g in frames}


def ldr_at(hdr: np.ndarray, dt: float, response: np.ndarray) -> np.ndarray:
    """The 8-bit frame a prediction shows at exposure time dt (through its own estimated
    response, as a method shows its renders through its own tone mapper)."""
    return expose(hdr, dt, response)
