"""Videos and induced tracks of a trained run (`m4dgs render RUN --videos --tracks`).

Written to RUN/videos/ (every file atomically: temporary name in the same folder, then os.replace):

    fix_view_change_time.mp4   camera of the middle training frame; time sweeps over all training
    frames including
                               `substeps - 1` fractional in-between times per interval. Left: LDR
                               through the learned tone mapper at the reference exposure; right:
                               mu-law HDR panel.
    fix_time_change_view.mp4   time fixed at the middle training frame; the camera moves along the
    estimated
                               trajectory (slerp + lerp between training cameras, same sampling).
                               LDR | mu-law HDR.
    exposure_sweep.mp4         middle frame, its own camera; log2 dt sweeps from log2(shortest
    observed dt) - 2 to
                               log2(longest observed dt) + 2 (`ev_steps` frames per stop); LDR only.
    tracks_2d.mp4 / .npz       induced 2D tracks (TrainedModel.track_2d) of a grid of query pixels
    on the first
                               training frame, followed through all training frames, drawn as
                               coloured trails over the LDR renders; npz: tracks [N, F, 2] float32
                               pixels, frames [F], queries [N, 2], query_frame, query_alpha [N].
    tracks_3d.npz / .png       induced 3D tracks: world positions of the dynamic Gaussians at every
    training time;
                               npz: tracks [Nd, F, 3] float32, frames [F], times [F], c2w [F, 4, 4]
                               (estimated training cameras); png: matplotlib 3D plot of the
                               most-moving trails and the camera path.

Reference exposure of the LDR panels: the geometric mean of the observed exposure levels (log2 dt =
mean of their log2), so alternating-exposure clips do not flicker. HDR panel: mu-law (mu = 5000) of
H / s clipped to [0, 1], s = the 99th percentile of the middle frame's HDR render (one s per video,
so brightness is comparable across its frames). Frame sizes are padded (black, right / bottom) to
even numbers for yuv420p; encoding is libx264 via imageio-ffmpeg."""

from __future__ import annotations

import colorsys
import io as _io
import math
from pathlib import Path
from typing import List, Optional

import numpy as np
import torch

from m4dgs.core import camera as cam
from m4dgs.core.hdr import mu_law
from m4dgs.core.io import write_bytes_atomic, write_npz
from m4dgs.core.progress import progress_bar
from m4dgs.core.video import caption, write_mp4
from m4dgs.model.trained import load_model


