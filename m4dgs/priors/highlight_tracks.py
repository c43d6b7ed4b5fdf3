"""Tracks of small bright movers from the input frames alone: the brightest blobs, linked over time.

Why (docs/method.md, "Small bright movers"): the method's only source of motion is its point tracks.
A lamp, a headlight or a glint is a uniform, saturated patch whose look changes with the exposure,
so point trackers and optical flow lose it (on the disc clip of bench/small_mover_bench.py the
few DIS-chained tracks that land on the disc stay one or two frames and mostly follow the plane
under it) and no Gaussian follows it. Given a few tracks with the right motion the method keeps
it; given tracks a quarter too slow it loses it. A bright blob's centroid, on the other hand,
moves with the mover whatever its interior looks like.

The tracker (beyond the paper; `stage1.init.highlight_tracks`):

1. Blobs: in each training frame, the 4-connected components of its brightest pixels (brightest
   channel within `margin` codes of the frame's brightest, and at least `min_code`), `min_area`
   pixels and more, and at most `max_area` of the image (a sunlit wall or a window is not a small
   mover). A highlight is the brightest thing at a short exposure even where it does not saturate
   it; at the longest exposure it shares the white with the bright parts of the scene.
2. Links: chains over the training frames, greedily by distance between a chain's predicted
   centroid (constant velocity once it has two frames) and a blob's, within `max_step` x the image
   diagonal per frame elapsed, skipping at most `max_gap` frames without a blob, and with blob
   areas within a factor `area_ratio` of each other (one blob per chain and frame, nearest first).
   A chain must hold blobs at two exposure levels or more: the bright parts of the scene that are
   the brightest only at the longest exposure are left to the point tracks.
3. Tracks: each chain of at least two frames gives `points` tracks, the chain's centroids plus
   fixed offsets inside the blob (a regular pattern within 0.6 x the blob's radius at its first
   frame), visible on the chain's frames. A static highlight gives tracks that do not move.

4. Masks (`highlight_masks`, beyond the variant: `masks.highlight_blobs`): the same chains, less
   those that stand still (every centroid within `still_px` of the chain's mean: a lamp seen by a
   still camera), painted into per-frame masks as discs of the blob's radius plus `dilate_px`
   around each centroid, on the chain's frames and, linearly interpolated, on the frames of its
   gaps. A mover a few pixels across is barely covered by the flow-based dynamic masks, so at the
   stage-1 to stage-2 hand-over the Gaussians that follow it are classified static
   (m4dgs.training.v2w); OR-ing these masks in marks them dynamic.

5. Motion (`chain_motion`, beyond the variant: `stage1.init.highlight_motion`): the chains carry
   the motion where they are. On the spark of the hard-lit suite the prior tracks miss the mover's
   centroid by 0.7-2.3 px and the prior flow smears its motion into the background's, while a
   chain's centre lies within 0.25 px of it (lab/notes/hard-lit.md, "Stage 1 and the spark"). So
   the prior tracks that follow a chain's centre (within `near_px` of it on `near_frames` frames
   or more) are dropped for the chain's tracks, and the flow prior is invalid within `flow_px` of
   a chain's centre at the pair's source frame: stage 1 then learns the mover's motion from the
   chain alone, in its initialisation and in its track and flow losses.

6. Depth (`chain_depth`, beyond the variant: `stage1.init.highlight_depth`): the depth prior held at
   each chain's median around the chain. A monocular depth model sees a mover a few pixels across
   as part of what lies behind it: on the spark of the hard-lit suite its prior depth jumps from
   about 2 to 5-6 (its own units) where the spark crosses pixels with nothing behind it, and the
   method loses the spark on and around those stretches; with the prior held along the chain it
   keeps it there (lab/notes/hard-lit.md, "Stage 2's smoothness terms and the fast movers"). So at
   every frame the pixels within `hold_px` of a chain's centre take the chain's median over its
   frames of the median prior depth in that disc.

Pixel coordinates: continuous, pixel centres at +0.5 (m4dgs.clip.TrackSet). Pure numpy + scipy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Sequence, Tuple

import numpy as np


@dataclass(frozen=True)
class Blob:
    """One saturated component of a frame: centroid (x, y) in pixels (centres at +0.5), area in
    pixels."""

    x: float
    y: float
    area: int


def brightest_blobs(
    ldr: np.ndarray,
    margin: int = 8,
    min_code: int = 128,
    min_area: int = 3,
    max_area: float = 0.02,
) -> List[Blob]:
    """Blobs of one frame (module docstring, step 1).

    Args:
        ldr: [H, W, 3] uint8, or float in [0, 1] (scaled by 255).
        margin, min_code: a pixel is a highlight when its brightest channel's code is within
            `margin` of the frame's brightest code and at least `min_code`.
        min_area: smallest blob in pixels; max_area: largest, as a fraction of H x W.
    Returns:
        Blobs sorted by area, largest first.
    """
    from scipy import ndimage

    a = np.asarray(ldr)
    codes = (a if a.dtype == np.uint8 else np.round(np.clip(a, 0.0, 1.0) * 255.0)).max(axis=-1)
    top = int(codes.max())
    sat = codes >= max(top - int(margin), int(min_code))
    H, W = sat.shape
    labels, n = ndimage.label(sat)
    if n == 0:
        return []
    idx = np.arange(1, n + 1)
    area = ndimage.sum_labels(np.ones_like(labels), labels, idx).astype(np.int64)
    cy, cx = np.asarray(ndimage.center_of_mass(sat, labels, idx), np.float64).reshape(-1, 2).T
    keep = (area >= int(min_area)) & (area <= float(max_area) * H * W)
    blobs = [
        Blob(float(x) + 0.5, float(y) + 0.5, int(s)) for x, y, s, k in zip(cx, cy, area, keep) if k
    ]
    return sorted(blobs, key=lambda b: -b.area)


def link_blobs(
    blobs: Sequence[Sequence[Blob]],
    diagonal: float,
    max_step: float = 0.1,
    max_gap: int = 2,
    area_ratio: float = 3.0,
) -> List[List[Tuple[int, Blob]]]:
    """Chains of blobs over frames 0..T-1 (module docstring, step 2): each a list of (frame, blob),
    frames increasing. Chains of one blob are returned too (the caller drops them)."""
    chains: List[List[Tuple[int, Blob]]] = []
    open_: List[int] = []  # indices of chains that may still grow
    for t, frame in enumerate(blobs):
        cands = []
        for ci in open_:
            ch = chains[ci]
            t1, b1 = ch[-1]
            gap = t - t1
            if gap > max_gap + 1:
                continue
            if len(ch) >= 2:
                t0, b0 = ch[-2]
                vx, vy = (b1.x - b0.x) / (t1 - t0), (b1.y - b0.y) / (t1 - t0)
            else:
                vx = vy = 0.0
            px, py = b1.x + vx * gap, b1.y + vy * gap
            for bi, b in enumerate(frame):
                d = math.hypot(b.x - px, b.y - py)
                ratio = max(b.area, b1.area) / max(min(b.area, b1.area), 1)
                if d <= max_step * diagonal * gap and ratio <= area_ratio:
                    cands.append((d, ci, bi))
        used_c, used_b = set(), set()
        for _, ci, bi in sorted(cands):
            if ci in used_c or bi in used_b:
                continue
            chains[ci].append((t, frame[bi]))
            used_c.add(ci)
            used_b.add(bi)
        for bi, b in enumerate(frame):
            if bi not in used_b:
                chains.append([(t, b)])
        open_ = [ci for ci, ch in enumerate(chains) if t - ch[-1][0] <= max_gap]
    return chains


def blob_offsets(area: int, points: int) -> np.ndarray:
    """[points, 2] offsets from a blob's centroid: the centre, then rings within 0.6 x its radius
    (sqrt(area / pi)), evenly spread (a sunflower pattern)."""
    r = 0.6 * math.sqrt(max(area, 1) / math.pi)
    k = np.arange(points, dtype=np.float64)
    rad = r * np.sqrt(k / max(points - 1, 1))
    ang = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)


def highlight_chains(
    ldr_frames: np.ndarray,
    dts: Sequence[float],
    margin: int = 8,
    min_code: int = 128,
    min_area: int = 3,
    max_area: float = 0.02,
    max_step: float = 0.1,
    max_gap: int = 2,
    area_ratio: float = 3.0,
) -> List[List[Tuple[int, Blob]]]:
    """The chains `highlight_tracks` and `highlight_masks` use (module docstring, steps 1-2): of
    two frames or more, with blobs at two exposure levels or more (all of them when the clip has
    one). ldr_frames [T, H, W, 3], dts [T]; the other arguments: brightest_blobs and link_blobs."""
    frames = np.asarray(ldr_frames)
    T, H, W = frames.shape[:3]
    blobs = [brightest_blobs(f, margin, min_code, min_area, max_area) for f in frames]
    levels = np.unique(np.round(np.log2(np.asarray(dts, np.float64)), 6))
    need = min(2, len(levels))
    return [
        c
        for c in link_blobs(blobs, math.hypot(W, H), max_step, max_gap, area_ratio)
        if len(c) >= 2 and len({round(math.log2(float(dts[t])), 6) for t, _ in c}) >= need
    ]


STILL_PX = 1.0  # step 4: a chain whose centroids all lie within this of their mean stands still


def chain_is_still(chain, still_px: float = STILL_PX) -> bool:
    """Whether a chain [(t, Blob), ...] stands still: every blob centroid within still_px of the
    centroids' mean (a lamp seen by a still camera)."""
    c = np.array([[b.x, b.y] for _, b in chain])
    return bool(np.hypot(*(c - c.mean(0)).T).max() <= still_px)


