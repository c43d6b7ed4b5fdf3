"""Your own footage as a clip: `m4dgs import-clip` (docs/clip-format.md, "Your own footage").

A clip folder (m4dgs.clip) needs the LDR frames, one exposure time per frame, a depth prior per
frame and point tracks; this module writes one from what a user has:

- frames: a folder of images (sorted by name; 8-bit, or 16-bit / float rounded to 8 bits) or a
  video file (ffmpeg through imageio), optionally every n-th frame;
- exposure times: a text file (one number per frame, or `name value` lines; JSON list or
  {name: value} also work), else the EXIF ExposureTime of every frame when all have one. Times are
  divided by the geometric mean of the distinct levels (clip.json keeps that unit in
  generator.exposure_unit_seconds), so the levels sit around 1 like benchgen's;
- depth (required): one [T, H, W] .npy/.npz, or a folder with one file per frame (.npy, .npz, .exr,
  16-bit .png or .tif; sorted by name), depth or disparity (inverse depth, as many monocular models
  write); resized to the frames when its size differs (larger: the mean of the valid depths under
  each frame pixel; smaller: bilinear); any scale (the bundle adjustment estimates one per frame);
- tracks (optional): [T, N, 2] pixel positions and [T, N] visibility (the layout of CoTracker-style
  trackers) in an .npz (keys tracks + visibility / visible / vis) or two .npy files; without them
  long tracks are chained through OpenCV DIS optical flow between consecutive frames (brightness
  normalised by the exposure times) with a forward-backward check
  (m4dgs.priors.epipolar.tracks_from_flow);
- flow (optional): a folder of `<a>_<b>.flo` (Middlebury) or `<a>_<b>.npy` ([H, W, 2]) files between
  frame positions a and b, written as the clip's flow prior (validity: a forward-backward check
  where both directions are given, else everywhere);
- a new width (optional, `--width`): the frames are resized (area averaging when smaller), the
  height keeping the aspect ratio; tracks and flow given at the source frames' size are scaled with
  them (positions and vectors in continuous pixel coordinates, whose pixel edges sit at integers,
  scale exactly by the size ratio), depth is resized as it is at any size.

Every frame is a training frame (a real clip has no test frames or ground truth) unless `split` is
"alternate": then the odd frames are held out as test frames, each kept as its own ground truth at
the exposure it was captured at (gt/ldr/<level>/<g>.png, clip.json exposures.test_dt; the paper's
Real-Exp-3 protocol), and depth may be given per frame (the training ones are taken) while tracks
and flow refer to the training frames. The camera response is unknown (crf null) and the
unit-exposure value is the paper's 0.5 for real footage. The
clip is written into a temporary folder and renamed into place when complete, so a failed import
leaves nothing half-made."""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from m4dgs.clip import (
    ClipMeta,
    Exposures,
    FlowSet,
    Split,
    TrackSet,
    staged_clip,
)
from m4dgs.core.errors import InputError
from m4dgs.core.io import ldr_to_8bit, read_image

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".bmp")
DEPTH_EXTS = (".npy", ".npz", ".exr", ".png", ".tif", ".tiff")
REAL_UNIT_EXPOSURE_VALUE = 0.5  # paper appendix "Unit Exposure Loss": C_0 = 0.5 for real scenes
DEPTH_HELP = (
    "a depth prior is required: run a monocular depth model on the frames (e.g. Depth Anything "
    "V2, UniDepth, Metric3D or DepthCrafter) and pass its output with --depth: one [T, H, W] "
    ".npy/.npz, or a folder with one .npy/.exr/16-bit .png per frame (--depth-kind disparity for "
    "models that write inverse depth)"
)


@dataclass
class ImportOptions:
    """What `import_clip` reads and how (the CLI options of `m4dgs import-clip`)."""

    frames: Optional[Path] = None  # folder of images
    video: Optional[Path] = None  # or a video file
    every: int = 1  # keep every n-th frame
    max_frames: Optional[int] = None
    width: Optional[int] = None  # resize the frames to this width (the height keeps the aspect)
    exposures: Optional[Path] = None  # exposure-time file; None: EXIF
    depth: Optional[Path] = None
    depth_kind: str = "depth"  # depth | disparity
    tracks: Optional[Path] = None
    visibility: Optional[Path] = None  # with a tracks .npy: the [T, N] visibility .npy
    track_pixel_centre: float = 0.0  # coordinate of the first pixel's centre in the given tracks
    flow: Optional[Path] = None
    fps: float = 30.0
    name: Optional[str] = None
    # "all": every frame trains (no test frames); "alternate": even frames train, odd frames are
    # test frames scored at their own exposure (the paper's Real-Exp-3 protocol)
    split: str = "all"
    # DIS chains: one seed every track_grid pixels (None: 8, fewer on images under 128 px) ...
    track_grid: Optional[int] = None
    track_seed_every: int = 4  # ... in every track_seed_every-th frame of a chain
    max_tracks: int = 20_000
    report: Dict[str, object] = field(default_factory=dict)