# --------------------------------------------------------------------------------------------------
# small image helpers
# --------------------------------------------------------------------------------------------------
def to_uint8(img) -> np.ndarray:
    """Float image [H, W, C] in [0, 1] (torch or numpy) -> uint8 with rounding."""
    a = img.detach().cpu().numpy() if isinstance(img, torch.Tensor) else np.asarray(img)
    return np.clip(np.round(a.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)


def _label(frame: np.ndarray, text: str) -> np.ndarray:
    """Small white-on-black caption at the top-left (only for frames wide enough to hold it)."""
    if frame.shape[1] < 128 or frame.shape[0] < 48:
        return frame
    return caption(frame, text)


def _progress(it, progress: bool, desc: str, total: Optional[int] = None):
    if not progress:
        return it
    return progress_bar(it, desc=desc, total=total, unit="frame", leave=False)


# --------------------------------------------------------------------------------------------------
# sampling of the sweeps
# --------------------------------------------------------------------------------------------------
def sweep_times(num_frames: int, substeps: int = 2) -> np.ndarray:
    """Training-frame times 0..T-1 with substeps - 1 evenly spaced in-between times per interval:
    [(T-1) substeps + 1]."""
    if num_frames <= 1:
        return np.zeros(1)
    substeps = max(int(substeps), 1)
    return np.linspace(0.0, num_frames - 1.0, (num_frames - 1) * substeps + 1)


def observed_log2_levels(model) -> np.ndarray:
    """log2 of the clip's observed exposure levels (falls back to the training exposures)."""
    obs = list(model.clip.meta.exposures.observed) or list(model.clip.train_dt)
    return np.log2(np.asarray(obs, np.float64))


def reference_log2_dt(model) -> float:
    """Exposure of the LDR panels: mean of the observed levels' log2 (their geometric mean)."""
    return float(observed_log2_levels(model).mean())


def exposure_sweep_levels(model, margin_ev: float = 2.0, ev_steps: int = 4) -> np.ndarray:
    """log2 dt from the shortest observed level - margin to the longest + margin, ev_steps samples
    per stop."""
    lv = observed_log2_levels(model)
    lo, hi = float(lv.min()) - margin_ev, float(lv.max()) + margin_ev
    return np.linspace(lo, hi, int(round((hi - lo) * ev_steps)) + 1)


def _hdr_scale(hdr: torch.Tensor, q: float = 0.99) -> float:
    """Robust maximum of an HDR image (q-quantile of the per-pixel channel maximum)."""
    m = hdr.detach().float().amax(-1).reshape(-1)
    if m.numel() > 1_000_000:
        m = m[
            torch.randperm(m.numel(), generator=torch.Generator().manual_seed(0))[:1_000_000].to(
                m.device
            )
        ]
    return max(float(torch.quantile(m, q)), 1e-8)


def _load(run_dir, device, model, backend):
    if model is not None:
        return model
    return load_model(run_dir, device=device, backend=backend)


# --------------------------------------------------------------------------------------------------
# videos
# --------------------------------------------------------------------------------------------------
@torch.no_grad()
def render_videos(
    run_dir,
    device: str = "cpu",
    fps: Optional[float] = None,
    out_dir=None,
    *,
    model=None,
    substeps: int = 2,
    ev_steps: int = 4,
    margin_ev: float = 2.0,
    progress: bool = True,
    backend: str = "auto",
) -> List[Path]:
    """Write fix_view_change_time.mp4, fix_time_change_view.mp4 and exposure_sweep.mp4 (see the
    module docstring).

    Args:
        run_dir: run folder. device: torch device for rendering. fps: frames per second (default:
        the clip's fps;
            with substeps = 2 and every other frame a training frame, that plays the time sweep in
            real time).
        out_dir: output folder (default RUN/videos). model: an already loaded TrainedModel (skips
        loading). substeps: samples per training-frame interval of the time / trajectory sweeps.
        ev_steps, margin_ev: exposure-sweep samples per stop and extension beyond the observed
        levels (stops).
    Returns:
        [fix_view_change_time.mp4, fix_time_change_view.mp4, exposure_sweep.mp4] paths.
    """
    model = _load(run_dir, device, model, backend)
    out = Path(out_dir) if out_dir is not None else Path(run_dir) / "videos"
    fps = float(fps or model.clip.meta.fps)
    n_train = len(model.frames)
    i_mid = (n_train - 1) // 2
    K, c2w_mid = model.camera(model.frames[i_mid])
    l2_ref = reference_log2_dt(model)
    ref = model.render(float(i_mid), c2w_mid, K, log2_dt=l2_ref)
    scale = _hdr_scale(ref["hdr"])
    times = sweep_times(n_train, substeps)

    def panel(r, caption: str) -> np.ndarray:
        ldr = to_uint8(r["ldr"])
        hdr = to_uint8(mu_law(r["hdr"] / scale))
        return _label(np.concatenate([ldr, hdr], axis=1), caption)

    def fix_view():
        for t in _progress(times, progress, "video fix-view", len(times)):
            yield panel(
                model.render(float(t), c2w_mid, K, log2_dt=l2_ref), f"t = {t:.2f}  |  mu-law HDR"
            )

    c2w_traj = cam.interpolate_trajectory(
        np.arange(n_train, dtype=np.float64), model.c2w_train.detach().cpu().double().numpy(), times
    )

    def fix_time():
        for t, c2w in _progress(list(zip(times, c2w_traj)), progress, "video fix-time", len(times)):
            yield panel(
                model.render(float(i_mid), c2w, K, log2_dt=l2_ref), f"view {t:.2f}  |  mu-law HDR"
            )

    levels = exposure_sweep_levels(model, margin_ev, ev_steps)

    def sweep():
        hdr = ref["hdr"]
        for l2 in _progress(levels, progress, "video exposure", len(levels)):
            ldr = model.tm(hdr, torch.tensor(float(l2), dtype=hdr.dtype, device=hdr.device)).clamp(
                0, 1
            )
            yield _label(to_uint8(ldr), f"log2 dt = {l2:+.2f}")

    return [
        write_mp4(out / "fix_view_change_time.mp4", fix_view(), fps),
        write_mp4(out / "fix_time_change_view.mp4", fix_time(), fps),
        write_mp4(out / "exposure_sweep.mp4", sweep(), fps),
    ]


# --------------------------------------------------------------------------------------------------
# tracks
# --------------------------------------------------------------------------------------------------
def query_grid(width: int, height: int, step: Optional[int] = None) -> np.ndarray:
    """Pixel centres of a regular grid [N, 2] (x, y), spacing `step` (default: about 16 points
    across the shorter side), offset by half a step from the border."""
    step = int(step or max(2, round(min(width, height) / 16)))
    xs = np.arange(step // 2, width, step) + 0.5
    ys = np.arange(step // 2, height, step) + 0.5
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.reshape(-1), gy.reshape(-1)], axis=1)


def _track_colors(n: int) -> np.ndarray:
    """[n, 3] uint8 distinct-ish colours (HSV wheel)."""
    return np.array(
        [
            [int(255 * c) for c in colorsys.hsv_to_rgb((i * 0.618033988749895) % 1.0, 0.85, 1.0)]
            for i in range(n)
        ],
        dtype=np.uint8,
    ).reshape(n, 3)


def draw_trails(
    img: np.ndarray, tracks: np.ndarray, f: int, colors: np.ndarray, trail: int = 8, zoom: int = 1
) -> np.ndarray:
    """Draw each track's positions over frames [f - trail, f] as a polyline ending in a dot.

    Args:
        img: uint8 [H, W, 3] (already zoomed). tracks: [N, F, 2] pixels of the unzoomed image.
        colors: [N, 3] uint8.
    """
    import cv2  # deferred: OpenCV (~0.2 s), only to draw track videos

    out = np.ascontiguousarray(img.copy())
    lo = max(0, f - int(trail))
    for i in range(tracks.shape[0]):
        seg = tracks[i, lo : f + 1] * zoom
        if not np.isfinite(seg).all():
            continue
        c = tuple(int(v) for v in colors[i])
        pts = np.round(seg * 4).astype(np.int32)  # 2 fractional bits (cv2 shift=2)
        if len(pts) > 1:
            cv2.polylines(out, [pts.reshape(-1, 1, 2)], False, c, 1, cv2.LINE_AA, shift=2)
        cv2.circle(out, tuple(int(v) for v in pts[-1]), 2 * 4, c, -1, cv2.LINE_AA, shift=2)
    return out


def _plot_tracks_3d(
    path: Path,
    tracks: np.ndarray,
    c2w: np.ndarray,
    static_pts: np.ndarray,
    max_tracks: int,
    title: str,
) -> Path:
    """matplotlib 3D plot of world trails (x, z, -y axes so that OpenCV 'up' = -y points up),
    written atomically."""
    # deferred: matplotlib (~0.6 s), only for the 3D track plot
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    def axes(p):
        return p[..., 0], p[..., 2], -p[..., 1]

    fig = Figure(figsize=(7, 6), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    if static_pts.shape[0] > 50:  # far-away outliers (floaters, background) would squash the plot
        lo, hi = np.percentile(static_pts, 2, axis=0), np.percentile(static_pts, 98, axis=0)
        static_pts = static_pts[((static_pts >= lo) & (static_pts <= hi)).all(1)]
    if static_pts.shape[0]:
        x, y, z = axes(static_pts)
        ax.scatter(x, y, z, s=0.5, c="0.7", alpha=0.5, depthshade=False, label="static Gaussians")
    if tracks.shape[0]:
        length = (
            np.linalg.norm(np.diff(tracks, axis=1), axis=-1).sum(1)
            if tracks.shape[1] > 1
            else np.zeros(len(tracks))
        )
        pick = np.argsort(-length, kind="stable")[:max_tracks]
        cols = _track_colors(len(pick)) / 255.0
        for j, i in enumerate(pick):
            x, y, z = axes(tracks[i])
            ax.plot(x, y, z, color=cols[j], lw=0.8)
            ax.scatter([x[-1]], [y[-1]], [z[-1]], color=[cols[j]], s=3)
    centres = c2w[:, :3, 3]
    x, y, z = axes(centres)
    ax.plot(x, y, z, color="k", lw=1.5, label="camera path")
    ax.scatter([x[0]], [y[0]], [z[0]], color="k", marker="^", s=20)
    allp = np.concatenate([a.reshape(-1, 3) for a in (static_pts, tracks, centres) if a.size], 0)
    lo, hi = allp.min(0), allp.max(0)
    span = np.maximum(hi - lo, 0.05 * max(float((hi - lo).max()), 1e-6))  # no flat axis
    # equal units on the three axes (plotted as x, z, -y)
    ax.set_box_aspect((span[0], span[2], span[1]))
    ax.set_xlabel("x")
    ax.set_ylabel("z (forward)")
    ax.set_zlabel("-y (up)")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper right", fontsize=7)
    buf = _io.BytesIO()
    fig.savefig(buf, format="png")
    write_bytes_atomic(path, buf.getvalue())
    return path


@torch.no_grad()
def render_tracks(
    run_dir,
    device: str = "cpu",
    *,
    model=None,
    out_dir=None,
    query_uv=None,
    grid_step=None,
    min_alpha: float = 0.5,
    fps: Optional[float] = None,
    trail: int = 8,
    max_plot_tracks: int = 300,
    progress: bool = True,
    backend: str = "auto",
) -> List[Path]:
    """Induced 2D and 3D tracks of a trained run (files in the module docstring).

    Args:
        query_uv: [N, 2] query pixels on the first training frame (default: `query_grid`, keeping
        the points whose
            rendered alpha >= min_alpha, i.e. that lie on the reconstructed scene rather than on the
            background).
        fps: frame rate of tracks_2d.mp4 (default: half the clip's fps, the training frames' rate
        with the default
            even/odd split). trail: trail length in frames.
    Returns:
        [tracks_2d.mp4, tracks_2d.npz, tracks_3d.npz, tracks_3d.png] paths.
    """
    model = _load(run_dir, device, model, backend)
    out = Path(out_dir) if out_dir is not None else Path(run_dir) / "videos"
    frames = list(model.frames)
    g0 = frames[0]
    W, H = model.width, model.height
    l2_ref = reference_log2_dt(model)

    # -- 2D
    # ----------------------------------------------------------------------------------------------
    first = model.render_frame(g0, log2_dt=l2_ref)
    alpha0 = first["alpha"].detach().cpu().numpy()
    if query_uv is None:
        uv = query_grid(W, H, grid_step)
        a = alpha0[uv[:, 1].astype(int), uv[:, 0].astype(int)]
        keep = a >= min_alpha
        uv, a = uv[keep], a[keep]
    else:
        uv = np.asarray(query_uv, np.float64).reshape(-1, 2)
        ij = np.clip(np.floor(uv).astype(int), 0, [W - 1, H - 1])
        a = alpha0[ij[:, 1], ij[:, 0]]
    if uv.shape[0]:
        tracks = model.track_2d(uv, g0, frames).detach().cpu().numpy()
    else:
        tracks = np.zeros((0, len(frames), 2))
    p_npz2 = out / "tracks_2d.npz"
    write_npz(
        p_npz2,
        tracks=tracks.astype(np.float32),
        frames=np.asarray(frames, np.int64),
        queries=uv.astype(np.float32),
        query_frame=np.int64(g0),
        query_alpha=a.astype(np.float32),
    )

    zoom = max(1, int(math.ceil(256 / max(min(W, H), 1))))
    colors = _track_colors(tracks.shape[0])

    def video():
        import cv2  # deferred: OpenCV (~0.2 s), only to draw track videos

        for f, g in _progress(list(enumerate(frames)), progress, "tracks 2d", len(frames)):
            ldr = first["ldr"] if f == 0 else model.render_frame(g, log2_dt=l2_ref)["ldr"]
            img = to_uint8(ldr)
            if zoom > 1:
                img = cv2.resize(img, (W * zoom, H * zoom), interpolation=cv2.INTER_NEAREST)
            yield draw_trails(img, tracks, f, colors, trail, zoom)

    p_mp4 = write_mp4(
        out / "tracks_2d.mp4", video(), float(fps or max(model.clip.meta.fps / 2.0, 1.0))
    )

    # -- 3D
    # ----------------------------------------------------------------------------------------------
    gauss = model.gauss
    times = torch.tensor(
        [model.time_of(g) for g in frames], dtype=gauss.knots.dtype, device=gauss.knots.device
    )
    pos = gauss.positions(times)  # [N, F, 3]
    dyn = gauss.is_dynamic
    tracks3 = pos[dyn].detach().cpu().numpy().astype(np.float32)
    c2w = model.c2w_train.detach().cpu().numpy().astype(np.float64)
    p_npz3 = out / "tracks_3d.npz"
    write_npz(
        p_npz3,
        tracks=tracks3,
        frames=np.asarray(frames, np.int64),
        times=times.cpu().numpy(),
        c2w=c2w,
    )
    stat = pos[~dyn, 0].detach().cpu().numpy()
    if stat.shape[0] > 4000:
        stat = stat[np.random.default_rng(0).choice(stat.shape[0], 4000, replace=False)]
    title = (
        f"{model.clip.meta.name}: {tracks3.shape[0]} dynamic Gaussians over {len(frames)} "
        "training frames "
        f"(showing <= {max_plot_tracks} most moving)"
    )
    p_png = _plot_tracks_3d(out / "tracks_3d.png", tracks3, c2w, stat, max_plot_tracks, title)
    return [p_mp4, p_npz2, p_npz3, p_png]