def highlight_masks(
    ldr_frames: np.ndarray,
    dts: Sequence[float],
    dilate_px: float = 1.0,
    still_px: float = STILL_PX,
    **chain_kw,
) -> np.ndarray:
    """[T, H, W] bool: the pixels of moving highlight chains (module docstring, step 4).

    Args:
        ldr_frames: [T, H, W, 3] training frames in order; dts: [T] their exposure times.
        dilate_px: added to each blob's radius sqrt(area / pi).
        still_px: a chain whose centroids all lie within this of their mean stands still and is
            left out.
        chain_kw: highlight_chains' arguments.
    """
    frames = np.asarray(ldr_frames)
    T, H, W = frames.shape[:3]
    out = np.zeros((T, H, W), bool)
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    for ch in highlight_chains(frames, dts, **chain_kw):
        if chain_is_still(ch, still_px):
            continue
        for (t0, b0), (t1, b1) in zip(ch[:-1], ch[1:]):
            for t in range(t0, t1 + (1 if (t1, b1) == ch[-1] else 0)):
                w = (t - t0) / (t1 - t0)
                x, y = b0.x + w * (b1.x - b0.x), b0.y + w * (b1.y - b0.y)
                r = math.sqrt(((1 - w) * b0.area + w * b1.area) / math.pi) + dilate_px
                out[t] |= (xs - x) ** 2 + (ys - y) ** 2 <= r * r
    return out


