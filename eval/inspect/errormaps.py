"""Where runs go wrong, as pictures: one test frame's ground truth, each run's render, its error
map and, beside a reference run, where its error grew or shrank.

A score says how far a run is off and `m4dgs-eval regions` which region the error sits in; this
shows the pixels. `m4dgs-eval error-maps RUN [RUN ...] [--ref RUN] [--domain D] [--frame G] [--out
PNG] [--video MP4]` (docs/eval.md) draws, for one test frame of one domain, a column per run (the
ground truth first, then the reference, then the runs) and the rows

1. the images: the LDR render at the domain's level, or the HDR render mu-law tone-mapped and
   normalised by the ground truth's maximum (the HDR PSNR's domain, docs/metrics.md);
2. the error: per pixel the root of the squared error averaged over the channels, one colour
   scale for every run (its 99.5th percentile over the runs, so that one hot pixel does not wash
   the rest out; brighter is worse);
3. with a reference: the change of the squared error, run - reference, on a diverging scale
   symmetric about 0 (red: worse than the reference, blue: better).

Each image's title gives the frame's PSNR (and its difference from the reference's), computed as
the scores compute it (capped per frame). Without --frame the frame is the domain's test frame
where the first run's PSNR falls furthest below the reference's (without a reference: the first
run's worst frame), the one where the comparison shows most. The video (error_video) holds the
same grid for every test frame of the domain, with one colour scale throughout.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np

from eval.conventions import PSNR_CAP_DB
from eval.experiments.run_files import resolve_clip_dir
from eval.inspect.regions import check_comparable, frame_pair, renders_root
from eval.metrics._util import psnr_from_mse
from m4dgs.clip import Clip, level_name
from m4dgs.core.errors import InputError


def parse_domain(clip: Clip, domain: Optional[str]) -> Optional[float]:
    """The exposure level of 'ldr <level>' (a level of the clip's observed or novel ones, as
    m4dgs.clip.level_name writes it), None for 'hdr'; default (None): the clip's first observed
    level. Raises InputError naming the clip's levels for anything else."""
    ex = clip.meta.exposures
    levels = list(ex.observed) + list(ex.novel)
    if domain is None:
        return levels[0]
    d = domain.strip()
    if d == "hdr":
        if not clip.has_gt_part("hdr"):
            raise InputError(
                f"{clip.root / 'gt'}: domain 'hdr', but the clip has no HDR ground truth"
            )
        return None
    names = {level_name(lv): lv for lv in levels}
    if d.startswith("ldr "):
        name = d[4:].strip()
        try:
            name = level_name(float(name))
        except ValueError:
            pass
        if name in names:
            return names[name]
    raise InputError(
        f"domain {domain!r}: 'hdr' or 'ldr <level>' with a level of {clip.root / 'clip.json'}: "
        + ", ".join(f"'ldr {n}'" for n in names)
    )


def domain_frames(clip: Clip, level: Optional[float]) -> List[int]:
    """The test frames (global indices) that have ground truth in the domain."""
    if level is None:
        return list(clip.test_frames)
    return [g for g in clip.test_frames if level in clip.meta.test_levels_of(g)]


