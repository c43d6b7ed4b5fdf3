"""The clip folder contract (docs/clip-format.md), schema version 1.

A clip is one input video with its priors and, for synthetic clips, the ground truth kept apart for
evaluation::

    <clip>/
      clip.json                 ClipMeta (below), written last by ClipWriter.finalize()
      input/ldr/<g>.png         8-bit training frames (g = global frame index, 5 digits), exposure
      dt from clip.json priors/depth/<g>.exr      depth prior per training frame, channel "Z" ([H,
      W] float32; any scale) priors/tracks.npz         TrackSet over the training frames: tracks [N,
      T, 2] float32 pixels, visible [N, T]
                                bool, frames [T] int64 (global indices)
      priors/flow.npz           FlowSet between training frames of the same exposure level: pairs
      [P, 2] int64
                                (a, b global indices; both directions are separate pairs), flow [P,
                                H, W, 2] float32 F_{a->b}, valid [P, H, W] bool
      gt/                       evaluation only; absent for real clips, only ldr/ (each test
                                frame at exposures.test_dt) for real ones with held-out test frames;
                                a clip made from an HDR video (benchgen from-hdr) has only hdr/,
                                ldr/ and flow.npz
        hdr/<g>.exr             linear HDR radiance, every frame (train and test), [H, W, 3] float32
        ldr/<level>/<g>.png     test frames at every observed and novel level (<level> =
        level_name(dt)) depth/<g>.exr           z-depth, every frame cameras.json
        Cameras: frames, K [G][3][3], c2w [G][4][4] (OpenCV, camera-to-world) flow.npz
        FlowSet between consecutive training frames (both directions) + exact visibility tracks.npz
        TrackSet over ALL frames with points3d [N, G, 3] (world) and dynamic [N] bool
        masks/dynamic/<g>.png   dynamic-object mask (0 / 255)

Pixel coordinates are continuous with pixel centres at integer + 0.5 (see m4dgs.core.camera). Errors
raised by the reader name the file and the field (`ClipError`)."""

from __future__ import annotations

import dataclasses
import hashlib
import math
import shutil
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterator, List, Optional, Sequence

import numpy as np

from m4dgs.core import io as mio
from m4dgs.core.crf import available_crfs as crf_names
from m4dgs.core.errors import InputError

SCHEMA_VERSION = 1
SUPPORTED_SCHEMA_VERSIONS = (1,)


class ClipError(InputError):
    """A malformed clip. The message starts with the offending file and names the field."""

    def __init__(self, path, field_name: str, problem: str):
        self.path = str(path)
        self.field = field_name
        self.problem = problem
        super().__init__(f"{path}: field '{field_name}': {problem}")

    def __reduce__(self):  # pickles (a worker process's error reaches its driver)
        return (type(self), (self.path, self.field, self.problem))


def frame_name(g: int, ext: str) -> str:
    """File name of global frame g, e.g. frame_name(7, 'png') == '00007.png'."""
    return f"{int(g):05d}.{ext}"


def level_name(dt: float) -> str:
    """Folder name of an exposure level, e.g. 0.125 -> '0.125', 2.0 -> '2'."""
    return f"{float(dt):g}"


# --------------------------------------------------------------------------------------------------
# Metadata
# --------------------------------------------------------------------------------------------------
@dataclass
class Split:
    train: List[int]
    test: List[int]


@dataclass
class Exposures:
    # exposure time of each training frame, aligned with split.train (as written on the input)
    train_dt: List[float]
    observed: List[float]  # observed exposure levels (the ones used for training; LDR-OE)
    novel: List[float]  # novel exposure levels (test only; LDR-NE); empty for real clips
    schedule: str = "alternating"  # benchgen.exposure.SCHEDULES, or real
    # real footage split into training and test frames (`m4dgs import-clip --split alternate`, the
    # paper's Real-Exp-3): the exposure each test frame was captured at, aligned with split.test;
    # its only ground truth is that LDR frame (gt/ldr/<level>/<g>.png). None: test frames have gt
    # at every observed and novel level (synthetic)
    test_dt: Optional[List[float]] = None


