"""Other projects' dataset folders as clips: `m4dgs import-clip --format mono4dgs-hdr|nerfies DIR`
(docs/clip-format.md, "Other formats"; the layouts are described in m4dgs.formats).

Frames that are 8-bit RGB PNGs keep their exact bytes (others are converted to 8-bit RGB PNGs),
EXR ground truth keeps its bytes, cameras convert exactly. Priors the folder holds are kept (a depth
folder, a track file); --depth and --tracks replace them, and without tracks long tracks are
chained through DIS optical flow as for any footage (m4dgs.footage). Everything `benchgen export`
writes comes back, so that an export and its import give the same clip."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from m4dgs.clip import (
    Cameras,
    Clip,
    ClipMeta,
    Exposures,
    Split,
    TrackSet,
    frame_name,
    level_name,
    staged_clip,
)
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError
from m4dgs.footage import (
    DEPTH_HELP,
    REAL_UNIT_EXPOSURE_VALUE,
    ImportOptions,
    dis_tracks,
    exposure_levels,
    positions_to_frames,
    read_depth,
    read_flow,
    read_tracks,
)
from m4dgs.formats import CLIP_META_FILE, copy_file, read_json_file
from m4dgs.formats import field as json_field
from m4dgs.formats import mono4dgs_hdr as m4f
from m4dgs.formats import nerfies as nf

SYNTHETIC_UNIT_EXPOSURE_VALUE = 0.73  # the paper's C_0 for its synthetic data (hdrnerf curve)


@dataclass
class _View:
    cams: Cameras
    ldr: Dict[int, Dict[float, Path]]
    hdr: Dict[int, Path]
    depth: Dict[int, np.ndarray]
    mask: Dict[int, Path]
    covis: Dict[int, Path]


@dataclass
class _Source:
    """What a format folder holds, indexed by global frame."""

    train: List[int]
    test: List[int]
    train_dt: List[float]
    frames: Dict[int, Path]  # training frames
    test_ldr: Dict[int, Dict[float, Path]]
    observed: List[float]
    novel: List[float]
    test_dt: Optional[List[float]] = None
    hdr: Dict[int, Path] = field(default_factory=dict)
    cameras: Optional[Cameras] = None
    gt_depth: Dict[int, np.ndarray] = field(default_factory=dict)
    masks: Dict[int, Path] = field(default_factory=dict)
    views: Dict[str, _View] = field(default_factory=dict)
    depth_prior: Optional[np.ndarray] = None  # [T, H, W]
    tracks: Optional[TrackSet] = None  # positions 0..T-1
    source_meta: Optional[dict] = None
    gt_notes: Dict[str, object] = field(default_factory=dict)


# --------------------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------------------
def _png_is_rgb8(path: Path) -> bool:
    """Whether a PNG's header says 8-bit RGB (its bytes can be a clip frame as they are)."""
    with open(path, "rb") as f:
        head = f.read(26)
    return head[:8] == mio.PNG_SIGNATURE and head[24] == 8 and head[25] == 2


def _put_png(src: Path, dst: Path, hw, grey: bool = False) -> None:
    """A frame (or a 0 / 255 mask with grey) into the clip: checked, and copied byte for byte when
    it is already what the clip holds, else converted."""
    px, kind = mio.read_image(src)
    if px.shape[:2] != tuple(hw):
        raise InputError(f"{src}: field 'pixels': expected {hw[0]}x{hw[1]}, got {px.shape[:2]}")
    if grey:
        m = np.asarray(px)[..., 0] > (127 if kind == "uint8" else 0.5)
        mio.write_png(dst, np.where(m, 255, 0).astype(np.uint8))
    elif src.suffix.lower() == ".png" and _png_is_rgb8(src):
        mio.check_png_bytes(src)
        copy_file(src, dst)
    else:
        mio.write_png(dst, mio.ldr_to_8bit(px, kind, src))


def _put_exr(src: Path, dst: Path, hw) -> None:
    a = mio.read_exr(src)
    if a.shape != (hw[0], hw[1], 3):
        raise InputError(f"{src}: field 'pixels': expected [{hw[0]}, {hw[1]}, 3], got {a.shape}")
    if not np.isfinite(a).all() or (a < 0).any():
        raise InputError(f"{src}: field 'pixels': NaN, inf or negative radiance")
    copy_file(src, dst)


def _stems_are_frames(names) -> bool:
    return all(re.fullmatch(r"\d+", Path(n).stem) for n in names)


def _files(folder: Path, exts) -> List[Path]:
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in exts)


