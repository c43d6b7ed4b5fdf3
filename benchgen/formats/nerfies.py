"""A clip in the Nerfies / DyCheck layout (m4dgs.formats.nerfies).

Image ids: camera 0 is the clip's camera path: its training frames are the train split, its test
frames the "val_path" split (interpolation along the path); camera k >= 1 is the k-th held-out
view (gt/views/), its images the "val_<view>" split; "val", DyCheck's validation split, is the
views (with their co-visibility masks; the path's test frames when the clip has no views), and
dataset.json val_ids, Nerfies' validation images, are all of them.
rgb/1x/ holds each training frame as captured and each validation image at one observed level
(the clip's reference level, `reference_level`; metadata.json "exposure" says which); every level
of a validation image is in rgb_levels/<level>/1x/. The cameras (camera/) and depth (depth/1x/,
z-depth, 0 = none) are the ground truth, as DyCheck's iPhone captures give sensor depth and
refined poses. With estimated cameras (`benchgen export --cameras FILE`: an m4dgs cameras.json of
at least the training frames, e.g. a run's cameras_ba.json) the training images get those, and
every other image the ground-truth camera carried into their frame by the similarity fitted on the
training cameras' centres (m4dgs.core.camera.align_to_truth, as a run is shown the held-out views),
with the ground-truth depths and points in that frame's units; extra.json "cameras" says which. The
clip's
depth prior, the input a method that estimates geometry should get, is in depth_prior/1x/;
covisible/1x/val/ holds the views' co-visibility masks, points.npy the static ground-truth track
points (mean position over the frames they are visible in)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from m4dgs.clip import Cameras, Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.camera import align_to_truth, truth_to_run
from m4dgs.core.errors import InputError
from m4dgs.formats import CLIP_META_FILE, copy_file
from m4dgs.formats import nerfies as fmt

FACTOR = "1x"


def reference_level(clip: Clip, j: int) -> float:
    """The level of the j-th test frame's image in rgb/1x: its captured level (real footage), else
    the observed level nearest the geometric mean of the observed ones (the best exposed)."""
    ex = clip.meta.exposures
    if ex.test_dt is not None:
        return ex.test_dt[j]
    mid = float(np.mean(np.log(ex.observed)))
    return min(ex.observed, key=lambda v: abs(math.log(v) - mid))


def _depth_npy(path: Path, depth: np.ndarray) -> None:
    """DyCheck's depth file: [H, W, 1] float32."""
    mio.write_bytes_atomic(path, _npy(np.asarray(depth, np.float32)[..., None]))


class _Frame:
    """The exported world frame: the truth's, or that of estimated cameras (module docstring)."""

    def __init__(self, clip: Clip, gt: Cameras, est: Optional[Cameras], source: str):
        self.gt, self.est, self.source = gt, est, source
        self.s, self.R, self.t = 1.0, np.eye(3), np.zeros(3)
        if est is None:
            return
        have = {int(g): i for i, g in enumerate(est.frames)}
        missing = [g for g in clip.train_frames if g not in have]
        if missing:
            raise InputError(
                f"{source}: 'frames': no camera for training frame(s) {missing[:5]} of "
                f"{clip.root}; estimated cameras must cover every training frame"
            )
        row = {int(g): i for i, g in enumerate(gt.frames)}
        tr = clip.train_frames
        al = align_to_truth(est.c2w[[have[g] for g in tr]], gt.c2w[[row[g] for g in tr]])
        self.s, self.R, self.t, self.rmse, self.have = al["s"], al["R"], al["t"], al["rmse"], have

    def camera(self, g: int, K_gt, c2w_gt, on_path: bool):
        """(K, c2w) of an image: the estimated camera of path frame g where there is one, else
        the ground truth's carried into the exported frame."""
        if self.est is None:
            return K_gt, c2w_gt
        if on_path and g in self.have:
            i = self.have[g]
            return self.est.K[i], self.est.c2w[i]
        return K_gt, truth_to_run(c2w_gt, self.s, self.R, self.t)

    def points(self, p: np.ndarray) -> np.ndarray:
        """[N, 3] ground-truth points in the exported frame."""
        return (np.asarray(p, np.float64) - self.t) @ self.R / self.s

    def depth(self, d: np.ndarray) -> np.ndarray:
        return d / self.s

    def record(self) -> dict:
        if self.est is None:
            return {"cameras": "ground truth"}
        return {
            "cameras": "estimated",
            "estimated_from": Path(self.source).name,
            "similarity_to_truth": {
                "s": self.s,
                "R": self.R.tolist(),
                "t": self.t.tolist(),
                "rmse": self.rmse,
                "convention": "c_gt ~ s R c + t over the training cameras' centres",
            },
        }


