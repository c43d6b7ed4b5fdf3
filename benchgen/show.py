"""Human-readable views of a clip: a JSON summary and a contact-sheet PNG."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from m4dgs.clip import Clip
from m4dgs.core.hdr import mu_law


def summary(clip: Clip) -> dict:
    m = clip.meta
    out = {
        "name": m.name,
        "size": f"{m.width}x{m.height}",
        "frames": m.num_frames,
        "train": len(m.split.train),
        "test": len(m.split.test),
        "schedule": m.exposures.schedule,
        "observed": m.exposures.observed,
        "novel": m.exposures.novel,
        "crf": m.crf,
        "unit_exposure_value": m.unit_exposure_value,
        "hdr_scale": m.hdr_scale,
        "priors": priors_view(clip),
        "has_gt": clip.has_gt,
    }
    if clip.view_names():
        views = m.gt.get("views", {})
        out["views"] = {
            v: {k: views[v][k] for k in ("angle_deg", "translation", "covisible") if k in views[v]}
            for v in clip.view_names()
            if v in views
        }
    for k in (
        "dynamic_fraction",
        "dynamic_range_stops",
        "hdr_tae_floor",
        "render_noise",
        "camera_motion",
    ):
        if k in m.gt:
            out[k] = m.gt[k]
    if "render_noise" in out:
        out["render_noise"] = render_noise_view(out["render_noise"])
    if clip.has_gt:
        from .relighting import clip_relighting

        # computed here from gt/tracks.npz and gt/hdr (not recorded in clip.json); a summary still
        # prints when those files are incomplete, saying why this part is missing
        try:
            relit = clip_relighting(clip.root)
        except (ValueError, OSError) as e:
            relit = {"unavailable": str(e)}
        if relit is not None:
            out["relighting"] = relit
    return out


def priors_view(clip: Clip) -> dict:
    """The priors a clip has: its degradation profile when benchgen degraded them (clip.json
    priors.profile), the number of depth maps (priors/depth/), tracks (priors/tracks.npz) and flow
    pairs (priors/flow.npz; null when the clip has none), and where given priors came from
    (clip.json priors.<kind>.source, e.g. `benchgen from-hdr` or `m4dgs import-clip`)."""
    m, root = clip.meta, clip.root
    out = {}
    if m.priors.get("profile") is not None:
        out["profile"] = m.priors["profile"]
    out["depth"] = len(list((root / "priors/depth").glob("*.exr")))
    out["tracks"] = None
    if (root / "priors/tracks.npz").exists():
        with np.load(root / "priors/tracks.npz") as z:
            out["tracks"] = int(z["tracks"].shape[0])
    out["flow"] = None
    if clip.has_flow_prior():
        with np.load(root / "priors/flow.npz") as z:
            out["flow"] = int(z["pairs"].shape[0])
    sources = {
        k: v["source"]
        for k, v in m.priors.items()
        if k in ("depth", "tracks", "flow") and isinstance(v, dict) and v.get("source")
    }
    if sources:
        out["sources"] = sources
    return out


def render_noise_view(noise: dict) -> dict:
    """clip.json gt.render_noise with rel_std as the unbiased estimate: clips made before
    benchgen.groundtruth.render_noise recorded rel_std_two_sample held the two-sample estimate
    (sqrt(2 / pi) of it) under rel_std; that value is converted and kept beside it."""
    import math

    out = dict(noise)
    rel = out.get("rel_std")
    if "rel_std_two_sample" not in out and isinstance(rel, (int, float)):
        out["rel_std"] = float(rel) * math.sqrt(math.pi / 2.0)
        out["rel_std_two_sample"] = float(rel)
        out["rel_std_note"] = "converted from the two-sample value this clip recorded"
    return out


def flow_to_color(flow: np.ndarray, max_mag: float = None) -> np.ndarray:
    """Colour-wheel visualisation [H, W, 3] in [0, 1] of a flow field [H, W, 2] (hue = direction,
    value = magnitude)."""
    import matplotlib.colors as mcolors  # deferred: matplotlib (~0.6 s), only for pictures

    mag = np.linalg.norm(flow, axis=-1)
    ang = np.arctan2(flow[..., 1], flow[..., 0])
    m = max_mag if max_mag is not None else max(float(np.percentile(mag, 99)), 1e-6)
    hsv = np.stack([(ang + np.pi) / (2 * np.pi), np.clip(mag / m, 0, 1), np.ones_like(mag)], -1)
    return mcolors.hsv_to_rgb(hsv)


def mu_law_view(hdr: np.ndarray) -> np.ndarray:
    """The HDR panel: mu-law of HDR divided by its own max."""
    return mu_law(hdr / max(float(hdr.max()), 1e-12))


def contact_sheet(clip: Clip, path) -> Path:
    """Write a PNG grid: input LDR frames at each observed level, test LDR at every level, HDR,
    depth (gt and prior), flow (gt and prior), tracks, dynamic mask."""
    import matplotlib  # deferred: matplotlib (~0.6 s), only for pictures

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = clip.meta
    train = clip.train_frames
    panels = []
    # one training frame per observed level
    seen = {}
    for g, dt in zip(train, m.exposures.train_dt):
        seen.setdefault(dt, g)
    for dt, g in sorted(seen.items())[:3]:
        panels.append((clip.load_ldr(g), f"input g={g} dt={dt:g}"))
    g0 = train[min(1, len(train) - 1)]
    if clip.has_gt and clip.has_gt_part("hdr"):
        hdr = clip.load_gt_hdr(g0)
        panels.append((mu_law_view(hdr), f"gt HDR (mu-law) g={g0}"))
        if clip.test_frames:
            gt = clip.test_frames[0]
            for lv in m.exposures.novel[:2]:
                panels.append((clip.load_gt_ldr(lv, gt), f"test g={gt} novel dt={lv:g}"))
        if clip.has_gt_part("depth"):
            panels.append((clip.load_gt_depth(g0), f"gt depth g={g0}"))
    panels.append((clip.load_depth_prior(g0), f"prior depth g={g0}"))
    if clip.has_gt and (clip.root / "gt/flow.npz").exists():
        fs = clip.load_gt_flow()
        panels.append(
            (
                flow_to_color(fs.flow[0]) * fs.valid[0][..., None],
                f"gt flow {tuple(int(x) for x in fs.pairs[0])}",
            )
        )
    if clip.has_flow_prior():
        fs = clip.load_flow_prior()
        if len(fs.pairs):
            panels.append(
                (
                    flow_to_color(fs.flow[0]) * fs.valid[0][..., None],
                    f"prior flow {tuple(int(x) for x in fs.pairs[0])}",
                )
            )
    ts = clip.load_tracks_prior()
    img = clip.load_ldr(train[-1]).astype(np.float32) / 255.0
    panels.append((img, "prior tracks (last frame)", ts))
    if clip.has_gt and clip.has_gt_part("masks/dynamic"):
        panels.append((clip.load_gt_dynamic_mask(g0).astype(np.float32), f"dynamic mask g={g0}"))
    if clip.test_frames and clip.view_names():
        # the first test frame's held-out views at its first level, each beside its co-visible
        # pixels (dark: no training frame pair sees them)
        gt, views = clip.test_frames[0], m.gt.get("views", {})
        lv = m.test_levels_of(gt)[0]
        panels.append((clip.load_gt_ldr(lv, gt), f"test g={gt} dt={lv:g} (input path)"))
        for v in clip.view_names():
            ldr = clip.load_view_ldr(v, lv, gt).astype(np.float32) / 255.0
            covis = clip.load_view_covis(v, gt)
            angle = views.get(v, {}).get("angle_deg")
            deg = f", {angle:.0f} deg" if angle is not None else ""
            panels.append((ldr, f"view {v}{deg}"))
            panels.append((ldr * np.where(covis, 1.0, 0.25)[..., None], f"view {v}: co-visible"))

    cols = 4
    rows = int(np.ceil(len(panels) / cols))
    aspect = m.height / m.width
    fig, axes = plt.subplots(
        rows, cols, figsize=(4 * cols, 4 * aspect * rows + 0.6 * rows), squeeze=False
    )
    for ax in axes.ravel():
        ax.axis("off")
    for ax, p in zip(axes.ravel(), panels):
        im, title = p[0], p[1]
        if im.ndim == 2:
            ax.imshow(im, cmap="magma" if "mask" not in title else "gray")
        else:
            ax.imshow(np.clip(im, 0, 1) if im.dtype != np.uint8 else im)
        if len(p) > 2:
            draw_tracks(ax, p[2])
        ax.set_title(title, fontsize=8)
    fig.suptitle(
        f"{m.name}: {m.width}x{m.height}, {m.num_frames} frames, {m.exposures.schedule}",
        fontsize=10,
    )
    fig.tight_layout()
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    tmp.replace(path)
    return path


def draw_tracks(ax, tracks, tail: int = 6, max_tracks: int = 200) -> None:
    """Draw on an image axis the tracks visible in the last frame: a yellow dot where each is now
    and, for the first max_tracks, a cyan line through its last `tail` positions. A position is
    drawn only where the track is visible and its coordinates are finite: an occluded frame's
    placeholder (often 0, 0) or NaN breaks the line instead of pulling it to the corner.
    Coordinates are the clip's (the first pixel's centre at 0.5)."""
    xy = np.asarray(tracks.tracks, np.float64) - 0.5  # imshow puts pixel centres at integers
    ok = np.asarray(tracks.visible, bool) & np.isfinite(xy).all(axis=-1)
    xy = np.where(ok[..., None], xy, np.nan)  # matplotlib breaks a line at NaN
    T = xy.shape[1]
    now = np.nonzero(ok[:, -1])[0]
    for n in now[:max_tracks]:
        ax.plot(xy[n, max(0, T - tail) :, 0], xy[n, max(0, T - tail) :, 1], "-", lw=0.6, c="cyan")
    ax.scatter(xy[now, -1, 0], xy[now, -1, 1], s=2, c="yellow")