# --------------------------------------------------------------------------------------------------
# frames and exposure times
# --------------------------------------------------------------------------------------------------
def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", p.name)]


def list_images(folder: Path, exts=IMAGE_EXTS) -> List[Path]:
    files = sorted(
        (p for p in Path(folder).iterdir() if p.suffix.lower() in exts), key=_natural_key
    )
    if not files:
        raise InputError(f"{folder}: no image files ({', '.join(exts)})")
    return files


def read_frames(opt: ImportOptions) -> Tuple[List[np.ndarray], List[str]]:
    """(frames [H, W, 3] uint8, their source names) after every / max_frames."""
    if (opt.frames is None) == (opt.video is None):
        raise InputError("give the frames as exactly one of --frames DIR or --video FILE")
    step = max(int(opt.every), 1)
    out, names = [], []
    if opt.frames is not None:
        files = list_images(opt.frames)[::step]
        if opt.max_frames:
            files = files[: opt.max_frames]
        for p in files:
            px, kind = read_image(p)
            out.append(ldr_to_8bit(px, kind, p))
            names.append(p.name)
    else:
        import imageio.v2 as iio  # deferred: ffmpeg only for video input

        try:
            reader = iio.get_reader(str(opt.video), "ffmpeg")
        except Exception as e:
            raise InputError(f"{opt.video}: not a readable video ({e})") from e
        with reader:
            for i, fr in enumerate(reader):
                if i % step:
                    continue
                out.append(np.ascontiguousarray(np.asarray(fr)[..., :3], dtype=np.uint8))
                names.append(f"{opt.video.name}#{i}")
                if opt.max_frames and len(out) >= opt.max_frames:
                    break
    shapes = {f.shape for f in out}
    if len(shapes) > 1:
        raise InputError(f"{opt.frames or opt.video}: frames of different sizes {sorted(shapes)}")
    if len(out) < 3:
        raise InputError(f"{opt.frames or opt.video}: {len(out)} frame(s); a clip needs at least 3")
    return out, names