@dataclass
class ClipMeta:
    name: str
    width: int
    height: int
    fps: float
    frames: List[int]  # all global frame indices 0..G-1
    split: Split
    exposures: Exposures
    crf: Optional[str] = "hdrnerf"  # name of the true CRF (synthetic) or None (real)
    # C0 of the unit-exposure loss (paper appendix: 0.73 synthetic, 0.5 real)
    unit_exposure_value: float = 0.73
    hdr_scale: Optional[float] = None  # global HDR scale applied by the generator (synthetic)
    generator: Dict[str, Any] = field(default_factory=dict)
    # prior profile, seed, parameters / external model names
    priors: Dict[str, Any] = field(default_factory=dict)
    # ground-truth notes (render noise, HDR-TAE floor, ...)
    gt: Dict[str, Any] = field(default_factory=dict)
    schema_version: int = SCHEMA_VERSION

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    @property
    def num_exposure_levels(self) -> int:
        """N_e of the paper: the number of distinct observed levels."""
        return len(self.exposures.observed)

    def train_dt_of(self, g: int) -> float:
        return self.exposures.train_dt[self.split.train.index(g)]

    def test_levels_of(self, g: int) -> List[float]:
        """The levels test frame g has ground-truth LDR at: its captured exposure for a real clip
        with test frames (exposures.test_dt), and the novel exposure of the same instant where the
        clip keeps one (gt.test_ne, {frame: level}: the paper's test_ne frames); else every
        observed and novel level."""
        ex = self.exposures
        if ex.test_dt is not None:
            own = ex.test_dt[self.split.test.index(g)]
            ne = (self.gt.get("test_ne") or {}).get(str(g))
            return [own] + ([float(ne)] if ne is not None and float(ne) != own else [])
        return list(ex.observed) + list(ex.novel)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        if d["exposures"].get("test_dt") is None:  # clip.json of synthetic clips as before
            d["exposures"].pop("test_dt", None)
        return d

    @staticmethod
    def from_dict(d: dict, path="clip.json") -> "ClipMeta":
        return _parse_meta(d, path)


def _req(d: dict, key: str, path, prefix: str = ""):
    if not isinstance(d, dict) or key not in d:
        raise ClipError(path, prefix + key, "missing")
    return d[key]


def _positive_int(v, path, name):
    if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
        raise ClipError(path, name, f"expected a positive integer, got {v!r}")
    return v


def _positive_float_list(v, path, name, allow_empty=False):
    if not isinstance(v, list) or (not v and not allow_empty):
        raise ClipError(path, name, f"expected a non-empty list of numbers, got {v!r}")
    out = []
    for i, x in enumerate(v):
        if not isinstance(x, (int, float)) or isinstance(x, bool) or not math.isfinite(x) or x <= 0:
            raise ClipError(
                path, f"{name}[{i}]", f"exposure must be a finite number > 0, got {x!r}"
            )
        out.append(float(x))
    return out


def _int_list(v, path, name):
    if not isinstance(v, list) or not all(
        isinstance(x, int) and not isinstance(x, bool) for x in v
    ):
        raise ClipError(path, name, f"expected a list of integers, got {v!r}")
    return list(v)


def _parse_meta(d: dict, path) -> ClipMeta:
    if not isinstance(d, dict):
        raise ClipError(path, "<root>", "expected a JSON object")
    ver = _req(d, "schema_version", path)
    if ver not in SUPPORTED_SCHEMA_VERSIONS:
        raise ClipError(
            path,
            "schema_version",
            f"unknown schema version {ver!r} (this reader supports {SUPPORTED_SCHEMA_VERSIONS})",
        )
    name = _req(d, "name", path)
    width = _positive_int(_req(d, "width", path), path, "width")
    height = _positive_int(_req(d, "height", path), path, "height")
    fps = _req(d, "fps", path)
    if not isinstance(fps, (int, float)) or not math.isfinite(fps) or fps <= 0:
        raise ClipError(path, "fps", f"expected a finite number > 0, got {fps!r}")
    frames = _int_list(_req(d, "frames", path), path, "frames")
    if frames != list(range(len(frames))) or not frames:
        raise ClipError(path, "frames", "expected the global indices 0..G-1 in order")
    G = len(frames)
    sp = _req(d, "split", path)
    train = _int_list(_req(sp, "train", path, "split."), path, "split.train")
    test = _int_list(_req(sp, "test", path, "split."), path, "split.test")
    if not train:
        raise ClipError(path, "split.train", "no training frames")
    for nm, lst in (("split.train", train), ("split.test", test)):
        for i, g in enumerate(lst):
            if not 0 <= g < G:
                raise ClipError(path, f"{nm}[{i}]", f"frame index {g} out of range 0..{G - 1}")
        if sorted(set(lst)) != lst:
            raise ClipError(path, nm, "indices must be increasing and unique")
    ex = _req(d, "exposures", path)
    train_dt = _positive_float_list(
        _req(ex, "train_dt", path, "exposures."), path, "exposures.train_dt"
    )
    if len(train_dt) != len(train):
        raise ClipError(
            path,
            "exposures.train_dt",
            f"has {len(train_dt)} values for {len(train)} training frames",
        )
    observed = _positive_float_list(
        _req(ex, "observed", path, "exposures."), path, "exposures.observed"
    )
    novel = _positive_float_list(ex.get("novel", []), path, "exposures.novel", allow_empty=True)
    schedule = ex.get("schedule", "alternating")
    if schedule == "alternating":
        # every training exposure is one of the observed levels (random-values schedules are not)
        for i, dt in enumerate(train_dt):
            if not any(abs(dt - o) <= 1e-6 * max(dt, o) for o in observed):
                raise ClipError(
                    path,
                    f"exposures.train_dt[{i}]",
                    f"{dt!r} is none of the observed levels {observed} (schedule alternating)",
                )
    test_dt = ex.get("test_dt")
    if test_dt is not None:
        test_dt = _positive_float_list(test_dt, path, "exposures.test_dt", allow_empty=True)
        if len(test_dt) != len(test):
            raise ClipError(
                path, "exposures.test_dt", f"has {len(test_dt)} values for {len(test)} test frames"
            )
        for i, dt in enumerate(test_dt):
            if not any(abs(dt - o) <= 1e-6 * max(dt, o) for o in observed):
                raise ClipError(
                    path,
                    f"exposures.test_dt[{i}]",
                    f"{dt!r} is none of the observed levels {observed}",
                )
    crf = d.get("crf")
    if crf is not None and str(crf) not in crf_names():
        raise ClipError(path, "crf", f"unknown camera response {crf!r} (known: {crf_names()})")
    uev = d.get("unit_exposure_value", 0.73)
    if not isinstance(uev, (int, float)) or not 0 < uev < 1:
        raise ClipError(path, "unit_exposure_value", f"expected a number in (0, 1), got {uev!r}")
    hs = d.get("hdr_scale")
    if hs is not None and (not isinstance(hs, (int, float)) or not math.isfinite(hs) or hs <= 0):
        raise ClipError(path, "hdr_scale", f"expected a number > 0 or null, got {hs!r}")
    known = {f.name for f in dataclasses.fields(ClipMeta)}
    unknown = sorted(set(d) - known)
    if unknown:
        raise ClipError(path, unknown[0], "unknown field (schema version 1)")
    return ClipMeta(
        name=str(name),
        width=width,
        height=height,
        fps=float(fps),
        frames=frames,
        split=Split(train=train, test=test),
        exposures=Exposures(
            train_dt=train_dt,
            observed=observed,
            novel=novel,
            schedule=str(schedule),
            test_dt=test_dt,
        ),
        crf=d.get("crf"),
        unit_exposure_value=float(uev),
        hdr_scale=None if hs is None else float(hs),
        generator=dict(d.get("generator", {})),
        priors=dict(d.get("priors", {})),
        gt=dict(d.get("gt", {})),
        schema_version=ver,
    )


