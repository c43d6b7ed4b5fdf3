"""Temporal-consistency primitives shared by the benchmark generator and the metrics: HDR-TAE over
consecutive frame pairs and the occlusion-edge masks of its interior variant (docs/metrics.md
"Temporal"; benchgen records the ground truth's own HDR-TAE floor with them, eval.metrics.temporal
scores renders with them).

HDR-TAE convention (the authors' compute_HDR_TAE):
- H_{t+1->t} = W(H_{t+1}, F_{t->t+1}): backward warp, bilinear, border padding, align_corners=True
  (m4dgs.core.warp).
- per pixel, the SUM over RGB of |H_t - H_{t+1->t}| / (H_t + H_{t+1->t} + 1e-10), times the
  visibility V_{t->t+1}, summed and divided by the COUNT of visible pixels (so 3x the per-channel
  mean);
- the same for t+1 with H_{t->t+1} = W(H_t, F_{t+1->t}) and V_{t+1->t}; per pair (fwd + bwd) / 2;
  mean over pairs.
- visibility: given masks (exact from ground truth) or forward-backward consistency
  |f + b(x + f)| < 0.5 (|f| + |b(x + f)|) + 0.5 (m4dgs.core.warp.fb_consistency).
A direction with no visible pixel is skipped (a pair with none in both directions too); all empty ->
NaN.

HDR-TCE (temporal change error, beyond the paper; `hdr_tce`): HDR-TAE scores how much a video
changes between frames along the true motion, so a prediction that changes less than the truth
(blurred, or frozen where the scene's light really changes) scores lower than the truth itself.
TCE compares the change with the ground truth's instead: per pixel and channel the signed relative
change d(X) = (X_t - X_{t+1->t}) / (X_t + X_{t+1->t} + eps), the same warp, visibility, channel
sum and averaging as HDR-TAE, and the error |d(P) - d(G)| of prediction P against ground truth G.
A perfect prediction scores 0 (plus what the ground truth's own noise adds), a prediction frozen in
time scores exactly the ground truth's HDR-TAE (the clip's floor), and a constant scale on P
cancels."""

from __future__ import annotations

import math

import numpy as np
import torch

from m4dgs.core.tensors import as_mask, as_tensor
from m4dgs.core.warp import backward_warp, fb_consistency

TAE_EPS = 1e-10


def _tae_direction(
    h_a: torch.Tensor, h_b: torch.Tensor, flow_ab: torch.Tensor, vis_a: torch.Tensor
):
    """Sum over visible pixels of frame a of sum_c |H_a - W(H_b, F_ab)| / (H_a + W + eps), and the
    visible count."""
    hw = backward_warp(h_b, flow_ab, padding_mode="border")
    rel = ((h_a - hw).abs() / (h_a + hw + TAE_EPS)).sum(dim=-1)  # [H, W] channel sum
    n = int(vis_a.sum())
    return float((rel * vis_a.to(rel.dtype)).sum()), n


def _tce_direction(
    p_a: torch.Tensor,
    p_b: torch.Tensor,
    g_a: torch.Tensor,
    g_b: torch.Tensor,
    flow_ab: torch.Tensor,
    vis_a: torch.Tensor,
):
    """Sum over visible pixels of frame a of sum_c |d(P) - d(G)| with d(X) = (X_a - W(X_b, F_ab)) /
    (X_a + W + eps), and the visible count."""

    def change(x_a, x_b):
        xw = backward_warp(x_b, flow_ab, padding_mode="border")
        return (x_a - xw) / (x_a + xw + TAE_EPS)

    err = (change(p_a, p_b) - change(g_a, g_b)).abs().sum(dim=-1)  # [H, W] channel sum
    n = int(vis_a.sum())
    return float((err * vis_a.to(err.dtype)).sum()), n


