"""An evaluation clip from an HDR video: `benchgen from-hdr` (docs/clip-format.md, "From an HDR
video").

The paper built its Syn-Exp-3 benchmark from public HDR videos (appendix, "Datasets"): every
other frame a training frame, the others test frames at novel times and views; the training frames
tone-mapped with the HDR-NeRF response at alternating exposure times (LDR-OE), the test frames
also at two novel exposures (LDR-NE); the HDR frames kept as ground truth; depth, tracks and flow
priors from external models run on the LDR training video. This module writes that clip from a
folder of linear HDR frames:

- frames: `.exr` or `.hdr` files sorted by name (numbers in numeric order), optionally every n-th
  and at most N, optionally resized (area averaging); they must be finite and >= 0;
- split: even global frames g = 0, 2, 4, ... train, odd ones test (the clip format's default; the
  paper's "odd indices" counted from 1 are the same frames);
- exposures: the levels and schedule of `benchgen make` (benchgen.exposure: `--exposures 3` is
  observed 0.125, 2, 32 and novel 0.5, 8; alternating), any response of m4dgs.core.crf (default
  the paper's hdrnerf);
- HDR scale: one global factor, chosen like benchgen make's (benchgen.placement: the middle level's
  median code near the middle, highlights kept at the short level, dark and saturated pixels where
  the targets ask), or given with `scale`; what the clip achieved is measured from its PNGs
  (clip.json gt.placement) and a miss is an error unless allowed, since a mis-exposed clip is a
  poor yardstick;
- priors (the reader of `m4dgs import-clip`, m4dgs.footage): depth (required) for the training
  frames, i.e. one map per frame of input/ldr/ (or one per HDR frame kept, or one per HDR file of
  the folder when every / max_frames drop frames: the training ones are taken; `depth_step`);
  tracks and flow optional, indexed by training-frame position (0 = input/ldr/00000.png, 1 = the
  next training frame, ...), DIS-chained tracks without them. `ldr_only` writes just the training
  frames (input/ldr/, no clip.json) for the depth model to run on first;
- ground truth: gt/hdr (every frame, scaled) and gt/ldr (test frames at every observed and novel
  level). HDR-TAE needs flow between consecutive training frames: `gt_flow` writes a given one
  (e.g. RAFT run on the ground truth, as the paper did; the file layout of the flow prior) as
  gt/flow.npz, with gt.hdr_tae_floor the HDR-TAE of the ground truth under it; without it eval
  computes OpenCV DIS flow on the ground-truth HDR frames, the same for every method. No cameras,
  depth, tracks or dynamic masks: the metrics that need them are n/a for such a clip.

The clip is written into a hidden folder beside `out` and renamed into place when complete.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from m4dgs.clip import ClipMeta, Exposures, FlowSet, Split, TrackSet, frame_name, staged_clip
from m4dgs.core import io as mio
from m4dgs.core.crf import clip_crf, tonemap_ldr
from m4dgs.core.errors import InputError

from .exposure import dynamic_range_stops, exposure_preset, schedule_train_dt, test_levels

HDR_EXTS = (".exr", ".hdr")


@dataclass
class HdrVideoOptions:
    """What `clip_from_hdr_video` reads and how (the options of `benchgen from-hdr`)."""

    hdr: Path  # folder of linear HDR frames
    depth: Optional[Path] = None  # depth prior: per training frame (or per HDR frame)
    depth_kind: str = "depth"  # depth | disparity
    tracks: Optional[Path] = None  # [T_train, N, 2] (+ visibility), training-frame positions
    visibility: Optional[Path] = None
    track_pixel_centre: float = 0.0
    flow: Optional[Path] = None  # flow prior files <a>_<b> between training-frame positions
    gt_flow: Optional[Path] = None  # flow for HDR-TAE between consecutive training frames
    exposures: int = 3  # number of observed levels (benchgen.exposure presets: 2 or 3)
    observed: Optional[Sequence[float]] = None
    novel: Optional[Sequence[float]] = None
    schedule: str = "alternating"
    crf: str = "hdrnerf"
    scale: Optional[float] = None  # None: chosen by the exposure-placement targets
    every: int = 1
    max_frames: Optional[int] = None
    width: Optional[int] = None
    fps: float = 30.0
    name: Optional[str] = None
    seed: int = 0  # random schedules
    ldr_only: bool = False
    allow_misplaced: bool = False
    report: Dict[str, object] = field(default_factory=dict)


def read_hdr_frames(
    opt: HdrVideoOptions,
) -> Tuple[List[np.ndarray], List[str], Tuple[int, int]]:
    """(frames [H, W, 3] float32 linear HDR, their file names, their (height, width) before
    --width) after every / max_frames / width."""
    from m4dgs.footage import _resize, list_images

    files = list_images(Path(opt.hdr), HDR_EXTS)[:: max(int(opt.every), 1)]
    if opt.max_frames:
        files = files[: int(opt.max_frames)]
    if opt.width is not None and int(opt.width) < 16:
        raise InputError(f"--width {opt.width}: expected at least 16 pixels")
    frames, size = [], None
    for p in files:
        px, kind = mio.read_image(p)
        if kind != "float":
            raise InputError(f"{p}: field 'pixels': an 8/16-bit image, not linear HDR")
        px = np.asarray(px, np.float32)[..., :3]
        bad = int((~np.isfinite(px)).sum())
        if bad:
            raise InputError(f"{p}: field 'pixels': contains NaN or inf ({bad} values)")
        if (px < 0).any():
            raise InputError(
                f"{p}: field 'pixels': negative radiance ({int((px < 0).sum())} values)"
            )
        if size is None:
            size = px.shape
        elif px.shape != size:
            raise InputError(
                f"{p}: {px.shape[1]}x{px.shape[0]} pixels, the first frame is {size[1]}x{size[0]}"
            )
        if opt.width is not None:  # one frame at a time: a long 4K video need not fit in memory
            h = max(1, int(round(size[0] * int(opt.width) / size[1])))
            px = np.maximum(_resize(px, h, int(opt.width)), 0.0)
        frames.append(px)
    if len(frames) < 6:
        raise InputError(
            f"{opt.hdr}: {len(frames)} frame(s); a clip needs at least 6 (3 training, 3 test)"
        )
    H0, W0 = size[:2]
    return frames, [p.name for p in files], (H0, W0)


def _frames_by_level(hdr, train, train_dt, test, observed) -> Dict[float, np.ndarray]:
    """Unit-scale HDR frames shown at each observed level: its training frames, or the test frames
    (which are tone-mapped at every level) when no training frame has it."""
    res = {}
    for lv in observed:
        gs = [g for g, dt in zip(train, train_dt) if float(dt) == float(lv)] or list(test)
        res[float(lv)] = np.stack([hdr[g] for g in gs])
    return res


def _hdr_tae_floor(hdr, train, fs: FlowSet) -> Optional[float]:
    """HDR-TAE of the ground-truth training sequence with the clip's gt flow (None when a
    consecutive pair lacks a direction)."""
    from m4dgs.core.temporal import hdr_tae_pairs

    index = {(int(a), int(b)): k for k, (a, b) in enumerate(fs.pairs)}
    fwd, bwd, vf, vb = [], [], [], []
    for a, b in zip(train[:-1], train[1:]):
        if (a, b) not in index or (b, a) not in index:
            return None
        fwd.append(fs.flow[index[(a, b)]])
        bwd.append(fs.flow[index[(b, a)]])
        vf.append(fs.valid[index[(a, b)]])
        vb.append(fs.valid[index[(b, a)]])
    vals = hdr_tae_pairs(
        np.stack([hdr[g] for g in train]), np.stack(fwd), np.stack(bwd), np.stack(vf), np.stack(vb)
    )
    vals = [v for v in vals if np.isfinite(v)]
    return float(np.mean(vals)) if vals else None


def depth_step(depth: Path, T: int, G: int, n_files: int, opt: HdrVideoOptions) -> int:
    """Every how many depth maps a training frame's map comes (ImportOptions.every of the depth
    reader), from how many maps `depth` holds: T, one per training frame (step 1); G, one per HDR
    frame kept (step 2: the training frames are the even ones); or, when --every / --max-frames
    dropped HDR frames, n_files, one per HDR file of the --hdr folder (step 2 * every). Any other
    count is an InputError naming the path, the count and every accepted count (a folder or array
    whose count cannot be told is left to the reader)."""
    from m4dgs.footage import count_depth_maps

    n = count_depth_maps(depth)
    every = max(int(opt.every), 1)
    steps = {T: 1, G: 2}
    if n_files != G:
        steps.setdefault(n_files, 2 * every)
    if n is None or n in steps:
        return steps.get(n, 1)
    accepted = [
        f"{T} (one per training frame: the PNGs of input/ldr/)",
        f"{G} (one per HDR frame kept; the training ones are taken)",
    ]
    if n_files != G:
        accepted.append(f"{n_files} (one per HDR file in {opt.hdr}, before --every / --max-frames)")
    raise InputError(
        f"{depth}: field 'depth maps': {n} found; expected "
        + (", ".join(accepted[:-1]) + " or " + accepted[-1])
    )


def clip_from_hdr_video(out, opt: HdrVideoOptions, force: bool = False) -> Path:
    """Write the evaluation clip of an HDR video at `out` (module docstring); returns its folder
    (with `ldr_only`: the folder holding only input/ldr/)."""
    from m4dgs.footage import (
        DEPTH_HELP,
        ImportOptions,
        dis_tracks,
        list_images,
        positions_to_frames,
        read_depth,
        read_flow,
        read_tracks,
    )

    from .placement import PlacementTargets, choose_hdr_scale, measure_placement

    out = Path(out)
    if (out / "clip.json").exists() and not force:
        raise InputError(f"{out}: a clip is already there; use --force to replace it")
    try:
        f = clip_crf(opt.crf)
    except ValueError as e:
        raise InputError(f"--crf {opt.crf}: {e}") from e
    frames, names, src_hw = read_hdr_frames(opt)
    G = len(frames)
    H, W = frames[0].shape[:2]
    train, test = list(range(0, G, 2)), list(range(1, G, 2))
    try:
        settings = exposure_preset(opt.exposures, opt.schedule, opt.observed, opt.novel)
    except ValueError as e:
        raise InputError(str(e)) from e
    train_dt = [float(v) for v in schedule_train_dt(len(train), settings, opt.seed)]
    targets = PlacementTargets()
    if opt.scale is None:
        unit = _frames_by_level(frames, train, train_dt, test, settings.observed)
        if max(float(a.max()) for a in unit.values()) <= 0:
            raise InputError(f"{opt.hdr}: every frame is black")
        try:
            scale, scale_report = choose_hdr_scale(unit, f, targets)
        except ValueError as e:
            raise InputError(f"{opt.hdr}: {e}; give --scale") from e
    else:
        if not (float(opt.scale) > 0 and np.isfinite(float(opt.scale))):
            raise InputError(f"--scale {opt.scale}: expected a finite number > 0")
        scale, scale_report = float(opt.scale), {"scale": float(opt.scale), "given": True}
    hdr = frames
    for fr in hdr:  # in place: the unit frames are not needed again
        fr *= np.float32(scale)
    ldr_train = {g: tonemap_ldr(hdr[g], dt, f) for g, dt in zip(train, train_dt)}

    if opt.ldr_only:
        out.mkdir(parents=True, exist_ok=True)
        if (out / "clip.json").exists():
            (out / "clip.json").unlink()  # --force: the folder is an unfinished clip now
        for g in train:
            mio.write_png(out / "input" / "ldr" / frame_name(g, "png"), ldr_train[g])
        return out
    if opt.depth is None:
        raise InputError(
            DEPTH_HELP.replace("on the frames", "on the training frames")
            + "; `--ldr-only` writes them first (OUT/input/ldr/), then rerun with --depth"
        )

    given = [p for p in (opt.depth, opt.tracks, opt.visibility, opt.flow, opt.gt_flow) if p]
    inside = [str(p) for p in given if Path(p).resolve().is_relative_to(out.resolve())]
    if inside:
        raise InputError(
            f"{', '.join(inside)}: inside --out {out}, which the finished clip replaces; keep "
            "the priors elsewhere"
        )
    T = len(train)
    io_opt = ImportOptions(
        depth=Path(opt.depth),
        depth_kind=opt.depth_kind,
        every=depth_step(Path(opt.depth), T, G, len(list_images(Path(opt.hdr), HDR_EXTS)), opt),
        tracks=opt.tracks,
        visibility=opt.visibility,
        track_pixel_centre=opt.track_pixel_centre,
        flow=opt.flow,
    )
    depth = read_depth(io_opt, T, H, W)
    tracks = read_tracks(io_opt, T, H, W)
    flow = read_flow(io_opt, T, H, W)
    if tracks is None:
        tracks = dis_tracks([ldr_train[g] for g in train], train_dt, io_opt)
    tracks = TrackSet(tracks.tracks, tracks.visible, np.asarray(train, np.int64))
    if flow is not None:
        flow = positions_to_frames(flow, train)
    gt_flow, gt_flow_note = (
        None,
        {
            "source": None,
            "note": "no gt/flow.npz: eval computes HDR-TAE with OpenCV DIS flow on the "
            "ground-truth HDR frames, the same flow for every method",
        },
    )
    if opt.gt_flow is not None:
        gt_flow = positions_to_frames(
            read_flow(ImportOptions(flow=Path(opt.gt_flow)), T, H, W), train
        )
        gt_flow_note = {"source": str(opt.gt_flow), "pairs": int(len(gt_flow.pairs))}
    meta = ClipMeta(
        name=opt.name or out.name,
        width=W,
        height=H,
        fps=float(opt.fps),
        frames=list(range(G)),
        split=Split(train, test),
        exposures=Exposures(
            train_dt=train_dt,
            observed=list(settings.observed),
            novel=list(settings.novel),
            schedule=settings.schedule,
        ),
        crf=f.name,
        unit_exposure_value=float(f(np.float64(1.0))),
        hdr_scale=float(scale),
        generator={
            "tool": "benchgen from-hdr",
            "source": str(opt.hdr),
            "source_frames": names,
            "every": int(opt.every),
            "resized_from": list(src_hw) if tuple(src_hw) != (H, W) else None,
            "exposures": settings.to_dict(),
            "seed": int(opt.seed),
            "crf": f.name,
        },
        priors={k: v for k, v in io_opt.report.items()},
    )
    with staged_clip(out, meta) as w:
        for g in range(G):
            w.write_gt_hdr(g, hdr[g])
        for i, g in enumerate(train):
            w.write_input_ldr(g, ldr_train[g])
            w.write_prior_depth(g, depth[i])
        for lv in test_levels(settings):
            for g in test:
                w.write_gt_ldr(lv, g, tonemap_ldr(hdr[g], float(lv), f))
        w.write_prior_tracks(tracks)
        if flow is not None:
            w.write_prior_flow(flow)
        if gt_flow is not None:
            w.write_gt_flow(gt_flow)
        meta.gt.update(
            {
                "source": "HDR video (benchgen from-hdr): no cameras, depth, tracks or masks",
                "hdr_scale_report": scale_report,
                "crf": f.metadata(),
                "flow": gt_flow_note,
                "hdr_tae_floor": None if gt_flow is None else _hdr_tae_floor(hdr, train, gt_flow),
                "hdr_tae_floor_convention": "HDR-TAE (channel sum) of the gt training sequence "
                "with the given gt flow (gt.flow); null without one",
                "dynamic_range_stops": dynamic_range_stops(hdr[g] for g in train),
            }
        )
        # what the clip achieved, from its PNGs
        meta.gt["placement"] = measure_placement(w.root, meta, targets)
    _check_placement(out, meta.gt["placement"], opt)
    return out


def _check_placement(out: Path, placement: dict, opt: HdrVideoOptions) -> None:
    """A missed exposure-placement target is an error (the clip stays, clip.json gt.placement says
    what it achieved) unless allowed; then a warning."""
    import sys

    from .make import PlacementError
    from .placement import placement_failures

    bad = placement_failures(placement)
    if not bad:
        return
    how = "the given --scale" if opt.scale is not None else "the scale chosen for the targets"
    msg = (
        f"{out}: at {how} the clip misses its exposure-placement targets (clip.json "
        f"gt.placement): " + "; ".join(bad) + ". Try another --scale (clip.json hdr_scale is the "
        "one used) or other --observed levels"
    )
    if opt.allow_misplaced:
        print(f"warning: {msg}; kept (--allow-misplaced).", file=sys.stderr)
        return
    raise PlacementError(msg + ", or pass --allow-misplaced to keep the clip anyway.")


def summary_lines(clip_dir) -> List[str]:
    """What `benchgen from-hdr` made, in a few lines for the user: frames and split, resolution,
    exposure levels, priors, exposure placement and the next commands (train, then score)."""
    from m4dgs.clip import Clip

    from .placement import placement_failures
    from .show import priors_view

    clip = Clip.open(clip_dir)
    m = clip.meta
    root = Path(clip_dir)

    def levels(vs) -> str:
        return ", ".join(f"{float(v):g}" for v in vs)

    resized = m.generator.get("resized_from")
    size = f"{m.width}x{m.height}" + (
        f" (resized from {resized[1]}x{resized[0]})" if resized else ""
    )
    pv = priors_view(clip)
    src = pv.get("sources", {})
    tracks = f"tracks {pv['tracks']}" + (f" ({src['tracks']})" if "tracks" in src else "")
    flow = "no flow" if pv["flow"] is None else f"flow {pv['flow']} pairs"
    gt_flow = "given" if clip.has_gt_part("flow.npz") else "none (eval uses DIS flow on gt/hdr)"
    bad = placement_failures(m.gt.get("placement") or {})
    run = Path("runs") / root.name / "full"
    return [
        f"clip {m.name}: {m.num_frames} frames, {size}: {len(clip.train_frames)} training (even), "
        f"{len(clip.test_frames)} test (odd)",
        f"exposures: training frames at {levels(m.exposures.observed)} "
        f"({m.exposures.schedule}), test frames at those and novel {levels(m.exposures.novel)}; "
        f"response {m.crf}, HDR scale {m.hdr_scale:.4g}",
        f"priors: depth {pv['depth']} maps"
        + (f" ({src['depth']})" if "depth" in src else "")
        + f", {tracks}, {flow}; gt flow: {gt_flow}",
        "exposure placement: "
        + ("every target met" if not bad else "misses " + "; ".join(bad) + " (kept)"),
        f"next: m4dgs train --clip {root} --preset small   (writes {run}), then "
        f"m4dgs-eval score {run}",
    ]