# --------------------------------------------------------------------------------------------------
# Array bundles
# --------------------------------------------------------------------------------------------------
@dataclass
class TrackSet:
    """Point tracks. tracks [N, T, 2] pixels (centres at +0.5), visible [N, T] bool, frames [T]
    global indices; optional points3d [N, T, 3] (world) and dynamic [N] bool (ground truth only)."""

    tracks: np.ndarray
    visible: np.ndarray
    frames: np.ndarray
    points3d: Optional[np.ndarray] = None
    dynamic: Optional[np.ndarray] = None

    def to_arrays(self) -> dict:
        d = {
            "tracks": self.tracks.astype(np.float32),
            "visible": self.visible.astype(bool),
            "frames": np.asarray(self.frames, np.int64),
        }
        if self.points3d is not None:
            d["points3d"] = self.points3d.astype(np.float32)
        if self.dynamic is not None:
            d["dynamic"] = self.dynamic.astype(bool)
        return d


@dataclass
class FlowSet:
    """Optical flow between frame pairs. pairs [P, 2] (a, b) global indices, flow [P, H, W, 2]
    F_{a->b} in pixels, valid [P, H, W] bool (prior: confidence mask; ground truth: exact visibility
    of a's pixel in b)."""

    pairs: np.ndarray
    flow: np.ndarray
    valid: np.ndarray

    def index(self, a: int, b: int) -> int:
        hits = np.nonzero((self.pairs[:, 0] == a) & (self.pairs[:, 1] == b))[0]
        if hits.size == 0:
            raise KeyError(f"no flow for pair ({a}, {b})")
        return int(hits[0])

    def get(self, a: int, b: int):
        """(flow [H, W, 2], valid [H, W]) for F_{a->b}."""
        i = self.index(a, b)
        return self.flow[i], self.valid[i]

    def to_arrays(self) -> dict:
        return {
            "pairs": np.asarray(self.pairs, np.int64),
            "flow": self.flow.astype(np.float32),
            "valid": self.valid.astype(bool),
        }


