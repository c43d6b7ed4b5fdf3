"""Temporal stability of rendered HDR video: HDR-TAE (paper appendix "Evaluation Metrics"),
HDR-TCE (its error against the ground truth's own change, beyond the paper), HDR_T_std, DIS flow.

HDR-TAE (`hdr_tae`, `hdr_tae_pairs`), HDR-TCE (`hdr_tce`, `hdr_tce_pairs`) and the
occlusion-edge masks of HDR-TAE's interior variant (`depth_edges`, `interior_visibility`) live in
m4dgs.core.temporal, whose docstring states the convention (the authors' compute_HDR_TAE: channel
sum, bilinear backward warp with border padding, mean over visible pixels, both directions);
benchgen uses them for the ground truth's HDR-TAE floor. They are re-exported here.

Flow for real clips (no learned model without weights): OpenCV DIS optical flow, preset MEDIUM, on
8-bit grey images of the mu-law tone-mapped HDR pair, both frames divided by the SAME scale (max
over the two frames), so the tone curve does not change between the frames."""

from __future__ import annotations

import numpy as np
import torch

from m4dgs.core.hdr import MU, mu_law
from m4dgs.core.temporal import (
    EDGE_DEPTH_RTOL,
    EDGE_RADIUS,
    TAE_EPS,
    depth_edges,
    hdr_tae,
    hdr_tae_pairs,
    hdr_tce,
    hdr_tce_pairs,
    interior_visibility,
)

from ._util import as_tensor

__all__ = [
    "CONVENTIONS",
    "EDGE_DEPTH_RTOL",
    "EDGE_RADIUS",
    "TAE_EPS",
    "depth_edges",
    "dis_flow",
    "dis_flow_sequence",
    "hdr_t_std",
    "hdr_tae",
    "hdr_tae_pairs",
    "hdr_tce",
    "hdr_tce_pairs",
    "interior_visibility",
    "tonemap_8bit",
]

CONVENTIONS = {
    "hdr_tae": "HDR-TAE: channel SUM convention (3x per-channel mean), as in the authors' code; "
    "bilinear backward "
    "warp with border padding; mean over visible pixels, both directions, consecutive pairs",
    "hdr_tae_gt_flow": "HDR-TAE flow: exact ground-truth flow and visibility",
    "hdr_tae_given_flow": "HDR-TAE flow: the flow given with the clip (gt/flow.npz of a clip made "
    "from an HDR video, e.g. RAFT on the ground truth), visibility from its forward-backward "
    "consistency",
    "hdr_tae_gt_dis_flow": "HDR-TAE flow: OpenCV DIS (preset medium) on the 8-bit mu-law "
    "tone-mapped ground-truth HDR frames (the same flow for every method), visibility from "
    "forward-backward consistency",
    "hdr_tae_dis_flow": "HDR-TAE flow: OpenCV DIS (preset medium) on 8-bit mu-law tone-mapped "
    "HDR, visibility from "
    "forward-backward consistency",
    "hdr_tae_interior": "HDR-TAE interior: the same, with occlusion-edge pixels (a 5 % depth jump "
    "or a surface "
    "boundary, grown by 1 px, in either frame) removed from the visibility",
    "hdr_tce": "HDR-TCE (beyond the paper): the HDR-TAE pairs, warp and visibility, scoring "
    "|d(P) - d(G)| with d(X) = (X_t - X_{t+1->t}) / (X_t + X_{t+1->t}), channel sum, against the "
    "ground truth's change: 0 for a perfect prediction, the clip's HDR-TAE floor for one frozen in "
    "time",
    "hdr_t_std": "HDR_T_std: population std over frames of each frame's mean HDR value, divided "
    "by the global mean",
}


def hdr_t_std(frames) -> float:
    """HDR_T_std: std over frames (population, ddof=0) of each frame's mean value, divided by the
    global mean.

    frames: [T, H, W, C] linear HDR (list or array). The frame mean is over pixels and channels.
    """
    if isinstance(frames, (list, tuple)):
        frames = torch.stack([as_tensor(f, uint8_scale=False) for f in frames])
    h = as_tensor(frames, uint8_scale=False)
    means = h.reshape(h.shape[0], -1).mean(dim=1)
    return float(means.std(correction=0) / h.mean())


def tonemap_8bit(hdr, scale: float | None = None, mu: float = MU) -> np.ndarray:
    """8-bit grey image for flow estimation: round(255 * mu_law(clip(H / scale, 0, 1))), Rec.709
    luma of RGB.

    hdr: [H, W, 3] or [H, W] linear HDR; scale defaults to the image's max.
    """
    h = as_tensor(hdr, uint8_scale=False).cpu().numpy()
    if h.ndim == 3:
        h = (
            h[..., 0] * 0.2126 + h[..., 1] * 0.7152 + h[..., 2] * 0.0722
            if h.shape[-1] == 3
            else h[..., 0]
        )
    s = float(h.max()) if scale is None else float(scale)
    t = mu_law(h / max(s, 1e-12), mu)
    return np.round(t * 255.0).astype(np.uint8)


def dis_flow(img_a, img_b, *, hdr: bool | None = None) -> np.ndarray:
    """Optical flow F_{a->b} [H, W, 2] (float32 numpy, pixels) by OpenCV DIS, preset MEDIUM.

    img_a, img_b: [H, W, 3] (or [H, W]) images. uint8 inputs are used as they are (converted to
    grey); float inputs are treated as linear HDR (`hdr=None` auto-detects from the dtype) and
    tone-mapped to 8-bit with the mu-law curve on H / max(H_a, H_b) (same scale for both frames).
    """
    import cv2  # deferred: OpenCV (~0.2 s), only for clips without ground-truth flow

    a_np = img_a.detach().cpu().numpy() if isinstance(img_a, torch.Tensor) else np.asarray(img_a)
    b_np = img_b.detach().cpu().numpy() if isinstance(img_b, torch.Tensor) else np.asarray(img_b)
    if hdr is None:
        hdr = a_np.dtype != np.uint8
    if hdr:
        s = max(float(a_np.max()), float(b_np.max()))
        ga, gb = tonemap_8bit(a_np, s), tonemap_8bit(b_np, s)
    else:

        def grey(x):
            x = x if x.dtype == np.uint8 else np.round(np.clip(x, 0, 1) * 255).astype(np.uint8)
            return (
                cv2.cvtColor(x, cv2.COLOR_RGB2GRAY)
                if x.ndim == 3 and x.shape[-1] == 3
                else x.reshape(x.shape[:2])
            )

        ga, gb = grey(a_np), grey(b_np)
    dis = cv2.DISOpticalFlow_create(cv2.DISOpticalFlow_PRESET_MEDIUM)
    flow = dis.calc(np.ascontiguousarray(ga), np.ascontiguousarray(gb), None)
    return flow.astype(np.float32)


def dis_flow_sequence(frames) -> tuple[np.ndarray, np.ndarray]:
    """Forward and backward DIS flows of consecutive frames: ([T-1, H, W, 2] F_{t->t+1}, [T-1, H, W,
    2] F_{t+1->t})."""
    fr = [
        f.detach().cpu().numpy() if isinstance(f, torch.Tensor) else np.asarray(f) for f in frames
    ]
    fwd = [dis_flow(fr[t], fr[t + 1]) for t in range(len(fr) - 1)]
    bwd = [dis_flow(fr[t + 1], fr[t]) for t in range(len(fr) - 1)]
    return np.stack(fwd), np.stack(bwd)