def _read_npy(path: Path, what: str) -> np.ndarray:
    try:
        a = np.load(path, allow_pickle=False)
    except Exception as e:
        raise InputError(f"{path}: field '{what}': not a readable .npy ({e})") from None
    a = np.squeeze(np.asarray(a, np.float64))
    if a.ndim != 2:
        raise InputError(f"{path}: field '{what}': expected [H, W] or [H, W, 1], got {a.shape}")
    return np.where(np.isfinite(a), a, 0.0)


def _tracks_file(path: Path, T: int, centre: float) -> TrackSet:
    """A [T, N, 2|3] tracks + [T, N] visibility .npz as a TrackSet over positions 0..T-1 (pixel
    centres moved from `centre` to the clip's 0.5)."""
    z = mio.read_npz(path)
    tr = np.asarray(json_field(z, "tracks", path), np.float64)
    vis_key = next((k for k in ("visibility", "visible", "vis") if k in z), "visibility")
    vis = np.asarray(json_field(z, vis_key, path)).astype(bool)
    if tr.ndim != 3 or tr.shape[0] != T or tr.shape[2] not in (2, 3):
        raise InputError(f"{path}: field 'tracks': expected [{T}, N, 2 or 3], got {tr.shape}")
    if vis.shape != tr.shape[:2]:
        raise InputError(f"{path}: field '{vis_key}': expected {tr.shape[:2]}, got {vis.shape}")
    xy = tr[..., :2] + (0.5 - centre)
    vis = vis & np.isfinite(xy).all(-1)
    xy = np.where(np.isfinite(xy), xy, 0.0)
    return TrackSet(np.swapaxes(xy, 0, 1).astype(np.float32), vis.T.copy(), np.arange(T))