def highlight_tracks(
    ldr_frames: np.ndarray,
    dts: Sequence[float],
    points: int = 16,
    **chain_kw,
) -> Tuple[np.ndarray, np.ndarray]:
    """Tracks of the brightest blobs of a video (module docstring).

    Args:
        ldr_frames: [T, H, W, 3] uint8 or float in [0, 1], the training frames in order.
        dts: [T] their exposure times. A chain is kept when it has blobs at two exposure levels or
            more (all of them when the clip has one): a patch that is the brightest only at the
            longest exposure is a bright part of the scene, not a highlight.
        points: tracks per chain.
        chain_kw: highlight_chains' arguments (those of brightest_blobs and link_blobs).
    Returns:
        (tracks [M, T, 2] float32 pixels, centres at +0.5, and visible [M, T] bool); M = points x
        the number of chains of two frames or more (0 when there is none).
    """
    frames = np.asarray(ldr_frames)
    T, H, W = frames.shape[:3]
    chains = highlight_chains(frames, dts, **chain_kw)
    tracks = np.zeros((len(chains) * points, T, 2), np.float32)
    vis = np.zeros((len(chains) * points, T), bool)
    for k, ch in enumerate(chains):
        off = blob_offsets(ch[0][1].area, points)
        rows = slice(k * points, (k + 1) * points)
        for t, b in ch:
            tracks[rows, t, 0] = np.clip(b.x + off[:, 0], 0.0, W)
            tracks[rows, t, 1] = np.clip(b.y + off[:, 1], 0.0, H)
            vis[rows, t] = True
    return tracks, vis


NEAR_PX, NEAR_FRAMES, FLOW_PX = 2.0, 3, 3.0  # step 5's defaults (lab/notes/hard-lit.md)