@dataclass
class Cameras:
    """Per-frame pinhole cameras: frames [G], K [G, 3, 3], c2w [G, 4, 4] (OpenCV convention)."""

    frames: np.ndarray
    K: np.ndarray
    c2w: np.ndarray

    def to_json(self) -> dict:
        return {
            "frames": [int(g) for g in self.frames],
            "K": np.asarray(self.K).tolist(),
            "c2w": np.asarray(self.c2w).tolist(),
        }

    @staticmethod
    def from_json(d: dict, path="cameras.json") -> "Cameras":
        for k in ("frames", "K", "c2w"):
            _req(d, k, path)
        frames = np.asarray(d["frames"], np.int64)
        K = np.asarray(d["K"], np.float64)
        c2w = np.asarray(d["c2w"], np.float64)
        G = len(frames)
        if K.shape != (G, 3, 3):
            raise ClipError(path, "K", f"expected shape ({G}, 3, 3), got {K.shape}")
        if c2w.shape != (G, 4, 4):
            raise ClipError(path, "c2w", f"expected shape ({G}, 4, 4), got {c2w.shape}")
        if not (np.isfinite(K).all() and np.isfinite(c2w).all()):
            raise ClipError(path, "K/c2w", "contains NaN or inf")
        R = c2w[:, :3, :3]
        err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max() if G else 0.0
        if err > 1e-4:
            raise ClipError(path, "c2w", f"rotation part is not orthonormal (max error {err:.2e})")
        return Cameras(frames=frames, K=K, c2w=c2w)


def _check_array(
    arr: np.ndarray, path, name: str, shape: Sequence[Optional[int]], finite: bool = True, mask=None
):
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise ClipError(path, name, f"expected shape {want}, got {tuple(arr.shape)}")
    if finite and np.issubdtype(arr.dtype, np.floating):
        vals = arr if mask is None else arr[mask]
        if not np.isfinite(vals).all():
            raise ClipError(path, name, "contains NaN or inf")


# content bounds of the priors: below them training cannot be meaningful, so the clip is refused
MIN_VALID_DEPTH_FRACTION = 0.05  # of the pixels of a depth-prior frame with depth > 0
# of the visible track points lying outside the image ...: tracks in the wrong units (e.g. at twice
# the resolution) put about half of them there, while a tracker's visibility mistakes as the camera
# pans fast leave a tail of a few per cent (benchgen's realistic tracks of a fast pan: 5.7 %)
MAX_OFF_IMAGE_FRACTION = 0.25
OFF_IMAGE_MARGIN = 0.1  # ... by more than this fraction of its width / height
MAX_FLOW_IMAGE_SIZES = 4.0  # largest flow displacement, in image sizes


def _load_npz_fields(path: Path, fields: Sequence[str]) -> dict:
    if not path.exists():
        raise ClipError(path, "<file>", "missing")
    d = mio.read_npz(path)
    for f in fields:
        if f not in d:
            raise ClipError(path, f, "missing")
    return d


def load_trackset(
    path,
    num_frames: Optional[int] = None,
    width: Optional[int] = None,
    height: Optional[int] = None,
) -> TrackSet:
    path = Path(path)
    d = _load_npz_fields(path, ("tracks", "visible", "frames"))
    tr, vis, fr = d["tracks"], d["visible"], d["frames"]
    T = num_frames if num_frames is not None else (tr.shape[1] if tr.ndim == 3 else None)
    _check_array(fr, path, "frames", (T,))
    _check_array(vis, path, "visible", (None, T))
    N = vis.shape[0]
    _check_array(tr, path, "tracks", (N, T, 2), mask=vis.astype(bool))
    if width is not None and height is not None and vis.any():
        # visible positions must lie on the image, up to a margin (trackers report points near the
        # border slightly outside it)
        pts = tr[vis.astype(bool)]
        mx, my = OFF_IMAGE_MARGIN * width, OFF_IMAGE_MARGIN * height
        off = (pts[:, 0] < -mx) | (pts[:, 0] > width + mx) | (pts[:, 1] < -my)
        off |= pts[:, 1] > height + my
        if off.mean() > MAX_OFF_IMAGE_FRACTION:
            raise ClipError(
                path,
                "tracks",
                f"{int(off.sum())} of {len(pts)} visible points lie outside the {width}x{height} "
                "image by more than 10 % of its size (pixel coordinates expected)",
            )
    if (vis.sum(axis=1) >= 2).sum() == 0:
        raise ClipError(path, "visible", "no track is visible in two or more frames")
    p3 = d.get("points3d")
    if p3 is not None:
        _check_array(p3, path, "points3d", (N, T, 3), mask=vis.astype(bool))
    dyn = d.get("dynamic")
    if dyn is not None:
        _check_array(dyn, path, "dynamic", (N,))
    return TrackSet(
        tracks=tr.astype(np.float32),
        visible=vis.astype(bool),
        frames=fr.astype(np.int64),
        points3d=None if p3 is None else p3.astype(np.float32),
        dynamic=None if dyn is None else dyn.astype(bool),
    )


