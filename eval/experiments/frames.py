"""Score another method's frames: `m4dgs-eval score-frames --clip CLIP --pred DIR --name NAME`.

Any method that renders frames can be scored against a benchgen clip with every metric an m4dgs
run gets from its frames; no m4dgs model is needed. The prediction folder (docs/eval.md, "Scoring
another method's frames"):

    DIR/test/hdr/<g>.exr                HDR of every test frame (required where the clip has
                                        ground-truth HDR), linear, in the clip's
                                        radiance units: LDR = CRF(HDR x dt) with clip.json's
                                        exposure times (.exr, .hdr or float .tif/.tiff)
    DIR/test/ldr/<level>/<g>.<ext>      LDR of every test frame at every observed and novel level
                                        of clip.json (required; real footage with held-out test
                                        frames: at the level each was captured at, clip.json
                                        exposures.test_dt); <level> as the clip names it
                                        (m4dgs.clip.level_name: 0.125, 0.5, 2, 8, 32); .png (8 or
                                        16 bit), .exr or .tif/.tiff (8, 16 bit or float in [0, 1])
    DIR/train/hdr/<g>.exr               optional: HDR of every training frame (hdr_train_*,
                                        HDR-TAE, HDR T-std)
    DIR/train/ldr/<g>.<ext>             optional: LDR of every training frame at its input
                                        exposure (ldr_train_*)
    DIR/test/depth/<g>.exr              optional: z-depth of every test frame (depth AbsRel)
    DIR/cameras.json                    optional: estimated cameras in the m4dgs format (ATE, RPE)
    DIR/views/<view>/hdr/<g>.<ext>      a held-out view of a benchgen clip (gt/views/<view>/): HDR
    DIR/views/<view>/ldr/<level>/<g>.<ext>  and LDR at every level of every test frame g, as for
                                        test/ (required for each view given)
    DIR/views/<view>/depth/<g>.exr      optional: z-depth in the view

DIR/test/ is required unless DIR/views/ is there: a method that renders only the views (a
depth-image-based rendering baseline) gives views/ alone. An unknown view name is an error naming
the clip's views. <g> is the global frame index, zero-padded to 5 digits (00007.exr). Every missing
required file is listed in one error. Images are read through OpenImageIO: RGB or RGBA by
channel name (R, G, B, else the first three channels; one channel is grey), any bit depth. LDR
predictions with more than 8 bits are rounded to 8 bits (round(255 x)), the precision m4dgs
renders are scored at; the number of files of each kind is recorded in metrics.json ("options" ->
"input", with the views given and the layout). HDR values must be finite; negative values are set
to 0 and counted.

Other layouts, read as their programs write them, no renaming (`--layout`, LAYOUTS):

    mono4dgs-hdr  the official Mono4DGS-HDR code's render folder <workspace>/<experiment>/world_gs/:
                  test_ldr/<name>.jpg (each test frame at its exposures.json "test" exposure),
                  test_ne_ldr/<name>.jpg (at its "test_ne" exposure), test_hdr_exr/<name>.exr,
                  train_ldr/, train_hdr_exr/; <name> the stem of the workspace's test/ (train/)
                  file: frame numbers for a clip written by `benchgen export --format
                  mono4dgs-hdr`, else the j-th name in sorted order is the j-th test frame (the
                  numbering of `m4dgs import-clip --format mono4dgs-hdr`). The level of each
                  render is the one that export gives the frame; an exposures.json beside the
                  folder (or one or two levels up) must agree.
    nerfies       a Nerfies / DyCheck method's results/rgb/<id>.png (DIR = results/, or rgb/
                  itself) for a clip written by `benchgen export --format nerfies`: <id> =
                  "<camera>_<g:05d>", camera 0 the clip's camera path (test frames; training
                  frames give ldr_train_*), camera k >= 1 the k-th held-out view; each at the level
                  of the export's rgb/1x/. No HDR, depth or cameras: those metrics are null.

A layout that renders each test frame at some of its levels only is scored at those
(scored_clip).

The frames are copied into the m4dgs render layout of a score folder (default runs/<clip>/<NAME>)
with a run.json naming NAME as the variant, and scored by eval.experiments.score.score_run without a
model: model-only metrics (tracks, learned CRF, render FPS, #Gaussians) are None.
`m4dgs-eval table RUNS_DIR` then shows NAME as a row beside the m4dgs runs under RUNS_DIR."""

