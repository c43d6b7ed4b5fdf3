"""The Nerfies / DyCheck dataset layout (google/nerfies, KAIR-BAIR/dycheck), as far as a clip needs.

Facts taken from those projects' data loaders and their released captures::

    dataset.json     {"count", "num_exemplars", "ids", "train_ids", "val_ids"}
    metadata.json    {id: {"warp_id", "appearance_id", "camera_id", "time_id"}}; DyCheck reads
                     warp_id as the time index
    scene.json       {"center", "scale", "near", "far"}: a loader maps world points p to
                     (p - center) * scale; near and far are in those scaled units
    extra.json       (DyCheck) {"factor", "fps", "bbox", "lookat", "up"}, scaled units
    splits/<s>.json  (DyCheck) {"frame_names", "time_ids", "camera_ids"} of split s (train, val)
    camera/<id>.json one camera per image (below), in world (unscaled) units
    rgb/<f>x/<id>.png  the image at 1/f of the cameras' resolution
    depth/<f>x/<id>.npy  (DyCheck) z-depth [H, W, 1], 0 = none
    covisible/<f>x/<split>/<id>.png  (DyCheck) 255 where the pixel is seen by the training views
    points.npy       [N, 3] background points (world units)

A camera JSON: `orientation` the 3x3 world-to-camera rotation (its rows are the camera axes in the
world), `position` the camera centre in the world, `focal_length` (pixels, x), `pixel_aspect_ratio`
(focal y / focal x), `principal_point` [x, y], `skew`, `radial_distortion` [k1, k2, k3],
`tangential_distortion` [p1, p2], `image_size` [width, height]. A world point p projects to
local = orientation @ (p - position); x, y = local.xy / local.z; pixel = (f x + skew y + cx,
f aspect y + cy) (after distortion), with pixel centres at integer + 0.5: x right, y down,
z forward, the clip's own OpenCV convention, so the conversion below is exact (no axis flips).

Image ids are DyCheck's "<camera_id>_<time_id:05d>"; camera 0 is the clip's camera path."""

from __future__ import annotations

from typing import Tuple

import numpy as np

from m4dgs.core.errors import InputError
from m4dgs.formats import field

DATASET_FILE = "dataset.json"
METADATA_FILE = "metadata.json"
SCENE_FILE = "scene.json"
EXTRA_FILE = "extra.json"
SPLITS_DIR = "splits"
CAMERA_DIR = "camera"
POINTS_FILE = "points.npy"
# folders (each with <f>x/ inside) beyond the layout's own rgb/, depth/ and covisible/: no other
# tool reads them; an import of the export gets everything back from them
RGB_LEVELS_DIR = "rgb_levels"  # rgb_levels/<level>/<f>x/<id>.png: every exposure level
HDR_DIR = "hdr"  # hdr/<f>x/<id>.exr: linear HDR radiance (ground truth)
DEPTH_PRIOR_DIR = "depth_prior"  # depth_prior/<f>x/<id>.npy: the clip's depth prior (any scale)
MASK_DIR = "mask_dynamic"  # mask_dynamic/<f>x/<id>.png: 0 / 255 moving-object mask
TRACKS_PRIOR_FILE = "tracks_prior.npz"  # tracks [T, N, 2] (centres +0.5), visibility [T, N]
PATH_CAMERA = 0  # camera_id of the clip's own camera path


def image_id(camera_id: int, time_id: int) -> str:
    return f"{int(camera_id)}_{int(time_id):05d}"


def camera_json(K: np.ndarray, c2w: np.ndarray, width: int, height: int) -> dict:
    """A Nerfies camera JSON of an OpenCV pinhole camera (K, camera-to-world c2w)."""
    K = np.asarray(K, np.float64)
    c2w = np.asarray(c2w, np.float64)
    fx = float(K[0, 0])
    return {
        "orientation": c2w[:3, :3].T.tolist(),
        "position": c2w[:3, 3].tolist(),
        "focal_length": fx,
        "principal_point": [float(K[0, 2]), float(K[1, 2])],
        "skew": float(K[0, 1]),
        "pixel_aspect_ratio": float(K[1, 1]) / fx,
        "radial_distortion": [0.0, 0.0, 0.0],
        "tangential_distortion": [0.0, 0.0],
        "image_size": [int(width), int(height)],
    }


def _numbers(d, key, path, shape) -> np.ndarray:
    v = field(d, key, path)
    try:
        a = np.asarray(v, np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{path}: field '{key}': expected numbers, got {v!r:.60}") from None
    if a.shape != shape:
        raise InputError(f"{path}: field '{key}': expected shape {shape}, got {a.shape}")
    if not np.isfinite(a).all():
        raise InputError(f"{path}: field '{key}': contains NaN or inf")
    return a


def camera_from_json(d: dict, path, scale: float = 1.0) -> Tuple[np.ndarray, np.ndarray, tuple]:
    """(K [3, 3], c2w [4, 4], (width, height)) of a Nerfies camera JSON, its image domain scaled by
    `scale` (1 / f for the images of rgb/<f>x/: focal length, principal point and size times scale,
    exact with pixel centres at +0.5). A camera with lens distortion is refused: a clip's cameras
    are pinholes (undistort the images first)."""
    R = _numbers(d, "orientation", path, (3, 3))
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > 1e-4 or np.linalg.det(R) <= 0:
        raise InputError(f"{path}: field 'orientation': not a rotation (max error {err:.2e})")
    pos = _numbers(d, "position", path, (3,))
    f = float(_numbers(d, "focal_length", path, ()))
    pp = _numbers(d, "principal_point", path, (2,))
    skew = float(_numbers(d, "skew", path, ())) if "skew" in d else 0.0
    aspect = (
        float(_numbers(d, "pixel_aspect_ratio", path, ())) if "pixel_aspect_ratio" in d else 1.0
    )
    if not (f > 0 and aspect > 0):
        raise InputError(f"{path}: field 'focal_length': must be > 0 (and pixel_aspect_ratio too)")
    for key, n in (("radial_distortion", 3), ("tangential_distortion", 2)):
        if key in d and np.any(_numbers(d, key, path, (n,)) != 0):
            raise InputError(
                f"{path}: field '{key}': lens distortion is not supported (clip cameras are "
                "pinholes); undistort the images and cameras first"
            )
    size = _numbers(d, "image_size", path, (2,))
    K = np.array([[f, skew, pp[0]], [0.0, f * aspect, pp[1]], [0.0, 0.0, 1.0]])
    if scale != 1.0:
        K[:2] *= scale
        size = np.round(size * scale)
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = pos
    return K, c2w, (int(size[0]), int(size[1]))