def chain_centres(chain_tracks: np.ndarray, chain_visible: np.ndarray, points: int) -> np.ndarray:
    """[C, T, 2] the centre of each chain of `highlight_tracks`' output (the mean of its `points`
    tracks where visible), NaN on the frames the chain misses. chain_tracks [C * points, T, 2],
    chain_visible [C * points, T]."""
    n, T = chain_visible.shape
    c = n // points
    tr = np.asarray(chain_tracks, np.float64).reshape(c, points, T, 2)
    vis = np.asarray(chain_visible, bool).reshape(c, points, T)
    num = np.where(vis[..., None], tr, 0.0).sum(1)
    cnt = vis.sum(1)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, num / np.maximum(cnt, 1), np.nan)


def chain_motion(
    tracks: np.ndarray,
    visible: np.ndarray,
    centres: np.ndarray,
    flow_pairs: Sequence[Tuple[int, int]],
    flow_valid: np.ndarray | None,
    near_px: float = NEAR_PX,
    near_frames: int = NEAR_FRAMES,
    flow_px: float = FLOW_PX,
) -> Tuple[np.ndarray, np.ndarray | None]:
    """Where the highlight chains take over the motion priors (module docstring, step 5).

    Args:
        tracks: [N, T, 2] prior tracks in pixels (centres at +0.5); visible: [N, T] bool.
        centres: [C, T, 2] chain centres (chain_centres), NaN where a chain has no blob.
        flow_pairs: [P] (i, j) training-frame indices of the prior flows F_{i->j}.
        flow_valid: [P, H, W] bool, or None (no flow prior).
        near_px, near_frames: a prior track within near_px of a chain's centre on near_frames of
            its visible frames or more follows the chain and is dropped.
        flow_px: the flow prior is invalid at the pixels whose centre lies within flow_px of a
            chain's centre at the pair's source frame i.
    Returns:
        (keep [N] bool: the prior tracks left, flow_valid [P, H, W] bool with the chains' discs
        cleared, a copy, or None).
    """
    tr = np.asarray(tracks, np.float64)
    vis = np.asarray(visible, bool)
    keep = np.ones(tr.shape[0], bool)
    for cc in np.asarray(centres, np.float64):
        with np.errstate(invalid="ignore"):
            near = (np.linalg.norm(tr - cc[None], axis=-1) < near_px) & vis
        keep &= near.sum(1) < near_frames
    if flow_valid is None:
        return keep, None
    fv = np.array(flow_valid, bool, copy=True)
    H, W = fv.shape[1:]
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    for cc in np.asarray(centres, np.float64):
        for p, (i, _) in enumerate(flow_pairs):
            if np.isfinite(cc[i]).all():
                fv[p] &= (xs - cc[i, 0]) ** 2 + (ys - cc[i, 1]) ** 2 >= flow_px**2
    return keep, fv


HOLD_PX = 3.0  # step 6's default: the disc the depth prior is held in (lab/notes/hard-lit.md)


def chain_depth(depth: np.ndarray, centres: np.ndarray, hold_px: float = HOLD_PX) -> np.ndarray:
    """The depth prior held at each chain's median around the chain (module docstring, step 6).

    Args:
        depth: [T, H, W] the depth prior of the training frames (arbitrary scale; > 0 where valid).
        centres: [C, T, 2] chain centres in pixels (chain_centres), NaN where a chain has no blob.
        hold_px: the pixels whose centre lies within hold_px of a chain's centre (boundary
            included) are held.
    Returns:
        [T, H, W] a copy of depth. Chain by chain in order (a later chain's median reads the
        earlier chains' holds where their discs overlap): at each frame of the chain, the median of
        the valid prior depth in its disc; their median over the frames; that value written into
        every valid pixel of every disc (invalid pixels stay invalid). A chain with no valid pixel
        in any of its discs is left alone.
    """
    out = np.array(depth, copy=True)
    T, H, W = out.shape
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    for cc in np.asarray(centres, np.float64):
        discs, vals = [], []
        for t in range(T):
            if not np.isfinite(cc[t]).all():
                continue
            m = (xs - cc[t, 0]) ** 2 + (ys - cc[t, 1]) ** 2 <= hold_px**2
            discs.append((t, m))
            v = out[t][m]
            v = v[v > 0]
            if v.size:
                vals.append(np.median(v))
        if not vals:
            continue
        held = np.median(vals)
        for t, m in discs:
            out[t][m & (out[t] > 0)] = held
    return out