def exif_exposure(path: Path) -> Optional[float]:
    """EXIF ExposureTime (seconds) of an image file, None when it has none."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            exif = im.getexif()
    except Exception:
        return None
    v = exif.get_ifd(0x8769).get(33434) or exif.get(33434)
    try:
        v = float(v)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def read_exposures(path: Path, names: Sequence[str]) -> List[float]:
    """Exposure time per frame from a file: one number per line (in frame order), `name value`
    lines, a JSON list, or a JSON object {frame name: value}."""
    text = Path(path).read_text()
    vals: List[float]
    try:
        data = json.loads(text)
    except ValueError:
        data = None
    if isinstance(data, list):
        vals = [float(v) for v in data]
    elif isinstance(data, dict):
        missing = [n for n in names if n not in data]
        if missing:
            raise InputError(f"{path}: no exposure time for frame(s) {missing[:10]}")
        vals = [float(data[n]) for n in names]
    else:
        rows = [ln.split("#")[0].replace(",", " ").split() for ln in text.splitlines()]
        rows = [r for r in rows if r]
        if rows and all(len(r) >= 2 for r in rows):
            table = {r[0]: r[-1] for r in rows}
            missing = [n for n in names if n not in table]
            if missing:
                raise InputError(f"{path}: no exposure time for frame(s) {missing[:10]}")
            vals = [_number(table[n], path, n) for n in names]
        else:
            vals = [_number(r[0], path, f"line {i + 1}") for i, r in enumerate(rows)]
    if len(vals) != len(names):
        raise InputError(f"{path}: {len(vals)} exposure times for {len(names)} frames")
    for i, v in enumerate(vals):
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"{path}: exposure time of frame {i} ({names[i]}) is {v!r}; need > 0")
    return vals


def _number(s: str, path, where) -> float:
    try:
        if "/" in s:  # 1/250
            a, b = s.split("/", 1)
            return float(a) / float(b)
        return float(s)
    except (ValueError, ZeroDivisionError):
        raise InputError(f"{path}: {where}: {s!r} is not a number") from None


def exposure_levels(dts: Sequence[float], rtol: float = 0.02) -> List[float]:
    """The distinct exposure levels (values within rtol of each other are one level, their mean)."""
    levels: List[List[float]] = []
    for v in sorted(dts):
        if levels and abs(v - levels[-1][0]) <= rtol * levels[-1][0]:
            levels[-1].append(v)
        else:
            levels.append([v])
    return [float(np.mean(lv)) for lv in levels]


# --------------------------------------------------------------------------------------------------
# priors
# --------------------------------------------------------------------------------------------------
def _resize(a: np.ndarray, h: int, w: int, valid: Optional[np.ndarray] = None) -> np.ndarray:
    """[H0, W0(, C)] map resized to (h, w): the mean over each output pixel's footprint when both
    sides shrink (area averaging; with `valid` [H0, W0] bool, over its valid pixels only, 0 where
    it has none), bilinear otherwise."""
    import cv2

    a = a.astype(np.float32)
    if a.shape[:2] == (h, w):
        return a
    if h > a.shape[0] or w > a.shape[1]:
        return cv2.resize(a, (w, h), interpolation=cv2.INTER_LINEAR)
    if valid is None:
        return cv2.resize(a, (w, h), interpolation=cv2.INTER_AREA)
    m = valid.astype(np.float32)
    num = cv2.resize(a * (m if a.ndim == 2 else m[..., None]), (w, h), interpolation=cv2.INTER_AREA)
    den = cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA)
    den = den if a.ndim == 2 else den[..., None]
    return np.where(den > 1e-6, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)


def resize_frames(frames: List[np.ndarray], width: int) -> List[np.ndarray]:
    """Frames [H, W, 3] uint8 resized to `width` x round(H width / W) (area averaging when
    smaller, bilinear when larger)."""
    import cv2

    H, W = frames[0].shape[:2]
    h = max(1, int(round(H * width / W)))
    if (h, width) == (H, W):
        return frames
    interp = cv2.INTER_AREA if width < W else cv2.INTER_LINEAR
    return [cv2.resize(f, (width, h), interpolation=interp) for f in frames]


def _load_array(path: Path, what: str) -> np.ndarray:
    if path.suffix == ".npy":
        return np.load(path)
    if path.suffix == ".npz":
        with np.load(path) as z:
            keys = list(z.keys())
            for k in ("depth", "disparity", "arr_0", what):
                if k in keys:
                    return z[k]
            if len(keys) == 1:
                return z[keys[0]]
            raise InputError(f"{path}: which array is the {what}? keys {keys}")
    raise InputError(f"{path}: expected .npy or .npz")


def count_depth_maps(path: Path) -> Optional[int]:
    """How many depth maps a --depth path holds (the files of a folder, or the first axis of an
    array file); None when it cannot tell."""
    path = Path(path)
    if path.is_dir():
        return len(list_images(path, DEPTH_EXTS))
    if path.is_file() and path.suffix in (".npy", ".npz"):
        return int(np.squeeze(np.asarray(_load_array(path, "depth"))).shape[0])
    return None


def read_depth(opt: ImportOptions, T: int, H: int, W: int) -> np.ndarray:
    """[T, H, W] float32 depth (> 0 where valid, 0 where unknown)."""
    if opt.depth is None:
        raise InputError(DEPTH_HELP)
    p = Path(opt.depth)
    if p.is_dir():
        files = list_images(p, DEPTH_EXTS)
        step = max(int(opt.every), 1)
        # one per kept frame, or one per source frame (then the same every-n-th ones)
        if len(files) != T and len(files[::step]) < T:
            raise InputError(f"{p}: {len(files)} depth files for {T} frames")
        if len(files) != T:
            files = files[::step][:T]
        maps = []
        for f in files:
            if f.suffix in (".npy", ".npz"):
                a = _load_array(f, "depth")
            else:
                a = read_image(f)[0][..., 0]
            maps.append(np.squeeze(np.asarray(a, np.float64)))
    elif p.is_file():
        arr = np.squeeze(np.asarray(_load_array(p, "depth"), np.float64))
        if arr.ndim != 3:
            raise InputError(f"{p}: depth array of shape {arr.shape}; expected [T, H, W]")
        if arr.shape[0] != T:
            step = max(int(opt.every), 1)
            if len(arr[::step]) >= T:
                arr = arr[::step][:T]
            else:
                raise InputError(f"{p}: {arr.shape[0]} depth maps for {T} frames")
        maps = list(arr)
    else:
        raise InputError(f"{p}: no such depth file or folder ({DEPTH_HELP})")
    out = []
    for i, d in enumerate(maps):
        if d.ndim != 2:
            raise InputError(f"{p}: depth map {i} has shape {d.shape}; expected [H, W]")
        d = np.where(np.isfinite(d), d, 0.0)
        if opt.depth_kind == "disparity":
            d = np.where(d > 0, 1.0 / np.maximum(d, 1e-12), 0.0)
        elif opt.depth_kind != "depth":
            raise InputError(f"--depth-kind {opt.depth_kind!r}: expected depth or disparity")
        d = np.maximum(d, 0.0)
        if not (d > 0).any():
            raise InputError(f"{p}: depth map {i} has no positive value")
        out.append(_resize(d, H, W, valid=d > 0))
    opt.report["depth"] = {
        "source": str(p),
        "kind": opt.depth_kind,
        "resized_from": list(maps[0].shape) if maps[0].shape != (H, W) else None,
    }
    return np.stack(out).astype(np.float32)


def read_tracks(
    opt: ImportOptions, T: int, H: int, W: int, source: Optional[Tuple[int, int]] = None
) -> Optional[TrackSet]:
    """Given tracks [T, N, 2] + visibility [T, N] as a TrackSet (clip layout [N, T, 2], pixel
    centres at +0.5), or None when no --tracks. source: (height, width) of the frames the tracks
    were given on, when the clip's (H, W) differs (--width): positions are scaled by the ratio."""
    if opt.tracks is None:
        return None
    p = Path(opt.tracks)
    if p.suffix == ".npz":
        with np.load(p) as z:
            if "tracks" not in z:
                raise InputError(f"{p}: no 'tracks' array (keys {list(z.keys())})")
            tr = np.asarray(z["tracks"], np.float64)
            vk = next((k for k in ("visibility", "visible", "vis") if k in z), None)
            vis = np.asarray(z[vk]) if vk else None
    elif p.suffix == ".npy":
        tr = np.asarray(np.load(p), np.float64)
        vis = None if opt.visibility is None else np.asarray(np.load(opt.visibility))
    else:
        raise InputError(f"{p}: tracks must be .npz (tracks + visibility) or .npy")
    tr = np.squeeze(tr)
    three_d = tr.ndim == 3 and tr.shape[-1] == 3  # 3D trackers (SpatialTracker): x, y, depth
    if three_d:
        tr = tr[..., :2]
    if tr.ndim != 3 or tr.shape[-1] != 2 or tr.shape[0] != T:
        raise InputError(f"{p}: tracks of shape {tr.shape}; expected [T={T}, N, 2] (or [T, N, 3])")
    if vis is None:
        vis = np.ones(tr.shape[:2], bool)
    vis = np.squeeze(vis)
    if vis.shape != tr.shape[:2]:
        raise InputError(f"{p}: visibility of shape {vis.shape}; expected {tr.shape[:2]}")
    vis = (vis > 0.5) if vis.dtype != bool else vis
    xy = tr - float(opt.track_pixel_centre) + 0.5  # clip convention: first pixel centre at 0.5
    if source is not None and tuple(source) != (H, W):
        xy = xy * np.array([W / source[1], H / source[0]])
    inside = (xy[..., 0] >= 0) & (xy[..., 0] < W) & (xy[..., 1] >= 0) & (xy[..., 1] < H)
    vis = vis & inside & np.isfinite(xy).all(-1)
    xy = np.where(vis[..., None], xy, 0.0)
    keep = vis.sum(0) >= 2
    opt.report["tracks"] = {"source": str(p), "num": int(keep.sum()), "given": int(tr.shape[1])}
    if three_d:
        opt.report["tracks"]["third_column"] = "dropped (x, y, depth tracks; depth from --depth)"
    return TrackSet(
        np.transpose(xy[:, keep], (1, 0, 2)).astype(np.float32),
        np.transpose(vis[:, keep], (1, 0)),
        np.arange(T, dtype=np.int64),
    )