from __future__ import annotations

import os
import re
import shutil
from collections import Counter
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from m4dgs.clip import Cameras, Clip, ClipMeta, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError
from m4dgs.core.io import ldr_to_8bit, read_image

LDR_EXTS = ("png", "exr", "tif", "tiff")
HDR_EXTS = ("exr", "hdr", "tif", "tiff")
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")
MAX_LISTED = 20
# the layouts a prediction folder may be written in: this project's (below), the official
# Mono4DGS-HDR code's outputs, a Nerfies / DyCheck method's validation renders
LAYOUTS = ("m4dgs", "mono4dgs-hdr", "nerfies")


# --------------------------------------------------------------------------------------------------
# the prediction folder
# --------------------------------------------------------------------------------------------------
@dataclass
class _Group:
    """One set of prediction files: entries (file path without its extension, render path relative
    to renders/), the extensions accepted, and whether the set is required (an optional set is all
    or nothing)."""

    entries: List[Tuple[Path, str]]
    exts: tuple
    required: bool


def _find(base: Path, exts) -> Tuple[Optional[Path], List[Path]]:
    """(the file base.<ext>, every candidate found)."""
    found = [Path(f"{base}.{e}") for e in exts if Path(f"{base}.{e}").is_file()]
    return (found[0] if len(found) == 1 else None), found


def _level_groups(clip: Clip, folder: Path, out: str, frames: List[int], required: bool, exts):
    """{out/<level>: group} of LDR frames at every level their ground truth has."""
    ex = clip.meta.exposures
    groups = {}
    for lv in list(ex.observed) + list(ex.novel):
        frames_lv = [g for g in frames if lv in clip.meta.test_levels_of(g)]
        if frames_lv:
            sub = f"{out}/{level_name(lv)}"
            d = folder / level_name(lv)
            entries = [(d / f"{g:05d}", f"{sub}/{frame_name(g, 'png')}") for g in frames_lv]
            groups[sub] = _Group(entries, exts, required)
    return groups


def _frames_group(folder: Path, out: str, frames: List[int], exts, out_ext: str, required: bool):
    entries = [(folder / f"{g:05d}", f"{out}/{frame_name(g, out_ext)}") for g in frames]
    return _Group(entries, exts, required)


def _m4dgs_groups(clip: Clip, pred: Path) -> Dict[str, _Group]:
    """The m4dgs layout (module docstring): test/, train/, views/<view>/."""
    test, train = clip.test_frames, clip.train_frames
    views_dir = pred / "views"
    # a folder of view frames alone (e.g. a depth-image-based rendering baseline) has no test/
    with_test = (pred / "test").is_dir() or not views_dir.is_dir()
    # a clip without ground-truth HDR (real footage with held-out test frames) scores LDR only,
    # each test frame at the level its ground truth has (Clip.meta.test_levels_of)
    hdr_gt = clip.has_gt_part("hdr")
    groups: Dict[str, _Group] = {}
    if with_test:
        groups["test/hdr"] = _frames_group(
            pred / "test/hdr", "test/hdr", test, HDR_EXTS, "exr", hdr_gt
        )
        groups.update(_level_groups(clip, pred / "test/ldr", "test/ldr", test, True, LDR_EXTS))
        groups["test/depth"] = _frames_group(
            pred / "test/depth", "test/depth", test, ("exr",), "exr", False
        )
    groups["train/hdr"] = _frames_group(
        pred / "train/hdr", "train/hdr", train, HDR_EXTS, "exr", False
    )
    groups["train/ldr"] = _frames_group(
        pred / "train/ldr", "train/ldr", train, LDR_EXTS, "png", False
    )
    if views_dir.is_dir():
        for view in _given_views(clip, views_dir):
            src, out = views_dir / view, f"views/{view}"
            hdr_v = (clip.root / "gt/views" / view / "hdr").is_dir()
            groups[f"{out}/hdr"] = _frames_group(
                src / "hdr", f"{out}/hdr", test, HDR_EXTS, "exr", hdr_v
            )
            groups.update(_level_groups(clip, src / "ldr", f"{out}/ldr", test, True, LDR_EXTS))
            groups[f"{out}/depth"] = _frames_group(
                src / "depth", f"{out}/depth", test, ("exr",), "exr", False
            )
    return groups