def load_flowset(
    path, width: int, height: int, allowed_frames: Optional[Sequence[int]] = None
) -> FlowSet:
    path = Path(path)
    d = _load_npz_fields(path, ("pairs", "flow", "valid"))
    pairs, flow, valid = d["pairs"], d["flow"], d["valid"]
    _check_array(pairs, path, "pairs", (None, 2))
    P = pairs.shape[0]
    _check_array(flow, path, "flow", (P, height, width, 2))
    _check_array(valid, path, "valid", (P, height, width))
    big = np.abs(flow).max() if flow.size else 0.0
    if big > MAX_FLOW_IMAGE_SIZES * max(width, height):
        i = int(np.abs(flow).reshape(P, -1).max(axis=1).argmax())
        raise ClipError(
            path,
            f"flow[{i}]",
            f"displacements up to {big:.3g} px on a {width}x{height} image (pixels expected)",
        )
    if allowed_frames is not None:
        allowed = set(int(g) for g in allowed_frames)
        for i, (a, b) in enumerate(pairs.tolist()):
            if a not in allowed or b not in allowed:
                raise ClipError(
                    path,
                    f"pairs[{i}]",
                    f"pair ({a}, {b}) names a frame outside {sorted(allowed)[:4]}...",
                )
    return FlowSet(
        pairs=pairs.astype(np.int64), flow=flow.astype(np.float32), valid=valid.astype(bool)
    )


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".hdr", ".tif", ".tiff")


def _missing_clip_json(root: Path) -> str:
    """The problem text for a folder without clip.json: what makes a clip, and from frames which
    command (a folder of images, directly or one level down, is taken for frames)."""
    images = [p for p in root.glob("*") if p.suffix.lower() in IMAGE_SUFFIXES]
    images += [p for p in root.glob("*/*") if p.suffix.lower() in IMAGE_SUFFIXES]
    make = (
        "`m4dgs import-clip --frames FOLDER ...` makes a clip from 8-bit video frames, "
        "`benchgen from-hdr --hdr FOLDER ...` from HDR frames (docs/clip-format.md)"
    )
    if images:
        hdr = any(p.suffix.lower() in (".exr", ".hdr") for p in images)
        return (
            f"missing: this folder holds {len(images)} image(s) ({'HDR ' if hdr else ''}frames?) "
            f"but is not a clip; {make}"
        )
    return f"missing: not a clip folder (an unfinished clip, or another folder?); {make}"