def export(clip: Clip, out: Path, cameras=None) -> None:
    """Write `clip` into `out` in this layout (module docstring); `cameras`: the path of an m4dgs
    cameras.json of estimated cameras to export instead of the truth's (None: the truth)."""
    m = clip.meta
    if not clip.has_gt_part("cameras.json"):
        raise InputError(
            f"{clip.path('gt/cameras.json')}: missing; the Nerfies layout needs a camera per image "
            "(a clip from an HDR video or real footage has none)"
        )
    gt_cams = clip.load_gt_cameras()
    est = None
    if cameras is not None:
        est = Cameras.from_json(mio.read_json(cameras), cameras)
    frame = _Frame(clip, gt_cams, est, str(cameras))
    cams = gt_cams
    W, H = m.width, m.height
    has = {p: clip.has_gt_part(p) for p in ("hdr", "depth", "masks/dynamic")}
    meta: Dict[str, dict] = {}
    splits: Dict[str, List[tuple]] = {"train": [], "val_path": []}
    row = {int(g): i for i, g in enumerate(cams.frames)}

    def write_camera(iid, K, c2w):
        mio.write_json(out / fmt.CAMERA_DIR / f"{iid}.json", fmt.camera_json(K, c2w, W, H))

    def write_gt(iid, hdr_src, depth, mask):
        if hdr_src is not None:
            copy_file(hdr_src, out / fmt.HDR_DIR / FACTOR / f"{iid}.exr")
        if depth is not None:
            _depth_npy(out / "depth" / FACTOR / f"{iid}.npy", depth)
        if mask is not None:
            copy_file(mask, out / fmt.MASK_DIR / FACTOR / f"{iid}.png")

    def entry(iid, g, cam, dt, split, view=None):
        meta[iid] = {"warp_id": g, "appearance_id": g, "camera_id": cam, "time_id": g}
        meta[iid]["exposure"] = dt
        if view is not None:
            meta[iid]["view"] = view
        splits[split].append((iid, g, cam))

    for g in clip.train_frames:
        iid = fmt.image_id(fmt.PATH_CAMERA, g)
        copy_file(clip.path("input/ldr", frame_name(g, "png")), out / "rgb" / FACTOR / f"{iid}.png")
        write_camera(iid, *frame.camera(g, cams.K[row[g]], cams.c2w[row[g]], True))
        _depth_npy(out / fmt.DEPTH_PRIOR_DIR / FACTOR / f"{iid}.npy", clip.load_depth_prior(g))
        write_gt(
            iid,
            clip.path("gt/hdr", frame_name(g, "exr")) if has["hdr"] else None,
            frame.depth(clip.load_gt_depth(g)) if has["depth"] else None,
            clip.path("gt/masks/dynamic", frame_name(g, "png")) if has["masks/dynamic"] else None,
        )
        entry(iid, g, fmt.PATH_CAMERA, m.train_dt_of(g), "train")
    for j, g in enumerate(clip.test_frames):
        iid = fmt.image_id(fmt.PATH_CAMERA, g)
        ref = reference_level(clip, j)
        name = frame_name(g, "png")
        copy_file(clip.path("gt/ldr", level_name(ref), name), out / "rgb" / FACTOR / f"{iid}.png")
        for lv in m.test_levels_of(g):
            dst = out / fmt.RGB_LEVELS_DIR / level_name(lv) / FACTOR / f"{iid}.png"
            copy_file(clip.path("gt/ldr", level_name(lv), name), dst)
        write_camera(iid, *frame.camera(g, cams.K[row[g]], cams.c2w[row[g]], True))
        write_gt(
            iid,
            clip.path("gt/hdr", frame_name(g, "exr")) if has["hdr"] else None,
            frame.depth(clip.load_gt_depth(g)) if has["depth"] else None,
            clip.path("gt/masks/dynamic", name) if has["masks/dynamic"] else None,
        )
        entry(iid, g, fmt.PATH_CAMERA, ref, "val_path")
    for k, view in enumerate(clip.view_names(), start=1):
        vc = clip.load_view_cameras(view)
        split = f"val_{view}"
        splits[split] = []
        vdir = Path("gt/views") / view
        for j, g in enumerate(clip.test_frames):
            iid = fmt.image_id(k, g)
            ref = reference_level(clip, j)
            name = frame_name(g, "png")
            copy_file(
                clip.path(vdir, "ldr", level_name(ref), name), out / "rgb" / FACTOR / f"{iid}.png"
            )
            for lv in m.test_levels_of(g):
                dst = out / fmt.RGB_LEVELS_DIR / level_name(lv) / FACTOR / f"{iid}.png"
                copy_file(clip.path(vdir, "ldr", level_name(lv), name), dst)
            write_camera(iid, *frame.camera(g, vc.K[j], vc.c2w[j], False))
            write_gt(
                iid,
                clip.path(vdir, "hdr", frame_name(g, "exr")),
                frame.depth(clip.load_view_depth(view, g)),
                clip.path(vdir, "masks/dynamic", name),
            )
            copy_file(
                clip.path(vdir, "covis", name), out / "covisible" / FACTOR / "val" / f"{iid}.png"
            )
            entry(iid, g, k, ref, split, view)
    train_ids = [s[0] for s in splits["train"]]
    val = [s for k, v in splits.items() if k != "train" for s in v]
    # DyCheck's "val": its validation cameras, each image with a co-visibility mask (its masked
    # metrics read one per image): the held-out views; the path's test frames where there are none
    views = [s for k, v in splits.items() if k.startswith("val_") and k != "val_path" for s in v]
    splits["val"] = views or splits["val_path"]
    ids = train_ids + [s[0] for s in val]
    mio.write_json(
        out / fmt.DATASET_FILE,
        {
            "count": len(ids),
            "num_exemplars": len(train_ids),
            "ids": ids,
            "train_ids": train_ids,
            "val_ids": [s[0] for s in val],
        },
    )
    mio.write_json(out / fmt.METADATA_FILE, meta)
    for name, rows in splits.items():
        mio.write_json(
            out / fmt.SPLITS_DIR / f"{name}.json",
            {
                "frame_names": [r[0] for r in rows],
                "time_ids": [r[1] for r in rows],
                "camera_ids": [r[2] for r in rows],
            },
        )
    _scene(clip, frame, out)
    ts = clip.load_tracks_prior()
    mio.write_npz(
        out / fmt.TRACKS_PRIOR_FILE,
        tracks=np.swapaxes(ts.tracks, 0, 1).astype(np.float32),
        visibility=np.swapaxes(ts.visible, 0, 1).astype(bool),
    )
    copy_file(clip.path("clip.json"), out / CLIP_META_FILE)