def _given_views(clip: Clip, views_dir: Path) -> List[str]:
    """The view folders of DIR/views, each a view of the clip (else an InputError naming them)."""
    names = clip.view_names()
    given = sorted(p.name for p in views_dir.iterdir() if p.is_dir())
    unknown = [v for v in given if v not in names]
    if unknown or not given:
        have = ", ".join(names) if names else "none (the clip has no held-out views)"
        what = f"unknown view(s) {', '.join(unknown)}" if unknown else "no view folders"
        raise InputError(
            f"{views_dir}: {what}; the held-out views of clip {clip.root} are: {have} "
            "(gt/views/<view>/ of the clip)"
        )
    return [v for v in names if v in given]


# -- the official Mono4DGS-HDR code's outputs (--layout mono4dgs-hdr) ------------------------------
OFFICIAL_LDR_EXTS = ("jpg", "jpeg", "png")
OFFICIAL_DIRS = {  # its folder: (frames, render folder); LDR at the levels of test_levels()
    "test_ldr": "test",
    "test_ne_ldr": "test",
    "test_hdr_exr": "test",
    "train_ldr": "train",
    "train_hdr_exr": "train",
}


def _stems(folder: Path, exts) -> List[str]:
    if not folder.is_dir():
        return []
    return sorted(
        {p.stem for p in folder.iterdir() if p.is_file() and p.suffix.lower()[1:] in exts}
    )


def _official_names(pred: Path, frames: List[int], kind: str, clip: Clip) -> Dict[int, str]:
    """{global frame: file stem} of the `kind` ("test", "train") folders: names that are all numbers
    are the frames (an export of the clip), else the j-th name in sorted order is the j-th frame
    (the numbering of `m4dgs import-clip --format mono4dgs-hdr`)."""
    dirs = [d for d, k in OFFICIAL_DIRS.items() if k == kind]
    stems = sorted({s for d in dirs for s in _stems(pred / d, OFFICIAL_LDR_EXTS + ("exr",))})
    if stems and all(s.isdigit() for s in stems):
        other = [s for s in stems if int(s) not in frames]
        if other:
            raise InputError(
                f"{pred}: {', '.join(other[:8])}: not {kind} frames of clip {clip.root} "
                f"({kind} frames: {frames[:12]}{' ...' if len(frames) > 12 else ''})"
            )
        named = {int(s): s for s in stems}
        return {g: named.get(g, f"{g:05d}") for g in frames}
    if stems and len(stems) != len(frames):
        raise InputError(
            f"{pred}: {len(stems)} {kind} frame names in {', '.join(dirs)}, clip {clip.root} has "
            f"{len(frames)} {kind} frames (names that are not frame numbers are matched to the "
            "frames in sorted order, so every frame must be there)"
        )
    return {g: (stems[j] if stems else f"{g:05d}") for j, g in enumerate(frames)}


def _official_groups(clip: Clip, pred: Path) -> Dict[str, _Group]:
    """The official code's render folder (its world_gs/): test_ldr/<name>.jpg at the test frame's
    exposure of exposures.json "test", test_ne_ldr/<name>.jpg at "test_ne", test_hdr_exr/<name>.exr,
    train_ldr/, train_hdr_exr/; the levels are those `benchgen export --format mono4dgs-hdr` gives
    each test frame (benchgen.formats.mono4dgs_hdr.test_levels)."""
    from benchgen.formats.mono4dgs_hdr import test_levels

    test, train = clip.test_frames, clip.train_frames
    tn = _official_names(pred, test, "test", clip)
    rn = _official_names(pred, train, "train", clip)
    oe, ne, levels = [], [], {}
    for j, g in enumerate(test):
        obs, nov = test_levels(clip, j, g)
        levels[tn[g]] = (obs, nov)
        oe.append((pred / "test_ldr" / tn[g], f"test/ldr/{level_name(obs)}/{frame_name(g, 'png')}"))
        # a real clip's novel-exposure frame (clip.json gt.test_ne), scored as LDR-NE
        if nov is not None and nov in clip.meta.test_levels_of(g):
            ne.append(
                (pred / "test_ne_ldr" / tn[g], f"test/ldr/{level_name(nov)}/{frame_name(g, 'png')}")
            )
    _check_official_exposures(pred, levels)
    hdr = [(pred / "test_hdr_exr" / tn[g], f"test/hdr/{frame_name(g, 'exr')}") for g in test]
    return {
        "test_ldr": _Group(oe, OFFICIAL_LDR_EXTS, True),
        "test_ne_ldr": _Group(ne, OFFICIAL_LDR_EXTS, False),
        "test_hdr_exr": _Group(hdr, ("exr",), clip.has_gt_part("hdr")),
        "train_ldr": _Group(
            [(pred / "train_ldr" / rn[g], f"train/ldr/{frame_name(g, 'png')}") for g in train],
            OFFICIAL_LDR_EXTS,
            False,
        ),
        "train_hdr_exr": _Group(
            [(pred / "train_hdr_exr" / rn[g], f"train/hdr/{frame_name(g, 'exr')}") for g in train],
            ("exr",),
            False,
        ),
    }