# --------------------------------------------------------------------------------------------------
# Mono4DGS-HDR
# --------------------------------------------------------------------------------------------------
def read_mono4dgs_hdr(src: Path) -> _Source:
    ex_path = src / m4f.EXPOSURES_FILE
    ex = read_json_file(ex_path)
    img_dir = src / m4f.IMAGES_DIR if (src / m4f.IMAGES_DIR).is_dir() else src / m4f.TRAIN_DIR
    train_files = _files(img_dir, (".png", ".jpg", ".jpeg"))
    if len(train_files) < 3:
        raise InputError(
            f"{img_dir}: {len(train_files)} training frame(s); a clip needs at least 3"
        )
    t_dt = m4f.exposure_times(ex, "train", ex_path)
    missing = [p.name for p in train_files if p.name not in t_dt]
    if missing:
        raise InputError(f"{ex_path}: field 'train.{missing[0]}': missing (a frame of {img_dir})")
    test_files = _files(src / m4f.TEST_DIR, (".png", ".jpg", ".jpeg"))
    ne_files = _files(src / m4f.TEST_NE_DIR, (".png", ".jpg", ".jpeg"))
    te_dt = m4f.exposure_times(ex, "test", ex_path) if test_files else {}
    ne_dt = m4f.exposure_times(ex, "test_ne", ex_path) if ne_files else {}
    for files, table, key in ((test_files, te_dt, "test"), (ne_files, ne_dt, "test_ne")):
        for p in files:
            if p.name not in table:
                raise InputError(
                    f"{ex_path}: field '{key}.{p.name}': missing (a frame of {p.parent})"
                )
    # global frame indices: the file names when they are all numbers (as `benchgen export` writes),
    # else the paper's split: training frame i is frame 2i, test frame j frame 2j + 1
    names = [p.name for p in train_files + test_files + ne_files]
    if _stems_are_frames(names):
        g_train = [int(p.stem) for p in train_files]
        g_of_test = {p.stem: int(p.stem) for p in test_files + ne_files}
    else:
        g_train = [2 * i for i in range(len(train_files))]
        stems = sorted({p.stem for p in test_files + ne_files})
        g_of_test = {s: 2 * j + 1 for j, s in enumerate(stems)}
    test = sorted(set(g_of_test.values()))
    G = len(g_train) + len(test)
    if sorted(g_train + test) != list(range(G)):
        raise InputError(
            f"{src}: frames {sorted(g_train + test)[:12]}...: training and test frames must number "
            f"0..{G - 1} together"
        )
    levels = exposure_levels(list(t_dt[p.name] for p in train_files))

    def snap(v):  # a level within 2 % of a training level is that level
        near = min(levels, key=lambda lv: abs(math.log(lv / v)))
        return near if abs(math.log(near / v)) <= math.log(1.02) else v

    s = _Source(
        train=g_train,
        test=test,
        train_dt=[snap(t_dt[p.name]) for p in train_files],
        frames=dict(zip(g_train, train_files)),
        test_ldr={g: {} for g in test},
        observed=levels,
        novel=[],
    )
    lv_dir = src / m4f.TEST_LEVELS_DIR
    if lv_dir.is_dir():  # every test frame at every level (benchgen export)
        for d in sorted(lv_dir.iterdir(), key=lambda p: float(p.name)):
            for p in _files(d, (".png",)):
                s.test_ldr[g_of_test[p.stem]][float(d.name)] = p
        all_levels = sorted({lv for d in s.test_ldr.values() for lv in d})
        s.novel = [lv for lv in all_levels if lv not in levels]
    else:
        for p in test_files:
            s.test_ldr[g_of_test[p.stem]][snap(te_dt[p.name])] = p
        no_oe = [g for g in test if not s.test_ldr[g]]
        if no_oe:
            raise InputError(f"{src / m4f.TEST_DIR}: no frame for test frame {no_oe[0]}")
        s.test_dt = [next(iter(s.test_ldr[g])) for g in test]
        if ne_files:  # kept beside the clip's LDR-OE ground truth, listed in clip.json gt
            s.gt_notes["test_ne"] = {}
            for p in ne_files:
                g, lv = g_of_test[p.stem], ne_dt[p.name]
                s.test_ldr[g][lv] = p
                s.gt_notes["test_ne"][str(g)] = lv
            # the novel levels: rendered by a run at every test frame and scored as LDR-NE on
            # the frames that have one (ClipMeta.test_levels_of)
            s.novel = sorted({float(lv) for lv in ne_dt.values()} - set(levels))
    tr_exr = _files(src / m4f.TRAIN_EXR_DIR, (".exr",))
    te_exr = _files(src / m4f.TEST_EXR_DIR, (".exr",))
    if tr_exr or te_exr:
        if len(tr_exr) != len(train_files) or len(te_exr) != len(test):
            raise InputError(
                f"{src}: {len(tr_exr)} train_exr / {len(te_exr)} test_exr files for "
                f"{len(train_files)} training and {len(test)} test frames; HDR ground truth needs "
                "one per frame (in the order of the frames' names)"
            )
        s.hdr = dict(zip(g_train, tr_exr))
        s.hdr.update(dict(zip(test, te_exr)))
    cam_path = src / m4f.CAMERAS_GT_FILE
    if cam_path.is_file():
        s.cameras = Cameras.from_json(mio.read_json(cam_path), cam_path)
    # priors the folder holds: a <mode>_depth/ folder ("prior" first) and a *_tap.npz track file
    depth_dirs = sorted(p for p in src.glob(f"*{m4f.DEPTH_SUFFIX}") if p.is_dir())
    if depth_dirs:
        d = next((p for p in depth_dirs if p.name == m4f.PRIOR_DEPTH_DIR), None)
        if d is None and len(depth_dirs) > 1:
            raise InputError(
                f"{src}: several depth folders ({', '.join(p.name for p in depth_dirs)}); choose "
                "one with --depth"
            )
        d = d or depth_dirs[0]
        maps = []
        for p in train_files:
            f = d / f"{p.stem}.npz"
            if not f.is_file():
                raise InputError(f"{f}: missing (the depth of training frame {p.name})")
            maps.append(np.asarray(json_field(mio.read_npz(f), "dep", f), np.float32))
        s.depth_prior = np.stack(maps)
        s.gt_notes["depth_prior_source"] = str(d)
    taps = sorted(src.glob(f"*{m4f.TRACKS_SUFFIX}"))
    if taps:
        tap = next((p for p in taps if p.name == m4f.PRIOR_TRACKS_FILE), taps[0])
        s.tracks = _tracks_file(tap, len(train_files), centre=0.0)
        s.gt_notes["tracks_prior_source"] = str(tap)
    return s


# --------------------------------------------------------------------------------------------------
# Nerfies / DyCheck
# --------------------------------------------------------------------------------------------------
def _factor_dir(src: Path) -> tuple:
    rgb = src / "rgb"
    facs = (
        sorted((int(p.name[:-1]), p.name) for p in rgb.iterdir() if re.fullmatch(r"\d+x", p.name))
        if rgb.is_dir()
        else []
    )
    if not facs:
        raise InputError(f"{rgb}: missing (the layout's images are in rgb/<f>x/)")
    return facs[0]