def read_flo(path: Path) -> np.ndarray:
    """A Middlebury .flo file as [H, W, 2] float32."""
    with open(path, "rb") as f:
        magic = np.frombuffer(f.read(4), np.float32)
        if magic.size != 1 or magic[0] != 202021.25:
            raise InputError(f"{path}: not a .flo file (bad magic number)")
        w, h = np.frombuffer(f.read(8), np.int32)
        data = np.frombuffer(f.read(), np.float32)
    if data.size != w * h * 2:
        raise InputError(f"{path}: truncated .flo file")
    return data.reshape(h, w, 2).copy()


def read_flow(
    opt: ImportOptions, T: int, H: int, W: int, source: Optional[Tuple[int, int]] = None
) -> Optional[FlowSet]:
    """Given flow files `<a>_<b>.flo|.npy` (frame positions) as a FlowSet, or None. source:
    (height, width) of the frames before --width: flow of that size is resized to (H, W) and its
    vectors scaled by the size ratio."""
    if opt.flow is None:
        return None
    folder = Path(opt.flow)
    src = tuple(source) if source is not None else (H, W)
    flows: Dict[Tuple[int, int], np.ndarray] = {}
    for p in sorted(folder.iterdir()):
        m = re.fullmatch(r"(\d+)_(\d+)\.(flo|npy)", p.name)
        if not m:
            continue
        a, b = int(m.group(1)), int(m.group(2))
        if not (0 <= a < T and 0 <= b < T) or a == b:
            raise InputError(f"{p}: frame positions out of range 0..{T - 1}")
        f = read_flo(p) if p.suffix == ".flo" else np.asarray(np.load(p), np.float32)
        if f.shape != (H, W, 2) and f.shape != (*src, 2):
            raise InputError(f"{p}: flow of shape {f.shape}; expected {(*src, 2)}")
        if f.shape != (H, W, 2):
            f = _resize(f, H, W) * np.array([W / src[1], H / src[0]], np.float32)
        flows[(a, b)] = f
    if not flows:
        raise InputError(f"{folder}: no <a>_<b>.flo or <a>_<b>.npy flow files")
    import torch

    from m4dgs.core.warp import fb_consistency

    pairs, fl, valid = [], [], []
    for (a, b), f in sorted(flows.items()):
        if (b, a) in flows:
            v = fb_consistency(torch.from_numpy(f), torch.from_numpy(flows[(b, a)])).numpy()
        else:
            v = np.ones((H, W), bool)
        pairs.append((a, b))
        fl.append(f)
        valid.append(v)
    opt.report["flow"] = {"source": str(folder), "pairs": len(pairs)}
    return FlowSet(np.asarray(pairs, np.int64), np.stack(fl), np.stack(valid).astype(bool))