def _frames(frames, name: str) -> torch.Tensor:
    if isinstance(frames, (list, tuple)):
        frames = torch.stack([as_tensor(f) for f in frames]) if len(frames) else torch.zeros(0)
    h = as_tensor(frames, uint8_scale=False)
    if h.dim() != 4:
        raise ValueError(f"{name}: frames must be [T, H, W, C], got {tuple(h.shape)}")
    return h


def _pair_values(name, h, flow_fwd, flow_bwd, vis_fwd, vis_bwd, direction) -> list[float]:
    """The per-pair loop HDR-TAE and HDR-TCE share: direction(t_a, t_b, flow_ab, vis_a) -> (sum,
    count) in both directions of each consecutive pair, averaged over the directions with a visible
    pixel (NaN for none)."""
    t_len = h.shape[0]
    ff = as_tensor(flow_fwd, device=h.device, uint8_scale=False)
    fb = as_tensor(flow_bwd, device=h.device, uint8_scale=False)
    expect = (t_len - 1, h.shape[1], h.shape[2], 2)
    if tuple(ff.shape) != expect or tuple(fb.shape) != expect:
        raise ValueError(
            f"{name}: flows must be {expect}, got {tuple(ff.shape)} and {tuple(fb.shape)}"
        )
    vf = as_mask(vis_fwd, h) if vis_fwd is not None else None
    vb = as_mask(vis_bwd, h) if vis_bwd is not None else None
    out = []
    for t in range(t_len - 1):
        va = vf[t] if vf is not None else fb_consistency(ff[t], fb[t])
        vb_t = vb[t] if vb is not None else fb_consistency(fb[t], ff[t])
        s1, n1 = direction(t, t + 1, ff[t], va)
        s2, n2 = direction(t + 1, t, fb[t], vb_t)
        terms = [s / n for s, n in ((s1, n1), (s2, n2)) if n > 0]
        out.append(float(np.mean(terms)) if terms else math.nan)
    return out


def hdr_tae_pairs(frames, flow_fwd, flow_bwd, vis_fwd=None, vis_bwd=None) -> list[float]:
    """Per-pair HDR-TAE values (see module docstring).

    Args:
        frames: [T, H, W, 3] linear HDR frames (list or array, numpy or torch).
        flow_fwd: [T-1, H, W, 2] F_{t->t+1} on frame t's grid (pixels).
        flow_bwd: [T-1, H, W, 2] F_{t+1->t} on frame t+1's grid.
        vis_fwd: optional [T-1, H, W] bool, pixels of frame t visible in t+1 (V_{t->t+1}).
        vis_bwd: optional [T-1, H, W] bool, pixels of frame t+1 visible in t (V_{t+1->t}).
            Masks missing -> forward-backward consistency of the two flows.
    Returns:
        list of T-1 floats (NaN for a pair with no visible pixel in either direction).
    """
    h = _frames(frames, "hdr_tae")
    return _pair_values(
        "hdr_tae",
        h,
        flow_fwd,
        flow_bwd,
        vis_fwd,
        vis_bwd,
        lambda a, b, f, v: _tae_direction(h[a], h[b], f, v),
    )


def hdr_tce_pairs(pred, gt, flow_fwd, flow_bwd, vis_fwd=None, vis_bwd=None) -> list[float]:
    """Per-pair HDR-TCE values (module docstring): pred and gt [T, H, W, 3] linear HDR frames of
    the same times, the flows and visibilities as for `hdr_tae_pairs` (the ground truth's)."""
    p, g = _frames(pred, "hdr_tce"), _frames(gt, "hdr_tce")
    if p.shape != g.shape:
        raise ValueError(
            f"hdr_tce: prediction {tuple(p.shape)} and ground truth {tuple(g.shape)} differ"
        )
    g = g.to(p.dtype)
    return _pair_values(
        "hdr_tce",
        p,
        flow_fwd,
        flow_bwd,
        vis_fwd,
        vis_bwd,
        lambda a, b, f, v: _tce_direction(p[a], p[b], g[a], g[b], f, v),
    )