def _check_official_exposures(pred: Path, levels: Dict[str, tuple]) -> None:
    """The exposures.json of the official code's workspace, where one lies beside the renders
    (world_gs/ is <workspace>/<experiment>/world_gs/): each test frame's "test" and "test_ne"
    exposure must be the level this clip scores it at, else the renders belong to another split."""
    path = next(
        (
            d / "exposures.json"
            for d in (pred, pred.parent, pred.parent.parent)
            if (d / "exposures.json").is_file()
        ),
        None,
    )
    if path is None:
        return
    ex = mio.read_json(path)
    for key, i in (("test", 0), ("test_ne", 1)):
        table = ex.get(key) if isinstance(ex, dict) else None
        for name, v in (table or {}).items():
            stem = Path(name).stem
            if stem not in levels or levels[stem][i] is None:
                continue
            want = levels[stem][i]
            if not isinstance(v, (int, float)) or abs(2.0 ** float(v) / want - 1) > 0.02:
                raise InputError(
                    f"{path}: field '{key}.{name}': exposure 2^{v!r}, but the clip scores this "
                    f"frame at level {want:g} here (the level `benchgen export --format "
                    "mono4dgs-hdr` gives it); were these renders made from another export?"
                )


# -- a Nerfies / DyCheck method's validation renders (--layout nerfies) ----------------------------
NERFIES_EXTS = ("png", "jpg", "jpeg")
NERFIES_ID = re.compile(r"^(\d+)_(\d+)$")


def _nerfies_groups(clip: Clip, pred: Path) -> Dict[str, _Group]:
    """DyCheck's results/rgb/<id>.png (or those files in DIR itself), <id> the image id of the
    Nerfies export, "<camera>_<frame:05d>": camera 0 the clip's camera path (its training and test
    frames), camera k >= 1 the k-th held-out view; each image at the level of the export's rgb/1x/
    (benchgen.formats.nerfies.reference_level). The layout carries no HDR."""
    from benchgen.formats.nerfies import reference_level
    from m4dgs.formats.nerfies import PATH_CAMERA, image_id

    root = pred / "rgb" if (pred / "rgb").is_dir() else pred
    views = clip.view_names()
    cams = {int(m[1]) for s in _stems(root, NERFIES_EXTS) if (m := NERFIES_ID.match(s))}
    unknown = sorted(c for c in cams if c > len(views))
    if unknown:
        have = ", ".join(f"{k} = {v}" for k, v in enumerate(views, start=1)) or "none"
        raise InputError(
            f"{root}: images of camera(s) {', '.join(map(str, unknown))}; clip {clip.root} has "
            f"camera {PATH_CAMERA} (its camera path) and its held-out views as cameras {have}"
        )
    test, train = clip.test_frames, clip.train_frames
    ref = {g: level_name(reference_level(clip, j)) for j, g in enumerate(test)}
    groups = {
        "rgb/train": _Group(
            [(root / image_id(PATH_CAMERA, g), f"train/ldr/{frame_name(g, 'png')}") for g in train],
            NERFIES_EXTS,
            False,
        ),
        "rgb/val_path": _Group(
            [
                (root / image_id(PATH_CAMERA, g), f"test/ldr/{ref[g]}/{frame_name(g, 'png')}")
                for g in test
            ],
            NERFIES_EXTS,
            False,
        ),
    }
    for k, view in enumerate(views, start=1):
        groups[f"rgb/val_{view}"] = _Group(
            [
                (root / image_id(k, g), f"views/{view}/ldr/{ref[g]}/{frame_name(g, 'png')}")
                for g in test
            ],
            NERFIES_EXTS,
            False,
        )
    return groups