def pixel_sq_error(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """[H, W] squared error averaged over the channels. pred, gt: [H, W, C]."""
    d = np.asarray(pred, np.float64) - np.asarray(gt, np.float64)
    return (d * d).mean(axis=-1)


def frame_psnr(pred: np.ndarray, gt: np.ndarray) -> float:
    """PSNR (peak 1) of one frame, capped at the scores' cap. pred, gt: [H, W, C] in [0, 1]."""
    return min(psnr_from_mse(float(pixel_sq_error(pred, gt).mean()), 1.0), PSNR_CAP_DB)


def frame_psnrs(run, clip: Clip, level: Optional[float], frames: Sequence[int]) -> Dict[int, float]:
    """{g: PSNR} of a run's test renders over `frames` of the domain."""
    root = renders_root(Path(run))
    return {g: frame_psnr(*frame_pair(root, clip, g, level)) for g in frames}


def pick_frame(first: Dict[int, float], ref: Optional[Dict[int, float]] = None) -> int:
    """The frame where `first` (a run's {g: PSNR}) falls furthest below `ref`'s, or without a
    reference the frame where it is lowest; ties go to the earliest frame."""
    if ref is None:
        return min(first, key=lambda g: (first[g], g))
    common = [g for g in first if g in ref]
    if not common:
        raise InputError("the run and the reference share no test frame")
    return min(common, key=lambda g: (first[g] - ref[g], g))


def error_panels(
    runs: Sequence[tuple],
    level: Optional[float],
    g: int,
    ref: Optional[tuple] = None,
    labels: Optional[Sequence[str]] = None,
) -> dict:
    """Everything the figure shows of frame g, as arrays. runs, ref: (run folder, its Clip); each
    run is compared with its own clip's ground truth, as its scores are.

    Returns {"frame", "domain", "gt" [H, W, C] (the reference's clip's, else the first run's),
    "ref": None or a panel, "runs": [panel]} with a panel {"label", "pred" [H, W, C], "sq_err"
    [H, W], "psnr", and beside a reference "d_sq_err" [H, W] (run - reference) and "d_psnr"}."""
    first_clip = (ref or runs[0])[1]
    if g not in domain_frames(first_clip, level):
        dom = "hdr" if level is None else f"ldr {level_name(level)}"
        raise InputError(
            f"frame {g}: not a test frame of {first_clip.root / 'clip.json'} in domain {dom} "
            f"(test frames: {domain_frames(first_clip, level)})"
        )
    labels = list(labels) if labels is not None else [Path(r).name for r, _ in runs]

    def panel(run, clip, label):
        pred, gt = frame_pair(renders_root(Path(run)), clip, g, level)
        se = pixel_sq_error(pred, gt)
        return {
            "label": label,
            "pred": pred,
            "gt": gt,
            "sq_err": se,
            "psnr": min(psnr_from_mse(float(se.mean()), 1.0), PSNR_CAP_DB),
        }

    ref_panel = panel(ref[0], ref[1], Path(ref[0]).name) if ref is not None else None
    out = [panel(r, c, lb) for (r, c), lb in zip(runs, labels)]
    if ref_panel is not None:
        for p in out:
            p["d_sq_err"] = p["sq_err"] - ref_panel["sq_err"]
            p["d_psnr"] = p["psnr"] - ref_panel["psnr"]
    return {
        "frame": g,
        "domain": "hdr" if level is None else f"ldr {level_name(level)}",
        "gt": (ref_panel or out[0])["gt"],
        "ref": ref_panel,
        "runs": out,
    }


def _scale(values: Sequence[np.ndarray], q: float = 99.5) -> float:
    """A colour scale's top: the q-th percentile of the values pooled (at least a tiny positive
    number, so that an all-zero map still draws)."""
    v = np.concatenate([np.abs(np.ravel(a)) for a in values]) if values else np.zeros(1)
    top = float(np.percentile(v, q)) if v.size else 0.0
    return top if top > 0 and math.isfinite(top) else 1e-6


def draw_error_maps(panels: dict, out_png, title: str = "") -> Path:
    """The figure of error_panels' output as a PNG (written atomically)."""
    from eval.figures import pyplot, save_png

    plt = pyplot()
    ref = panels["ref"]
    cols = [("ground truth", panels["gt"], None)]
    if ref is not None:
        cols.append((f"ref: {ref['label']}", ref["pred"], ref))
    cols += [(p["label"], p["pred"], p) for p in panels["runs"]]
    n_rows = 3 if ref is not None else 2
    h, w = panels["gt"].shape[:2]
    cw = 3.2  # inches per image column
    fig = plt.figure(figsize=(cw * (len(cols) + 0.15), n_rows * (cw * h / w + 0.45) + 0.4))
    # a narrow last column holds each map row's colour bar, so that every image keeps its size
    grid = fig.add_gridspec(n_rows, len(cols) + 1, width_ratios=[1.0] * len(cols) + [0.04])
    axes = np.array(
        [[fig.add_subplot(grid[i, j]) for j in range(len(cols))] for i in range(n_rows)]
    )
    for ax in axes.ravel():
        ax.set_axis_off()
    err_top = _scale([np.sqrt(p["sq_err"]) for _, _, p in cols if p is not None])
    d_top = _scale([p["d_sq_err"] for p in panels["runs"]]) if ref is not None else None
    im_err = im_d = None
    for j, (name, img, p) in enumerate(cols):
        ax = axes[0, j]
        ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
        sub = "" if p is None else f"\n{p['psnr']:.2f} dB"
        if p is not None and "d_psnr" in p:
            sub += f" ({p['d_psnr']:+.2f})"
        ax.set_title(name + sub, fontsize=8)
        if p is None:
            continue
        im_err = axes[1, j].imshow(
            np.sqrt(p["sq_err"]), cmap="magma", vmin=0.0, vmax=err_top, interpolation="nearest"
        )
        if ref is not None and p is not ref:
            im_d = axes[2, j].imshow(
                p["d_sq_err"], cmap="RdBu_r", vmin=-d_top, vmax=d_top, interpolation="nearest"
            )
    fig.colorbar(im_err, cax=fig.add_subplot(grid[1, -1]), label="RMS error")
    if im_d is not None:
        fig.colorbar(im_d, cax=fig.add_subplot(grid[2, -1]), label="sq. error - ref's")
    fig.suptitle(title or f"frame {panels['frame']}, {panels['domain']}", fontsize=9)
    return save_png(fig, out_png)


def _open_runs(runs: Sequence, ref, clip_dir) -> tuple:
    """([(run, Clip)], (ref, Clip) or None, the clip the frames and levels come from: the
    reference's, else the first run's), each run's clip from its run.json unless clip_dir; the
    clips must agree pixel for pixel (regions.check_comparable) and have ground truth."""
    if not runs:
        raise InputError("no run to draw")
    clips = [Clip.open(resolve_clip_dir(r, clip_dir)) for r in runs]
    clip = clips[0]
    if ref is not None:
        clip = Clip.open(resolve_clip_dir(ref, clip_dir))
    for c in clips:
        check_comparable(clip, c)
    if not clip.has_gt:
        raise InputError(f"{clip.root / 'gt'}: the clip has no ground truth to compare with")
    return list(zip(runs, clips)), ((ref, clip) if ref is not None else None), clip


def error_maps(
    runs: Sequence,
    out_png,
    *,
    ref=None,
    domain: Optional[str] = None,
    frame: Optional[int] = None,
    clip_dir=None,
    labels: Optional[Sequence[str]] = None,
) -> dict:
    """Draw the figure for runs (and a reference) of one scene: the panels of error_panels plus
    "png" (the written path) and, when the frame was picked, "picked_from" ({g: PSNR difference
    or PSNR} of every candidate frame). Clips are each run's (run.json) unless clip_dir is given;
    the runs' clips must agree pixel for pixel (regions.check_comparable)."""
    pairs, ref_pair, clip = _open_runs(runs, ref, clip_dir)
    level = parse_domain(clip, domain)
    picked_from = None
    if frame is None:
        frames = domain_frames(clip, level)
        if not frames:
            raise InputError(f"{clip.root / 'clip.json'}: no test frame in the domain")
        first = frame_psnrs(runs[0], pairs[0][1], level, frames)
        base = frame_psnrs(ref, clip, level, frames) if ref is not None else None
        frame = pick_frame(first, base)
        picked_from = {g: first[g] - (base[g] if base else 0.0) for g in frames}
    panels = error_panels(pairs, level, int(frame), ref=ref_pair, labels=labels)
    png = draw_error_maps(
        panels, out_png, title=f"{clip.meta.name}, frame {frame}, {panels['domain']}"
    )
    return dict(panels, png=str(png), picked_from=picked_from)


# --------------------------------------------------------------------------------------------------
# the same over every test frame, as a video
# --------------------------------------------------------------------------------------------------
GAP = 4  # pixels between the video's tiles (before scaling)


def colourise(a: np.ndarray, cmap: str, vmin: float, vmax: float) -> np.ndarray:
    """[H, W] values -> [H, W, 3] uint8 through a matplotlib colour map, clipped to [vmin, vmax]."""
    from matplotlib import colormaps

    t = np.clip((np.asarray(a, np.float64) - vmin) / max(vmax - vmin, 1e-12), 0.0, 1.0)
    return (colormaps[cmap](t)[..., :3] * 255.0 + 0.5).astype(np.uint8)


def video_frame(panels: dict, err_top: float, d_top: Optional[float], scale: int = 2) -> np.ndarray:
    """One video frame [H', W', 3] uint8 of error_panels' output: the figure's grid (images; RMS
    error on 'magma' over [0, err_top]; with a reference the squared error's change on 'RdBu_r'
    over [-d_top, d_top]), each tile scaled up `scale` times (nearest) and captioned, tiles GAP
    pixels apart on grey."""
    from m4dgs.core.video import caption

    ref = panels["ref"]
    cols = [("ground truth", panels["gt"], None)]
    if ref is not None:
        cols.append(("ref " + ref["label"], ref["pred"], ref))
    cols += [(p["label"], p["pred"], p) for p in panels["runs"]]
    n_rows = 3 if ref is not None else 2
    h, w = panels["gt"].shape[:2]
    th, tw = h * scale, w * scale
    g = GAP * scale
    out = np.full(
        (n_rows * th + (n_rows - 1) * g, len(cols) * tw + (len(cols) - 1) * g, 3), 96, np.uint8
    )

    def put(i, j, tile, text):
        tile = np.repeat(np.repeat(tile, scale, axis=0), scale, axis=1)
        out[i * (th + g) : i * (th + g) + th, j * (tw + g) : j * (tw + g) + tw] = caption(
            tile, text
        )

    for j, (name, img, p) in enumerate(cols):
        top = f"{name}, frame {panels['frame']}" if p is None else f"{name}: {p['psnr']:.2f} dB"
        if p is not None and "d_psnr" in p:
            top += f" ({p['d_psnr']:+.2f})"
        put(0, j, (np.clip(img, 0, 1) * 255.0 + 0.5).astype(np.uint8), top)
        if p is None:
            continue
        put(
            1,
            j,
            colourise(np.sqrt(p["sq_err"]), "magma", 0.0, err_top),
            f"RMS error, 0..{err_top:.3g}",
        )
        if ref is not None and p is not ref:
            put(
                2,
                j,
                colourise(p["d_sq_err"], "RdBu_r", -d_top, d_top),
                f"sq. error - ref's, ±{d_top:.3g}",
            )
    return out


def error_video(
    runs: Sequence,
    out_mp4,
    *,
    ref=None,
    domain: Optional[str] = None,
    clip_dir=None,
    labels: Optional[Sequence[str]] = None,
    fps: Optional[float] = None,
    scale: int = 2,
) -> dict:
    """The figure's grid over every test frame of the domain as an mp4 (m4dgs.core.video
    .write_mp4), one colour scale for the whole video: the median over the frames of each
    frame's 99.5th percentile (two passes over the renders; larger values saturate). fps:
    default a quarter of the clip's frame rate (test frames are every other frame). Returns
    {"mp4", "domain", "frames", "psnr" {label: [PSNR per frame], the reference's as
    "ref <label>"}, "err_top", "d_top"}."""
    from m4dgs.core.video import write_mp4

    pairs, ref_pair, clip = _open_runs(runs, ref, clip_dir)
    level = parse_domain(clip, domain)
    frames = domain_frames(clip, level)
    if not frames:
        raise InputError(f"{clip.root / 'clip.json'}: no test frame in the domain")

    def panels_of(g):
        return error_panels(pairs, level, g, ref=ref_pair, labels=labels)

    err_tops, d_tops = [], []
    for g in frames:
        pn = panels_of(g)
        shown = ([pn["ref"]] if pn["ref"] else []) + pn["runs"]
        err_tops.append(_scale([np.sqrt(p["sq_err"]) for p in shown]))
        if ref is not None:
            d_tops.append(_scale([p["d_sq_err"] for p in pn["runs"]]))
    err_top = float(np.median(err_tops))
    d_top = float(np.median(d_tops)) if ref is not None else None
    psnr: Dict[str, List[float]] = {}

    def video():
        for g in frames:
            pn = panels_of(g)
            if pn["ref"] is not None:
                psnr.setdefault("ref " + pn["ref"]["label"], []).append(pn["ref"]["psnr"])
            for p in pn["runs"]:
                psnr.setdefault(p["label"], []).append(p["psnr"])
            yield video_frame(pn, err_top, d_top, scale)

    rate = float(fps) if fps else max(clip.meta.fps / 4.0, 1.0)
    path = write_mp4(out_mp4, video(), rate)
    return {
        "mp4": str(path),
        "domain": "hdr" if level is None else f"ldr {level_name(level)}",
        "frames": frames,
        "psnr": psnr,
        "err_top": err_top,
        "d_top": d_top,
    }