def hdr_tae(frames, flow_fwd, flow_bwd, vis_fwd=None, vis_bwd=None) -> float:
    """HDR-TAE (lower is better): mean over consecutive pairs of the two-direction average (module
    docstring)."""
    vals = [
        v for v in hdr_tae_pairs(frames, flow_fwd, flow_bwd, vis_fwd, vis_bwd) if not math.isnan(v)
    ]
    return float(np.mean(vals)) if vals else math.nan


def hdr_tce(pred, gt, flow_fwd, flow_bwd, vis_fwd=None, vis_bwd=None) -> float:
    """HDR-TCE (lower is better; 0 for a perfect prediction): mean over consecutive pairs of the
    two-direction average (module docstring)."""
    vals = [
        v
        for v in hdr_tce_pairs(pred, gt, flow_fwd, flow_bwd, vis_fwd, vis_bwd)
        if not math.isnan(v)
    ]
    return float(np.mean(vals)) if vals else math.nan


EDGE_DEPTH_RTOL = 0.05  # relative z-depth jump between 4-neighbours that marks an occlusion edge
EDGE_RADIUS = 1  # edge pixels are grown by this many pixels (box)


def depth_edges(depth, rtol: float = EDGE_DEPTH_RTOL, radius: int = EDGE_RADIUS) -> np.ndarray:
    """[H, W] bool: pixels next to an occlusion edge of a z-depth map [H, W] (0 = no surface).

    A 4-neighbour pair is an edge when one has a surface and the other not, or when their depths
    differ by more than rtol of the smaller; both pixels of the pair are marked, then the mask is
    grown by `radius` pixels. These are the pixels whose colour mixes two surfaces (the box pixel
    filter averages over the footprint) and whose flow is that of only one of them, so the HDR-TAE
    of perfectly consistent frames is not zero there."""
    d = np.asarray(depth, np.float64)
    e = np.zeros(d.shape, bool)
    for a, b, sl_a, sl_b in (
        (d[:, :-1], d[:, 1:], (slice(None), slice(None, -1)), (slice(None), slice(1, None))),
        (d[:-1], d[1:], (slice(None, -1), slice(None)), (slice(1, None), slice(None))),
    ):
        surf_a, surf_b = a > 0, b > 0
        jump = np.abs(a - b) > rtol * np.maximum(np.minimum(a, b), 1e-12)
        pair = (surf_a != surf_b) | (surf_a & surf_b & jump)
        e[sl_a] |= pair
        e[sl_b] |= pair
    for _ in range(int(radius)):
        g = e.copy()
        g[1:] |= e[:-1]
        g[:-1] |= e[1:]
        g[:, 1:] |= e[:, :-1]
        g[:, :-1] |= e[:, 1:]
        g[1:, 1:] |= e[:-1, :-1]
        g[:-1, :-1] |= e[1:, 1:]
        g[1:, :-1] |= e[:-1, 1:]
        g[:-1, 1:] |= e[1:, :-1]
        e = g
    return e


def interior_visibility(vis_ab, flow_ab, edges_a, edges_b) -> np.ndarray:
    """vis_ab [H, W] without the pixels of frame a that are edge pixels or whose flow lands on an
    edge pixel of b (nearest pixel): the edge-excluded HDR-TAE's visibility (see `depth_edges`)."""
    v = np.asarray(vis_ab, bool) & ~np.asarray(edges_a, bool)
    f = np.asarray(flow_ab, np.float64)
    H, W = v.shape
    ys, xs = np.mgrid[0:H, 0:W]
    # pixel centres at integer + 0.5
    xt = np.clip(np.floor(xs + f[..., 0] + 0.5).astype(np.int64), 0, W - 1)
    yt = np.clip(np.floor(ys + f[..., 1] + 0.5).astype(np.int64), 0, H - 1)
    return v & ~np.asarray(edges_b, bool)[yt, xt]