def plan_inputs(clip: Clip, pred: Path, layout: str = "m4dgs") -> Dict[str, List[Tuple[Path, str]]]:
    """{group: [(source file, render path relative to renders/)]} of a prediction folder written in
    `layout` (LAYOUTS); raises one InputError listing every missing required file (and every frame
    given in two formats)."""
    pred = Path(pred)
    if not pred.is_dir():
        raise InputError(f"{pred}: the prediction folder does not exist")
    if not clip.test_frames:
        raise InputError(f"{clip.root}/clip.json: the clip has no test frames to score")
    if layout not in LAYOUTS:
        raise InputError(f"--layout {layout!r}: expected one of {', '.join(LAYOUTS)}")
    groups = {"m4dgs": _m4dgs_groups, "mono4dgs-hdr": _official_groups, "nerfies": _nerfies_groups}[
        layout
    ](clip, pred)
    missing, ambiguous = [], []
    plan: Dict[str, List[Tuple[Path, str]]] = {}
    for sub, grp in groups.items():
        if not grp.entries:  # nothing of this clip is scored from that folder
            continue
        files, miss = [], []
        for base, rel in grp.entries:
            f, cands = _find(base, grp.exts)
            if len(cands) > 1:
                ambiguous.append(", ".join(str(c) for c in cands))
            elif f is None:
                miss.append(f"{base}.{{{','.join(grp.exts)}}}")
            else:
                files.append((f, rel))
        if miss and (grp.required or files):  # an optional group given in part is an error too
            missing += miss
        elif not miss:
            plan[sub] = files
    if missing or ambiguous:
        lines = [str(m) for m in missing[:MAX_LISTED]]
        more = f"\n  ... and {len(missing) - MAX_LISTED} more" if len(missing) > MAX_LISTED else ""
        msg = f"{pred}: the prediction folder is incomplete for clip {clip.root}"
        if missing:
            msg += f"; {len(missing)} file(s) missing:\n  " + "\n  ".join(lines) + more
        if ambiguous:
            msg += "\nframes given in more than one format (keep one): " + "; ".join(ambiguous)
        msg += "\n(layout: docs/eval.md, 'Scoring another method's frames')"
        raise InputError(msg)
    if not any(plan.values()):
        raise InputError(
            f"{pred}: no frames of clip {clip.root} in the {layout} layout "
            "(docs/eval.md, 'Scoring another method's frames')"
        )
    return plan


def import_frames(clip: Clip, pred: Path, run_dir: Path, name: str, layout: str = "m4dgs") -> dict:
    """Copy a prediction folder written in `layout` into the render layout of `run_dir` (LDR as
    8-bit PNG, HDR and depth as float32 EXR), write run.json; returns the input report {kind:
    count, "hdr_negative": n, "given": groups, "views": views given, "cameras": bool, "layout"}."""
    plan = plan_inputs(clip, pred, layout)
    renders = Path(run_dir) / "renders"
    counts: Counter = Counter()
    negative = 0
    H, W = clip.height, clip.width
    for files in plan.values():
        for src, rel in files:
            px, kind = read_image(src)
            if px.shape[:2] != (H, W):
                raise InputError(
                    f"{src}: {px.shape[1]}x{px.shape[0]} pixels, the clip is {W}x{H} (clip.json)"
                )
            parts = rel.split("/")
            if "ldr" in parts:
                counts[f"ldr_{kind}"] += 1
                mio.write_png(renders / rel, ldr_to_8bit(px, kind, src))
                continue
            if kind != "float":
                raise InputError(f"{src}: an integer ({kind}) image where linear HDR is expected")
            x = px.astype(np.float32)
            if not np.isfinite(x).all():
                raise InputError(f"{src}: NaN or infinite values")
            if parts[-2] == "depth":
                mio.write_exr(renders / rel, x[..., 0])
                continue
            negative += int((x < 0).sum())
            mio.write_exr(renders / rel, np.maximum(x, 0.0))
            counts["hdr"] += 1
    cams = Path(pred) / "cameras.json"  # the m4dgs layout only: the others carry no camera file
    has_cams = layout == "m4dgs" and cams.is_file()
    if has_cams:
        Cameras.from_json(mio.read_json(cams), cams)  # a readable file, or an error naming it
        shutil.copyfile(cams, Path(run_dir) / "cameras.json")
    mio.write_json(
        Path(run_dir) / "run.json",
        {
            "clip": os.path.relpath(clip.root.resolve(), Path(run_dir).resolve()),
            "clip_abs": str(clip.root.resolve()),
            "variant": name,
            "method": "external",
            "preset": None,
            "external": {"name": name, "pred": str(Path(pred).resolve()), "layout": layout},
        },
    )
    views = sorted(
        {
            rel.split("/")[1]
            for files in plan.values()
            for _, rel in files
            if rel.startswith("views/")
        }
    )
    return {
        **dict(sorted(counts.items())),
        "hdr_negative": negative,
        "given": sorted(plan),
        "views": views,
        "cameras": has_cams,
        "layout": layout,
    }