def _scene(clip: Clip, frame: _Frame, out: Path) -> None:
    """scene.json, extra.json and points.npy, in the exported frame: the static ground-truth track
    points (else the camera centres) fix the centre and scale; near and far bracket the
    ground-truth depths."""
    gt = frame.gt
    path_c2w = np.stack(
        [frame.camera(int(g), gt.K[i], gt.c2w[i], True)[1] for i, g in enumerate(gt.frames)]
    )
    centres = path_c2w[:, :3, 3]
    points = np.zeros((0, 3))
    if clip.has_gt_part("tracks.npz"):
        tr = clip.load_gt_tracks()
        if tr.points3d is not None:
            static = ~tr.dynamic if tr.dynamic is not None else np.ones(len(tr.visible), bool)
            vis = tr.visible[static]
            keep = vis.any(1)
            p3 = tr.points3d[static][keep]
            w = vis[keep][..., None].astype(np.float64)
            points = frame.points((p3 * w).sum(1) / w.sum(1))
    mio.write_bytes_atomic(out / fmt.POINTS_FILE, _npy(points.astype(np.float32)))
    both = np.concatenate([points, centres]) if len(points) else centres
    lo, hi = both.min(0), both.max(0)
    center = (lo + hi) / 2
    scale = 1.0 / max(float(np.abs(both - center).max()), 1e-9)
    near, far = 0.01, 100.0
    if clip.has_gt_part("depth"):
        ds = [clip.load_gt_depth(g) for g in clip.meta.frames]
        pos = np.concatenate([d[d > 0] for d in ds])
        if pos.size:
            near = 0.9 * float(frame.depth(pos.min())) * scale
            far = 1.1 * float(frame.depth(pos.max())) * scale
    mio.write_json(
        out / fmt.SCENE_FILE,
        {"center": center.tolist(), "scale": scale, "near": near, "far": far},
    )
    up = -path_c2w[:, :3, 1].mean(0)
    look = points.mean(0) if len(points) else center
    mio.write_json(
        out / fmt.EXTRA_FILE,
        {
            "factor": 1,
            "fps": float(clip.meta.fps),
            "bbox": [((lo - center) * scale).tolist(), ((hi - center) * scale).tolist()],
            "lookat": ((look - center) * scale).tolist(),
            "up": (up / max(np.linalg.norm(up), 1e-12)).tolist(),
            **frame.record(),
        },
    )


def _npy(a: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()