# --------------------------------------------------------------------------------------------------
# Reader
# --------------------------------------------------------------------------------------------------
class Clip:
    """Read-only view of a clip folder. `Clip.open(path)` validates clip.json; `validate()` checks
    every file."""

    def __init__(self, root: Path, meta: ClipMeta):
        self.root = Path(root)
        self.meta = meta

    # -- construction
    # ------------------------------------------------------------------------------------------
    @staticmethod
    def open(root, validate: str = "meta") -> "Clip":
        """Open a clip. validate: 'meta' (clip.json only, cheap), 'full' (every file), or 'none'."""
        root = Path(root)
        mpath = root / "clip.json"
        if not root.is_dir():
            raise ClipError(root, "<folder>", "clip folder does not exist")
        if not mpath.exists():
            raise ClipError(mpath, "<file>", _missing_clip_json(root))
        meta = _parse_meta(mio.read_json(mpath), mpath)
        clip = Clip(root, meta)
        if validate == "full":
            clip.validate()
        return clip

    # -- paths
    # ----------------------------------------------------------------------------------------------
    def path(self, *parts) -> Path:
        return self.root.joinpath(*parts)

    @property
    def has_gt(self) -> bool:
        return (self.root / "gt").is_dir()

    def has_gt_part(self, part: str) -> bool:
        """Whether gt/<part> (a file or folder: "depth", "cameras.json", "masks/dynamic",
        "flow.npz", "tracks.npz", "hdr") is there. A benchgen render has every part; a clip made
        from an HDR video (`benchgen from-hdr`) only gt/hdr, gt/ldr and gt/flow.npz; real footage
        split into training and test frames (`m4dgs import-clip --split alternate`) only gt/ldr."""
        return (self.root / "gt" / part).exists()

    @property
    def width(self) -> int:
        return self.meta.width

    @property
    def height(self) -> int:
        return self.meta.height

    @property
    def train_frames(self) -> List[int]:
        return list(self.meta.split.train)

    @property
    def test_frames(self) -> List[int]:
        return list(self.meta.split.test)

    @property
    def train_dt(self) -> np.ndarray:
        return np.asarray(self.meta.exposures.train_dt, np.float64)

    # -- inputs and priors
    # ---------------------------------------------------------------------------------------
    def _img(self, rel: Path, channels: int) -> np.ndarray:
        p = self.root / rel
        if not p.exists():
            raise ClipError(p, "<file>", "missing frame")
        img = mio.read_png(p)
        want = (self.height, self.width, channels) if channels > 1 else (self.height, self.width)
        if img.shape != want:
            raise ClipError(p, "pixels", f"expected shape {want}, got {img.shape}")
        return img

    def _exr(self, rel: Path, channels: int, nonneg: bool = False) -> np.ndarray:
        p = self.root / rel
        if not p.exists():
            raise ClipError(p, "<file>", "missing frame")
        arr = mio.read_exr(p)
        want = (self.height, self.width, channels) if channels > 1 else (self.height, self.width)
        if arr.shape != want:
            raise ClipError(p, "pixels", f"expected shape {want}, got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ClipError(
                p, "pixels", f"contains NaN or inf ({int((~np.isfinite(arr)).sum())} values)"
            )
        if nonneg and (arr < 0).any():
            raise ClipError(p, "pixels", "contains negative radiance")
        return arr

    def load_ldr(self, g: int) -> np.ndarray:
        """Training frame g as uint8 [H, W, 3]."""
        return self._img(Path("input/ldr") / frame_name(g, "png"), 3)

    def load_depth_prior(self, g: int) -> np.ndarray:
        """Depth prior of training frame g, float32 [H, W] (> 0 where valid, 0 = no value)."""
        rel = Path("priors/depth") / frame_name(g, "exr")
        d = self._exr(rel, 1)
        neg = int((d < 0).sum())
        if neg:
            raise ClipError(
                self.root / rel, "pixels", f"{neg} negative depths (depth must be > 0, 0 = invalid)"
            )
        if (d > 0).mean() < MIN_VALID_DEPTH_FRACTION:
            raise ClipError(
                self.root / rel,
                "pixels",
                f"only {100 * (d > 0).mean():.1f} % of the pixels have a depth > 0 (at least "
                f"{100 * MIN_VALID_DEPTH_FRACTION:.0f} % needed; 0 marks a pixel without depth)",
            )
        return d

    def load_tracks_prior(self) -> TrackSet:
        ts = load_trackset(
            self.root / "priors/tracks.npz",
            num_frames=len(self.train_frames),
            width=self.width,
            height=self.height,
        )
        if ts.frames.tolist() != self.train_frames:
            raise ClipError(
                self.root / "priors/tracks.npz", "frames", "must equal split.train of clip.json"
            )
        return ts

    def load_flow_prior(self) -> FlowSet:
        return load_flowset(
            self.root / "priors/flow.npz", self.width, self.height, self.train_frames
        )

    def has_flow_prior(self) -> bool:
        return (self.root / "priors/flow.npz").exists()

    def stray_inputs(self) -> List[Path]:
        """Files under input/ that the clip contract does not name (anything but
        input/ldr/<training frame>.png): a test frame's image, notes, a copy left over. The
        trainer reads none of them, but they enter `input_fingerprint`."""
        expected = {Path("input/ldr") / frame_name(g, "png") for g in self.train_frames}
        folder = self.root / "input"
        if not folder.is_dir():
            return []
        return sorted(
            p for p in folder.rglob("*") if p.is_file() and p.relative_to(self.root) not in expected
        )

    def input_fingerprint(self) -> str:
        """SHA-256 (hex) of everything a trainer may read: clip.json and every file under input/
        and priors/ (names and contents; ground truth excluded). A run stores it and refuses to
        resume from outputs computed on other inputs."""
        h = hashlib.sha256()
        files = [self.root / "clip.json"]
        for sub in ("input", "priors"):
            if (self.root / sub).is_dir():
                files += sorted(p for p in (self.root / sub).rglob("*") if p.is_file())
        for p in files:
            h.update(p.relative_to(self.root).as_posix().encode() + b"\0")
            with open(p, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
            h.update(b"\0")
        return h.hexdigest()

    # -- ground truth
    # --------------------------------------------------------------------------------------------
    def _need_gt(self):
        if not self.has_gt:
            raise ClipError(
                self.root / "gt", "<folder>", "this clip has no ground truth (real clip?)"
            )

    def load_gt_hdr(self, g: int) -> np.ndarray:
        self._need_gt()
        return self._exr(Path("gt/hdr") / frame_name(g, "exr"), 3, nonneg=True)

    def load_gt_ldr(self, level: float, g: int) -> np.ndarray:
        self._need_gt()
        return self._img(Path("gt/ldr") / level_name(level) / frame_name(g, "png"), 3)

    def load_gt_depth(self, g: int) -> np.ndarray:
        self._need_gt()
        return self._exr(Path("gt/depth") / frame_name(g, "exr"), 1)

    def load_gt_cameras(self) -> Cameras:
        self._need_gt()
        p = self.root / "gt/cameras.json"
        if not p.exists():
            raise ClipError(p, "<file>", "missing")
        cams = Cameras.from_json(mio.read_json(p), p)
        if cams.frames.tolist() != self.meta.frames:
            raise ClipError(p, "frames", "must list every global frame of clip.json")
        return cams

    def load_gt_flow(self) -> FlowSet:
        self._need_gt()
        return load_flowset(self.root / "gt/flow.npz", self.width, self.height, self.meta.frames)

    def load_gt_tracks(self) -> TrackSet:
        self._need_gt()
        return load_trackset(self.root / "gt/tracks.npz", num_frames=self.meta.num_frames)

    def load_gt_dynamic_mask(self, g: int) -> np.ndarray:
        self._need_gt()
        return self._img(Path("gt/masks/dynamic") / frame_name(g, "png"), 1) > 127

    # -- held-out views (benchgen clips: the test frames' instants from other cameras)
    # ----------------------------------------------------------------------------------------------
    def view_names(self) -> List[str]:
        """The clip's held-out views (gt/views/<view>/ with a cameras.json): in the order of
        clip.json gt.views when it lists them, else sorted; [] for a clip without views."""
        folder = self.root / "gt" / "views"
        if not folder.is_dir():
            return []
        have = sorted(p.name for p in folder.iterdir() if (p / "cameras.json").is_file())
        listed = [n for n in (self.meta.gt.get("views") or {}) if n in have]
        return listed + [n for n in have if n not in listed]

    def _view(self, view: str, *parts) -> Path:
        self._need_gt()
        return Path("gt") / "views" / view / Path(*parts)

    def load_view_cameras(self, view: str) -> Cameras:
        """The view's cameras: one per test frame (frames = split.test), gt/cameras.json's
        conventions."""
        p = self.root / self._view(view, "cameras.json")
        if not p.exists():
            raise ClipError(p, "<file>", f"missing (views of this clip: {self.view_names()})")
        cams = Cameras.from_json(mio.read_json(p), p)
        if cams.frames.tolist() != self.test_frames:
            raise ClipError(p, "frames", "must list the test frames of clip.json split.test")
        return cams

    def load_view_hdr(self, view: str, g: int) -> np.ndarray:
        return self._exr(self._view(view, "hdr", frame_name(g, "exr")), 3, nonneg=True)

    def load_view_ldr(self, view: str, level: float, g: int) -> np.ndarray:
        return self._img(self._view(view, "ldr", level_name(level), frame_name(g, "png")), 3)

    def load_view_depth(self, view: str, g: int) -> np.ndarray:
        return self._exr(self._view(view, "depth", frame_name(g, "exr")), 1)

    def load_view_dynamic_mask(self, view: str, g: int) -> np.ndarray:
        return self._img(self._view(view, "masks", "dynamic", frame_name(g, "png")), 1) > 127

    def load_view_covis(self, view: str, g: int) -> np.ndarray:
        """[H, W] bool: pixels whose surface point at least two training frames see (gt/views/
        <view>/covis/<g>.png, 255 = co-visible)."""
        return self._img(self._view(view, "covis", frame_name(g, "png")), 1) > 127

    # -- validation
    # ----------------------------------------------------------------------------------------------
    def validate(self) -> None:
        """Check every file of the contract; raises ClipError naming the first offending file and
        field."""
        for g in self.train_frames:
            self.load_ldr(g)
            self.load_depth_prior(g)
        self.load_tracks_prior()
        if self.has_flow_prior():
            self.load_flow_prior()
        if self.has_gt:
            # gt/hdr and gt/ldr always; depth, masks and cameras where the clip has them (a clip
            # made from an HDR video has none), flow and tracks where present
            for g in self.meta.frames:
                if self.has_gt_part("hdr"):
                    self.load_gt_hdr(g)
                if self.has_gt_part("depth"):
                    self.load_gt_depth(g)
                if self.has_gt_part("masks/dynamic"):
                    self.load_gt_dynamic_mask(g)
            for g in self.test_frames:
                for level in self.meta.test_levels_of(g):
                    self.load_gt_ldr(level, g)
            if self.has_gt_part("cameras.json"):
                self.load_gt_cameras()
            if self.has_gt_part("flow.npz"):
                self.load_gt_flow()
            if self.has_gt_part("tracks.npz"):
                self.load_gt_tracks()
            for view in self.view_names():
                self.load_view_cameras(view)
                for g in self.test_frames:
                    self.load_view_hdr(view, g)
                    self.load_view_depth(view, g)
                    self.load_view_dynamic_mask(view, g)
                    self.load_view_covis(view, g)
                    for level in self.meta.test_levels_of(g):
                        self.load_view_ldr(view, level, g)


def frame_time(clip: Clip, g: float) -> float:
    """Fractional training-frame index of global frame g (linear interpolation over the training
    frames): the time axis of the trainer and of a trained model."""
    train = np.asarray(clip.train_frames, np.float64)
    return float(np.interp(g, train, np.arange(len(train), dtype=np.float64)))


# --------------------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------------------
class ClipWriter:
    """Writes a clip folder file by file (each write atomic); `finalize()` writes clip.json last.

    A folder without clip.json is an unfinished clip: `exists(rel)` lets a generator skip finished
    files and resume."""

    def __init__(self, root, meta: ClipMeta):
        self.root = Path(root)
        self.meta = meta
        _parse_meta(meta.to_dict(), self.root / "clip.json")  # validate early
        self.root.mkdir(parents=True, exist_ok=True)

    def exists(self, *rel) -> bool:
        return self.root.joinpath(*rel).exists()

    def _shape_hw(self, arr: np.ndarray, what: str, channels: int):
        want = (self.meta.height, self.meta.width) + ((channels,) if channels > 1 else ())
        if arr.shape != want:
            raise ValueError(f"{what}: expected shape {want}, got {arr.shape}")

    def write_input_ldr(self, g: int, img: np.ndarray) -> None:
        self._shape_hw(img, f"input/ldr/{g}", 3)
        mio.write_png(self.root / "input/ldr" / frame_name(g, "png"), img)

    def write_prior_depth(self, g: int, depth: np.ndarray) -> None:
        self._shape_hw(depth, f"priors/depth/{g}", 1)
        mio.write_exr(self.root / "priors/depth" / frame_name(g, "exr"), depth)

    def write_prior_tracks(self, ts: TrackSet) -> None:
        mio.write_npz(self.root / "priors/tracks.npz", **ts.to_arrays())

    def write_prior_flow(self, fs: FlowSet) -> None:
        mio.write_npz(self.root / "priors/flow.npz", **fs.to_arrays())

    def write_gt_hdr(self, g: int, hdr: np.ndarray) -> None:
        self._shape_hw(hdr, f"gt/hdr/{g}", 3)
        mio.write_exr(self.root / "gt/hdr" / frame_name(g, "exr"), hdr)

    def write_gt_ldr(self, level: float, g: int, img: np.ndarray) -> None:
        self._shape_hw(img, f"gt/ldr/{level}/{g}", 3)
        mio.write_png(self.root / "gt/ldr" / level_name(level) / frame_name(g, "png"), img)

    def write_gt_depth(self, g: int, depth: np.ndarray) -> None:
        self._shape_hw(depth, f"gt/depth/{g}", 1)
        mio.write_exr(self.root / "gt/depth" / frame_name(g, "exr"), depth)

    def write_gt_cameras(self, cams: Cameras) -> None:
        mio.write_json(self.root / "gt/cameras.json", cams.to_json())

    def write_gt_flow(self, fs: FlowSet) -> None:
        mio.write_npz(self.root / "gt/flow.npz", **fs.to_arrays())

    def write_gt_tracks(self, ts: TrackSet) -> None:
        mio.write_npz(self.root / "gt/tracks.npz", **ts.to_arrays())

    def write_gt_dynamic_mask(self, g: int, mask: np.ndarray) -> None:
        self._shape_hw(mask, f"gt/masks/dynamic/{g}", 1)
        mio.write_png(
            self.root / "gt/masks/dynamic" / frame_name(g, "png"),
            np.where(mask, 255, 0).astype(np.uint8),
        )

    def _view_path(self, view: str, *parts) -> Path:
        return self.root / "gt" / "views" / view / Path(*parts)

    def write_view_cameras(self, view: str, cams: Cameras) -> None:
        mio.write_json(self._view_path(view, "cameras.json"), cams.to_json())

    def write_view_hdr(self, view: str, g: int, hdr: np.ndarray) -> None:
        self._shape_hw(hdr, f"gt/views/{view}/hdr/{g}", 3)
        mio.write_exr(self._view_path(view, "hdr", frame_name(g, "exr")), hdr)

    def write_view_ldr(self, view: str, level: float, g: int, img: np.ndarray) -> None:
        self._shape_hw(img, f"gt/views/{view}/ldr/{level}/{g}", 3)
        mio.write_png(self._view_path(view, "ldr", level_name(level), frame_name(g, "png")), img)

    def write_view_depth(self, view: str, g: int, depth: np.ndarray) -> None:
        self._shape_hw(depth, f"gt/views/{view}/depth/{g}", 1)
        mio.write_exr(self._view_path(view, "depth", frame_name(g, "exr")), depth)

    def write_view_mask(self, view: str, kind: str, g: int, mask: np.ndarray) -> None:
        """A 0 / 255 mask of the view: kind "masks/dynamic" or "covis"."""
        self._shape_hw(mask, f"gt/views/{view}/{kind}/{g}", 1)
        mio.write_png(
            self._view_path(view, kind, frame_name(g, "png")),
            np.where(mask, 255, 0).astype(np.uint8),
        )

    def finalize(self) -> Path:
        """Write clip.json (atomically, last) and return its path."""
        p = self.root / "clip.json"
        mio.write_json(p, self.meta.to_dict())
        return p


@contextmanager
def staged_clip(out, meta: ClipMeta) -> Iterator[ClipWriter]:
    """A ClipWriter into a hidden folder beside `out`: when the block ends it is finalized
    (clip.json from the writer's meta) and renamed into place, replacing whatever `out` held; when
    the block raises it is removed. A refused or interrupted write leaves nothing half-made."""
    out = Path(out)
    tmp = out.parent / f".{out.name}.writing"
    if tmp.exists():
        shutil.rmtree(tmp)
    try:
        w = ClipWriter(tmp, meta)
        yield w
        w.finalize()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