def read_nerfies(src: Path) -> _Source:
    ds_path, md_path = src / nf.DATASET_FILE, src / nf.METADATA_FILE
    ds, md = read_json_file(ds_path), read_json_file(md_path)
    train_ids = [str(i) for i in json_field(ds, "train_ids", ds_path, list)]
    val_ids = [str(i) for i in json_field(ds, "val_ids", ds_path, list)]
    factor, fdir = _factor_dir(src)

    def info(iid):
        e = json_field(md, iid, md_path, dict)
        t = e.get("time_id", e.get("warp_id"))
        if not isinstance(t, int) or isinstance(t, bool):
            raise InputError(f"{md_path}: field '{iid}.warp_id': expected an integer, got {t!r}")
        c = e.get("camera_id", 0)
        if not isinstance(c, int) or isinstance(c, bool):
            raise InputError(f"{md_path}: field '{iid}.camera_id': expected an integer, got {c!r}")
        dt = e.get("exposure", 1.0)
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not dt > 0:
            raise InputError(
                f"{md_path}: field '{iid}.exposure': expected a number > 0, got {dt!r}"
            )
        return t, c, float(dt), e.get("view")

    def camera(iid):
        p = src / nf.CAMERA_DIR / f"{iid}.json"
        K, c2w, size = nf.camera_from_json(read_json_file(p), p, scale=1.0 / factor)
        h, w = mio.read_image(rgb(iid))[0].shape[:2]
        if size != (w, h):
            raise InputError(
                f"{p}: field 'image_size': {size[0] * factor}x{size[1] * factor} is "
                f"{size[0]}x{size[1]} at rgb/{fdir}, but {rgb(iid)} is {w}x{h}"
            )
        return K, c2w, size

    def rgb(iid):
        p = src / "rgb" / fdir / f"{iid}.png"
        if not p.is_file():
            raise InputError(f"{p}: missing (image of id {iid} in {ds_path})")
        return p

    tr = sorted((info(i) + (i,) for i in train_ids), key=lambda r: r[0])
    cams_used = sorted({r[1] for r in tr})
    if len(cams_used) != 1:
        raise InputError(
            f"{ds_path}: field 'train_ids': images of cameras {cams_used}; a clip is one camera "
            "(import a monocular capture)"
        )
    path_cam = cams_used[0]
    times = [r[0] for r in tr]
    if len(set(times)) != len(times):
        raise InputError(f"{md_path}: field 'warp_id': two training images share a time")
    val = [info(i) + (i,) for i in val_ids]
    test_rows = sorted(
        (r for r in val if r[1] == path_cam and r[0] not in times), key=lambda r: r[0]
    )
    all_t = sorted(times + [r[0] for r in test_rows])
    g_of = {t: g for g, t in enumerate(all_t)}  # times renumbered 0..G-1
    train = [g_of[t] for t in times]
    test = [g_of[r[0]] for r in test_rows]
    levels = exposure_levels([r[2] for r in tr])

    def snap(v):
        near = min(levels, key=lambda lv: abs(math.log(lv / v)))
        return near if abs(math.log(near / v)) <= math.log(1.02) else v

    s = _Source(
        train=train,
        test=test,
        train_dt=[snap(r[2]) for r in tr],
        frames={g_of[r[0]]: rgb(r[4]) for r in tr},
        test_ldr={},
        observed=levels,
        novel=[],
    )
    lv_root = src / nf.RGB_LEVELS_DIR

    def ldr_levels(iid, dt):
        out = {}
        if lv_root.is_dir():
            for d in lv_root.iterdir():
                p = d / fdir / f"{iid}.png"
                if p.is_file():
                    out[float(d.name)] = p
        return out or {snap(dt): rgb(iid)}

    for r in test_rows:
        s.test_ldr[g_of[r[0]]] = ldr_levels(r[4], r[2])
    all_levels = sorted({lv for d in s.test_ldr.values() for lv in d})
    if any(len(d) > 1 for d in s.test_ldr.values()):
        s.novel = [lv for lv in all_levels if lv not in levels]
    elif test:
        s.test_dt = [next(iter(s.test_ldr[g])) for g in test]
    # cameras of every frame of the path, ground truth where they are
    rows = sorted([(g_of[r[0]], r[4]) for r in tr + test_rows])
    Ks, c2ws = [], []
    for _g, iid in rows:
        K, c2w, _ = camera(iid)
        Ks.append(K)
        c2ws.append(c2w)
    s.cameras = Cameras(np.array([g for g, _ in rows]), np.stack(Ks), np.stack(c2ws))
    ids_of = dict(rows)

    def opt_file(folder, iid, ext):
        p = src / folder / fdir / f"{iid}{ext}"
        return p if p.is_file() else None

    hdr = {g: opt_file(nf.HDR_DIR, iid, ".exr") for g, iid in ids_of.items()}
    if all(hdr.values()):
        s.hdr = hdr
    dep = {g: opt_file("depth", iid, ".npy") for g, iid in ids_of.items()}
    if all(dep.values()):
        s.gt_depth = {g: _read_npy(p, "depth") for g, p in dep.items()}
    masks = {g: opt_file(nf.MASK_DIR, iid, ".png") for g, iid in ids_of.items()}
    if all(masks.values()):
        s.masks = masks
    # depth prior: depth_prior/ (benchgen export), else the layout's depth/ (sensor depth)
    prior = [opt_file(nf.DEPTH_PRIOR_DIR, r[4], ".npy") for r in tr]
    if all(prior):
        s.depth_prior = np.stack([_read_npy(p, "depth") for p in prior]).astype(np.float32)
        s.gt_notes["depth_prior_source"] = str(src / nf.DEPTH_PRIOR_DIR)
    elif all(dep[g] for g in train):
        s.depth_prior = np.stack([s.gt_depth[g] for g in train]).astype(np.float32)
        s.gt_notes["depth_prior_source"] = f"{src / 'depth'} (the capture's own depth)"
    tp = src / nf.TRACKS_PRIOR_FILE
    if tp.is_file():
        s.tracks = _tracks_file(tp, len(train), centre=0.5)
        s.gt_notes["tracks_prior_source"] = str(tp)
    # held-out views: validation cameras other than the path's, imaged at every test frame's time
    others = sorted({r[1] for r in val if r[1] != path_cam})
    test_times = [r[0] for r in test_rows]
    skipped = []
    for c in others:
        rs = {r[0]: r for r in val if r[1] == c}
        name = next((r[3] for r in rs.values() if r[3]), None) or f"camera{c}"
        if sorted(rs) != test_times:
            skipped.append(name)
            continue
        K, C, ldr, hd, dp, mk, cv = [], [], {}, {}, {}, {}, {}
        for t in test_times:
            iid = rs[t][4]
            g = g_of[t]
            k_, c2w, _ = camera(iid)
            K.append(k_)
            C.append(c2w)
            ldr[g] = ldr_levels(iid, rs[t][2])
            hd[g] = opt_file(nf.HDR_DIR, iid, ".exr")
            d = opt_file("depth", iid, ".npy")
            dp[g] = _read_npy(d, "depth") if d else None
            mk[g] = opt_file(nf.MASK_DIR, iid, ".png")
            p = src / "covisible" / fdir / "val" / f"{iid}.png"
            cv[g] = p if p.is_file() else None
        parts = [hd, dp, mk, cv]
        if not all(v is not None for part in parts for v in part.values()) or any(
            set(ldr[g]) != set(s.test_ldr[g]) for g in test
        ):
            skipped.append(name)
            continue
        s.views[name] = _View(
            Cameras(np.array(test), np.stack(K), np.stack(C)), ldr, hd, dp, mk, cv
        )
    if skipped:
        s.gt_notes["views_not_imported"] = (
            f"{skipped}: a clip's held-out view images every test frame's time with HDR, depth, "
            "masks and co-visibility"
        )
    return s