@dataclass
class _GivenLevels(ClipMeta):
    """clip.json's metadata with the levels a prediction gives each test frame (test_levels_of)."""

    given: Dict[int, List[float]] = field(default_factory=dict)

    def test_levels_of(self, g: int) -> List[float]:
        return list(self.given.get(g, []))


def scored_clip(clip: Clip, renders: Path) -> Clip:
    """The clip as the score sees it. A layout whose method renders each test frame at some of its
    levels only (the official code: one observed and one novel level; a Nerfies method: one) is
    scored at the levels given: test_levels_of(g) lists the levels of renders/test/ldr/ that hold
    frame g. Otherwise (every level of every test frame, or no test frame) the clip itself."""
    have = {
        g: [
            lv
            for lv in clip.meta.test_levels_of(g)
            if (renders / "test/ldr" / level_name(lv) / frame_name(g, "png")).is_file()
        ]
        for g in clip.test_frames
    }
    full = all(have[g] == clip.meta.test_levels_of(g) for g in clip.test_frames)
    if full or not any(have.values()):
        return clip
    base = {f.name: getattr(clip.meta, f.name) for f in fields(ClipMeta)}
    return Clip(clip.root, _GivenLevels(**base, given=have))


def score_frames(
    clip_dir,
    pred,
    name: str,
    out=None,
    *,
    force: bool = False,
    lpips_weights=None,
    roundtrip=None,
    flip: bool = False,
    tae_train_test: bool = False,
    layout: str = "m4dgs",
) -> Tuple[Path, dict]:
    """Import a prediction folder written in `layout` (import_frames) into `out` (default
    runs/<clip name>/<name>) and score it (eval.experiments.score.score_run, no model); returns
    (score folder, metrics)."""
    from eval.experiments.score import score_run  # deferred: loads torch and the metrics

    if not NAME_RE.match(name or ""):
        raise InputError(
            f"--name {name!r}: use letters, digits and . _ + - "
            "(it becomes a folder and a table row)"
        )
    clip = Clip.open(clip_dir)
    run_dir = Path(out) if out is not None else Path("runs") / clip.meta.name / name
    info = run_dir / "run.json"
    if info.exists():
        meta = mio.read_json(info)
        if not meta.get("external"):
            raise InputError(
                f"{run_dir}: an m4dgs run folder; score external frames into another --out"
            )
        if not force:
            raise InputError(f"{run_dir}: already scored (metrics.json); use --force to redo it")
    if run_dir.exists() and force:
        for sub in ("renders", "metrics.json", "cameras.json", "run.json"):
            p = run_dir / sub
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
    if layout not in LAYOUTS:  # before anything is removed or written
        raise InputError(f"--layout {layout!r}: expected one of {', '.join(LAYOUTS)}")
    report = import_frames(clip, Path(pred), run_dir, name, layout)
    m = score_run(
        run_dir,
        clip=scored_clip(clip, run_dir / "renders"),
        lpips_weights=lpips_weights,
        roundtrip=roundtrip,
        flip=flip,
        fps=False,
        tae_train_test=tae_train_test,
        model=False,
        render_missing=False,
        write=False,
    )
    m["options"]["model"] = "none (external frames)"
    m["options"]["input"] = report
    m["run"]["external"] = True
    mio.write_json(run_dir / "metrics.json", m)
    return run_dir, m
