"""Cameras of the viewer: a pinhole camera with its image size, the browser's camera in and out of
it, and the named cameras of a run (its training and test frames and the clip's held-out views).

Conventions are the project's (m4dgs.core.camera): OpenCV camera-to-world c2w [4, 4] (x right,
y down, z forward), intrinsics K [3, 3] in pixels with pixel centres at +0.5. The browser's camera
(viser) uses the same axes: its orientation quaternion wxyz (w, x, y, z) is the rotation part of
c2w and its position the translation; its fov is vertical, in radians."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np


@dataclass(frozen=True)
class ViewCamera:
    """A pinhole camera: K [3, 3] (pixels), c2w [4, 4] (OpenCV), image width x height."""

    K: np.ndarray
    c2w: np.ndarray
    width: int
    height: int

    @property
    def fov_y(self) -> float:
        """Vertical field of view in radians."""
        return 2.0 * math.atan(self.height / (2.0 * float(self.K[1, 1])))

    def resized(self, width: int, height: int) -> "ViewCamera":
        """The same camera imaging width x height pixels (K scaled per axis; a pixel centre u + 0.5
        maps to (u + 0.5) * width / self.width)."""
        K = np.array(self.K, np.float64)
        K[0] *= width / self.width
        K[1] *= height / self.height
        return ViewCamera(K, np.array(self.c2w, np.float64), int(width), int(height))

    def scaled(self, factor: float) -> "ViewCamera":
        """Resized by factor (at least 1 x 1 pixel)."""
        return self.resized(max(1, round(self.width * factor)), max(1, round(self.height * factor)))


def quat_to_matrix(wxyz) -> np.ndarray:
    """Rotation matrix [3, 3] of a quaternion (w, x, y, z), normalised first."""
    w, x, y, z = np.asarray(wxyz, np.float64) / np.linalg.norm(wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix [3, 3]."""
    R = np.asarray(R, np.float64)
    tr = np.trace(R)
    cands = [1 + tr, 1 + R[0, 0] - R[1, 1] - R[2, 2], 1 - R[0, 0] + R[1, 1] - R[2, 2]]
    cands.append(1 - R[0, 0] - R[1, 1] + R[2, 2])
    i = int(np.argmax(cands))
    s = 2.0 * math.sqrt(max(cands[i], 1e-300))
    if i == 0:
        q = [s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif i == 1:
        q = [(R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif i == 2:
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s]
    else:
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4]
    q = np.asarray(q)
    return q if q[0] >= 0 else -q


def from_browser(wxyz, position, fov_y: float, width: int, height: int) -> ViewCamera:
    """The browser's camera (orientation wxyz, position, vertical fov in radians) as a centred
    pinhole camera of width x height pixels with square pixels."""
    c2w = np.eye(4)
    c2w[:3, :3] = quat_to_matrix(wxyz)
    c2w[:3, 3] = np.asarray(position, np.float64)
    fy = height / (2.0 * math.tan(float(fov_y) / 2.0))
    K = np.array([[fy, 0.0, width / 2.0], [0.0, fy, height / 2.0], [0.0, 0.0, 1.0]])
    return ViewCamera(K, c2w, int(width), int(height))


def to_browser(camera: ViewCamera) -> Tuple[np.ndarray, np.ndarray, float]:
    """(wxyz [4], position [3], vertical fov in radians) that put the browser's camera at
    `camera`."""
    c2w = np.asarray(camera.c2w, np.float64)
    return matrix_to_quat(c2w[:3, :3]), c2w[:3, 3].copy(), camera.fov_y


@dataclass(frozen=True)
class NamedCamera:
    """A camera the viewer can jump to: kind "train", "test" or "view" (a held-out view of a
    benchgen clip, `view` names it), at global frame g (its time)."""

    label: str
    kind: str
    g: int
    camera: ViewCamera
    view: Optional[str] = None


def named_cameras(model) -> List[NamedCamera]:
    """The training cameras (as estimated by the run), the test cameras (interpolated between
    training ones, as `m4dgs render` renders them) and, for a clip with held-out views, each
    view's camera at each test frame carried into the run's world by its alignment to the truth
    (m4dgs.outputs.views); in that order."""
    from m4dgs.outputs.views import alignment_of, truth_to_run

    clip = model.clip
    out = []
    for kind, frames in (("train", clip.train_frames), ("test", clip.test_frames)):
        for g in frames:
            K, c2w = model.camera(g)
            cam = ViewCamera(K, c2w, model.width, model.height)
            out.append(NamedCamera(f"{kind} {g:05d}", kind, int(g), cam))
    views = clip.view_names() if clip.has_gt_part("cameras.json") else []
    if views:
        al = alignment_of(model)
        K = model.K.detach().cpu().double().numpy()
        for v in views:
            cams = clip.load_view_cameras(v)
            for j, g in enumerate(clip.test_frames):
                c2w = truth_to_run(cams.c2w[j], al["s"], al["R"], al["t"])
                cam = ViewCamera(K, c2w, model.width, model.height)
                out.append(NamedCamera(f"view {v} {g:05d}", "view", int(g), cam, view=v))
    return out