# --------------------------------------------------------------------------------------------------
# the clip
# --------------------------------------------------------------------------------------------------
READERS = {"mono4dgs-hdr": read_mono4dgs_hdr, "nerfies": read_nerfies}


def import_format(fmt: str, src, out, opt: ImportOptions, force: bool = False) -> Path:
    """Write a clip at `out` from the folder `src` in format `fmt`; `opt` gives the prior files
    that replace or complete the folder's own (depth, tracks, flow), fps and name."""
    src, out = Path(src), Path(out)
    if fmt not in READERS:
        raise InputError(f"--format {fmt!r}: expected one of {', '.join(READERS)}")
    if not src.is_dir():
        raise InputError(f"{src}: no such folder")
    if (out / "clip.json").exists() and not force:
        raise InputError(f"{out}: a clip is already there; use --force to replace it")
    s = READERS[fmt](src)
    first = s.frames[s.train[0]]
    H, W = mio.read_image(first)[0].shape[:2]
    T = len(s.train)
    src_meta = None
    mp = src / CLIP_META_FILE
    if mp.is_file():
        src_meta = ClipMeta.from_dict(mio.read_json(mp), mp)
    # priors: the options first, then the folder's own
    if opt.depth is not None:
        depth = read_depth(opt, T, H, W)
    elif s.depth_prior is not None:
        depth = s.depth_prior
        if depth.shape != (T, H, W):
            raise InputError(f"{src}: depth maps of shape {depth.shape[1:]}; frames are {H}x{W}")
    else:
        raise InputError(f"{src}: no depth in the folder; {DEPTH_HELP}")
    tracks = read_tracks(opt, T, H, W) or s.tracks
    flow = read_flow(opt, T, H, W)
    if tracks is None:
        from m4dgs.core.io import read_png

        tracks = dis_tracks([read_png(s.frames[g]) for g in s.train], s.train_dt, opt)
    tracks = TrackSet(tracks.tracks, tracks.visible, np.asarray(s.train, np.int64))
    G = len(s.train) + len(s.test)
    synthetic = bool(s.hdr)
    meta = ClipMeta(
        name=opt.name or (src_meta.name if src_meta else out.name),
        width=W,
        height=H,
        fps=float(opt.fps if opt.fps is not None else (src_meta.fps if src_meta else 30.0)),
        frames=list(range(G)),
        split=Split(list(s.train), list(s.test)),
        exposures=Exposures(
            train_dt=list(s.train_dt),
            observed=list(s.observed),
            novel=list(s.novel),
            schedule=src_meta.exposures.schedule if src_meta else "alternating",
            test_dt=s.test_dt,
        ),
        crf=src_meta.crf if src_meta else None,
        unit_exposure_value=(
            src_meta.unit_exposure_value
            if src_meta
            else (SYNTHETIC_UNIT_EXPOSURE_VALUE if synthetic else REAL_UNIT_EXPOSURE_VALUE)
        ),
        hdr_scale=src_meta.hdr_scale if src_meta else None,
        generator={"tool": "m4dgs import-clip", "format": fmt, "source": str(src)},
        priors={**opt.report, **{k: v for k, v in s.gt_notes.items() if "source" in k}},
        gt={k: v for k, v in s.gt_notes.items() if "source" not in k},
    )
    if src_meta is not None:  # an export of a clip: its notes describe the same files
        meta.generator["source_clip_generator"] = src_meta.generator
        meta.gt = {**src_meta.gt, **meta.gt}
        meta.priors = {**src_meta.priors, **meta.priors}
    hw = (H, W)
    with staged_clip(out, meta) as w:
        r = w.root
        for i, g in enumerate(s.train):
            _put_png(s.frames[g], r / "input/ldr" / frame_name(g, "png"), hw)
            w.write_prior_depth(g, np.asarray(depth[i], np.float32))
        w.write_prior_tracks(tracks)
        if flow is not None:
            w.write_prior_flow(positions_to_frames(flow, s.train))
        for g in s.test:
            for lv, p in s.test_ldr[g].items():
                _put_png(p, r / "gt/ldr" / level_name(lv) / frame_name(g, "png"), hw)
        for g, p in s.hdr.items():
            _put_exr(p, r / "gt/hdr" / frame_name(g, "exr"), hw)
        if s.cameras is not None:
            if s.cameras.frames.tolist() != list(range(G)):
                raise InputError(
                    f"{src}: cameras of frames {s.cameras.frames.tolist()}; need 0..{G - 1}"
                )
            w.write_gt_cameras(s.cameras)
        for g, d in s.gt_depth.items():
            w.write_gt_depth(g, np.asarray(d, np.float32))
        for g, p in s.masks.items():
            _put_png(p, r / "gt/masks/dynamic" / frame_name(g, "png"), hw, grey=True)
        for name, v in s.views.items():
            w.write_view_cameras(name, v.cams)
            for g in s.test:
                vr = r / "gt/views" / name
                for lv, p in v.ldr[g].items():
                    _put_png(p, vr / "ldr" / level_name(lv) / frame_name(g, "png"), hw)
                _put_exr(v.hdr[g], vr / "hdr" / frame_name(g, "exr"), hw)
                w.write_view_depth(name, g, np.asarray(v.depth[g], np.float32))
                _put_png(v.mask[g], vr / "masks/dynamic" / frame_name(g, "png"), hw, grey=True)
                _put_png(v.covis[g], vr / "covis" / frame_name(g, "png"), hw, grey=True)
        w.finalize()
        Clip(r, meta).validate()
    return out