def positions_to_frames(fs: FlowSet, frames: Sequence[int]) -> FlowSet:
    """A FlowSet indexed by positions 0..T-1 among `frames` re-indexed by those global frames."""
    idx = np.asarray(frames, np.int64)
    return FlowSet(idx[np.asarray(fs.pairs, np.int64)], fs.flow, fs.valid)


def dis_tracks(frames: List[np.ndarray], dts: Sequence[float], opt: ImportOptions) -> TrackSet:
    """Long tracks chained through DIS flow between consecutive frames (brightness normalised by the
    exposure times, forward-backward checked)."""
    from m4dgs.priors.epipolar import opencv_flow_prior, tracks_from_flow

    T = len(frames)
    H, W = frames[0].shape[:2]
    grid = opt.track_grid or max(2, min(8, min(H, W) // 16))
    fs = opencv_flow_prior(np.stack(frames), list(dts), list(range(T)), mode="consecutive")
    ts = tracks_from_flow(
        fs,
        list(range(T)),
        grid_step=grid,
        seed_every=opt.track_seed_every,
        max_tracks=opt.max_tracks,
    )
    if ts.tracks.shape[0] == 0:
        raise InputError(
            "no track survived the DIS flow chaining (forward-backward check); pass tracks from "
            "a point tracker with --tracks"
        )
    lengths = ts.visible.sum(1)
    opt.report["tracks"] = {
        "source": "DIS optical flow, consecutive frames, forward-backward checked",
        "num": int(ts.tracks.shape[0]),
        "median_length": float(np.median(lengths)),
        "max_length": int(lengths.max()),
    }
    return ts


# --------------------------------------------------------------------------------------------------
# the clip
# --------------------------------------------------------------------------------------------------
def import_clip(out, opt: ImportOptions, force: bool = False) -> Path:
    """Write a clip folder at `out` from the user's footage and priors (module docstring); returns
    the clip folder."""
    out = Path(out)
    if (out / "clip.json").exists() and not force:
        raise InputError(f"{out}: a clip is already there; use --force to replace it")
    frames, names = read_frames(opt)
    T = len(frames)
    src_hw = frames[0].shape[:2]
    if opt.width is not None:
        if int(opt.width) < 16:
            raise InputError(f"--width {opt.width}: expected at least 16 pixels")
        frames = resize_frames(frames, int(opt.width))
    H, W = frames[0].shape[:2]
    if opt.exposures is not None:
        dts = read_exposures(opt.exposures, names)
        source = str(opt.exposures)
    else:
        if opt.frames is None:
            raise InputError("a video has no EXIF: give the exposure times with --exposures FILE")
        files = list_images(opt.frames)[:: max(int(opt.every), 1)][:T]
        ex = [exif_exposure(p) for p in files]
        missing = [p.name for p, v in zip(files, ex) if v is None]
        if missing:
            raise InputError(
                f"{opt.frames}: no EXIF ExposureTime in {len(missing)} frame(s) (e.g. "
                f"{missing[0]}); give the exposure times with --exposures FILE"
            )
        dts, source = [float(v) for v in ex], "EXIF ExposureTime"
    levels = exposure_levels(dts)
    unit = float(np.exp(np.mean(np.log(levels))))
    level_of = [min(levels, key=lambda lv: abs(math.log(lv / d))) for d in dts]
    alternating = len(levels) <= 8
    all_dt = [lv / unit for lv in level_of] if alternating else [d / unit for d in dts]
    if opt.split == "all":
        train, test = list(range(T)), []
    elif opt.split == "alternate":
        if not alternating:
            raise InputError(
                f"--split alternate: the exposure times form {len(levels)} levels; a test frame is "
                "scored at its own exposure, which must be one the training frames have (at most 8 "
                "levels)"
            )
        train, test = list(range(0, T, 2)), list(range(1, T, 2))
        if len(train) < 3 or not test:
            raise InputError(f"--split alternate: {T} frames; it needs at least 6")
        missing = sorted({all_dt[g] for g in test} - {all_dt[g] for g in train})
        if missing:
            g = next(g for g in test if all_dt[g] in missing)
            raise InputError(
                f"--split alternate: test frame {g} ({names[g]}) was captured at an exposure no "
                "training frame has; its LDR-OE would compare against an unobserved level"
            )
    else:
        raise InputError(f"--split {opt.split!r}: expected all or alternate")
    train_dt = [all_dt[g] for g in train]
    # depth: one map per training frame, or (alternate split) per kept or source frame, of which
    # the training ones are taken
    n_depth = count_depth_maps(opt.depth) if opt.depth is not None else None
    if test and n_depth is not None and n_depth != len(train) and n_depth >= T:
        depth = read_depth(opt, T, H, W)[train]
    else:
        depth = read_depth(opt, len(train), H, W)
    tracks = read_tracks(opt, len(train), H, W, src_hw)
    flow = read_flow(opt, len(train), H, W, src_hw)
    if tracks is None:
        tracks = dis_tracks([frames[g] for g in train], train_dt, opt)
    tracks = TrackSet(tracks.tracks, tracks.visible, np.asarray(train, np.int64))
    if flow is not None:
        flow = positions_to_frames(flow, train)
    meta = ClipMeta(
        name=opt.name or out.name,
        width=W,
        height=H,
        fps=float(opt.fps),
        frames=list(range(T)),
        split=Split(train, test),
        exposures=Exposures(
            train_dt=train_dt,
            observed=sorted(set(train_dt)),
            novel=[],
            schedule="alternating" if alternating else "real",
            test_dt=[all_dt[g] for g in test] if test else None,
        ),
        crf=None,
        unit_exposure_value=REAL_UNIT_EXPOSURE_VALUE,
        generator={
            "tool": "m4dgs import-clip",
            "source": str(opt.frames or opt.video),
            "source_frames": names,
            "exposure_source": source,
            "exposure_unit_seconds": unit,
            "exposure_seconds": [float(d) for d in dts],
            "resized_from": [int(src_hw[0]), int(src_hw[1])] if src_hw != (H, W) else None,
        },
        priors={k: v for k, v in opt.report.items()},
    )
    if test:
        meta.gt["source"] = (
            "real footage, --split alternate: each test frame's own LDR frame at its exposure "
            "(gt/ldr/<level>/), nothing else"
        )
    with staged_clip(out, meta) as w:
        for i, g in enumerate(train):
            w.write_input_ldr(g, frames[g])
            w.write_prior_depth(g, depth[i])
        for g in test:
            w.write_gt_ldr(all_dt[g], g, frames[g])
        w.write_prior_tracks(tracks)
        if flow is not None:
            w.write_prior_flow(flow)
    return out
