"""Scene = validated spec + procedural meshes, textures and motion, evaluated per global frame.

This module implements the "benchgen scene interface" contract (helpers/API.md) shared with
benchgen.render and benchgen.groundtruth: :class:`Material`, :class:`MeshState`, :class:`Lighting`,
:class:`FrameState`, :class:`Scene`, :func:`load_scene`. Frame g is at time g / fps. Camera
trajectories are timed over the spec's own duration (num_frames - 1) / fps, so a preset that renders
fewer frames (:meth:`Scene.capped`) sees the first part of the same clip rather than a faster one.

It also has a small numpy z-buffer rasterizer (:func:`rasterize_ids`) used to estimate, honestly but
cheaply, how much of each frame shows dynamic objects or emitters (:func:`dynamic_pixel_fraction`,
:func:`coverage`): the renderer's exact masks come from ray casting."""

from __future__ import annotations

import argparse
import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from m4dgs.core.camera import K_from_fov

from . import meshes as _meshes
from . import motion as _motion
from .spec import SpecError, load_scene_spec, validate_scene  # noqa: F401  (SpecError re-exported)
from .suite import load_suite
from .textures import solid_color, texture_from_spec

__all__ = [
    "Material",
    "MeshState",
    "Lighting",
    "FrameState",
    "Scene",
    "load_scene",
    "scene_from_dict",
    "SpecError",
    "rasterize_ids",
    "dynamic_pixel_fraction",
    "coverage",
]


@dataclass
class Material:
    """kind: "diffuse" | "glossy" | "emitter"."""

    kind: str
    albedo: Optional[np.ndarray]  # texture [h, w, 3] float32 in [0, 1] (linear) or None
    color: Tuple[float, float, float] = (0.5, 0.5, 0.5)  # used when albedo is None
    roughness: float = 0.2  # glossy only (GGX alpha)
    # emitter only (area light radiance, linear)
    radiance: Optional[Tuple[float, float, float]] = None


@dataclass
class MeshState:
    """One object at one frame; topology (faces, uvs) is fixed over time."""

    name: str
    instance_id: int  # >= 1 (0 = nothing / environment)
    vertices: np.ndarray  # [V, 3] float64 world space at this frame
    faces: np.ndarray  # [F, 3] int32
    uvs: np.ndarray  # [V, 2] float32
    material: Material
    dynamic: bool  # moves on its own (object motion, not camera motion)


@dataclass
class Lighting:
    env_radiance: Tuple[float, float, float]  # constant environment (dim), linear
    sun_direction: Optional[np.ndarray]  # [3] unit vector FROM the scene TOWARDS the sun (world)
    sun_irradiance: Optional[Tuple[float, float, float]]


@dataclass
class FrameState:
    g: int  # global frame index
    time: float  # seconds = g / fps
    meshes: List[MeshState]  # same order and same names every frame
    c2w: np.ndarray  # [4, 4] OpenCV convention, camera-to-world
    K: np.ndarray  # [3, 3] pixels, centres at +0.5
    lighting: Lighting


@dataclass
class _Object:
    name: str
    instance_id: int
    local: _meshes.MeshData
    placement: np.ndarray  # [4, 4]
    material: Material
    motion: dict
    mesh_spec: dict
    static_vertices: Optional[np.ndarray]  # world vertices when the object never moves

    @property
    def dynamic(self) -> bool:
        return self.motion["type"] != "none"


def _material(spec: dict, seed: int, band_limit=None) -> Material:
    kind = spec["kind"]
    if kind == "emitter":
        return Material("emitter", None, radiance=tuple(float(x) for x in spec["radiance"]))
    albedo = (
        texture_from_spec(spec["texture"], seed, band_limit)
        if spec["texture"] is not None
        else None
    )
    return Material(
        kind, albedo, color=solid_color(spec["color"]), roughness=float(spec.get("roughness", 0.2))
    )


# --------------------------------------------------------------------------------------------------
# Texture band limit from the screen footprint (docs/rendering.md "Band-limited textures")
# --------------------------------------------------------------------------------------------------
#: the pixel grid textures are band-limited for by default (the small preset's)
BAND_LIMIT_SIZE = (216, 120)
#: screen frequency (cycles per pixel) at which the band-limiting Gaussian's gain is
#: benchgen.textures.CUTOFF_GAIN: half the Nyquist frequency, where a bilinear warp at a half-pixel
#: offset keeps only 71 % of a sinusoid's amplitude (at 0.125 cycles per pixel, where the gain is
#: 0.47, it keeps 92 %)
TEXTURE_MAX_CYCLES_PER_PIXEL = 0.25
#: the cutoff holds on all but this fraction of an object's on-screen area over the clip (the
#: farther, more grazing half of the views, which the box pixel filter averages anyway); measured on
#: lamp-room-orbit (albedo AOV, exact flow): 0.1 and 0.5 give a texture HDR-TAE of 0.006 and 0.009
#: (raw textures 0.047), but 0.1 blurs every box-shaped object (its thin or grazing faces share
#: one texture with the others) to a flat colour
TEXTURE_FOOTPRINT_QUANTILE = 0.5
#: frames of the spec's clip sampled for the footprint
TEXTURE_FOOTPRINT_FRAMES = 12
_NEAR = 0.05


def _subtriangle_barycentrics(n: int) -> np.ndarray:
    """[n * n, 3] barycentrics of the centroids of the n * n equal-area sub-triangles of a triangle
    split n times along each edge."""
    pts = []
    for i in range(n):
        for j in range(n - i):
            pts.append(((i + 1 / 3) / n, (j + 1 / 3) / n))
            if i + j <= n - 2:
                pts.append(((i + 2 / 3) / n, (j + 2 / 3) / n))
    b = np.asarray(pts, np.float64)
    return np.c_[1.0 - b.sum(1), b]


def uv_footprint(
    vertices: np.ndarray,
    faces: np.ndarray,
    uvs: np.ndarray,
    c2w: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    points_per_frame: int = 4096,
) -> Tuple[np.ndarray, np.ndarray]:
    """How a textured mesh is seen: (Q [N, 2, 2], area [N]) over sample points.

    Each face is split into n x n equal sub-triangles (n from points_per_frame); at each centroid
    that lies in front of the camera (z > 0.05) and inside the width x height image, J = d(pixel) /
    d(uv) is the 2x2 Jacobian of the pinhole projection of the face's affine uv map. A texture
    frequency k (cycles per texture side, (k_u, k_v)) shows there as J^-T k cycles per pixel, of
    squared length k^T Q k with Q = (J^T J)^-1; area is the point's screen area in pixels^2 (|det J|
    times its uv area). Occlusion is ignored. Faces with a degenerate uv map are skipped."""
    V = np.asarray(vertices, np.float64)
    F = np.asarray(faces, np.int64)
    UV = np.asarray(uvs, np.float64)
    w2c = np.linalg.inv(np.asarray(c2w, np.float64))
    Vc = V @ w2c[:3, :3].T + w2c[:3, 3]
    A = np.stack([UV[F[:, 1]] - UV[F[:, 0]], UV[F[:, 2]] - UV[F[:, 0]]], -1)  # [F, 2(uv), 2]
    detA = np.linalg.det(A)
    ok = np.abs(detA) > 1e-12
    F, A, detA = F[ok], A[ok], detA[ok]
    if F.shape[0] == 0:
        return np.zeros((0, 2, 2)), np.zeros(0)
    n = int(max(1, min(8, np.sqrt(points_per_frame / F.shape[0]))))
    bary = _subtriangle_barycentrics(n)  # [S, 3]
    E = np.stack([Vc[F[:, 1]] - Vc[F[:, 0]], Vc[F[:, 2]] - Vc[F[:, 0]]], -1)  # [F, 3, 2]
    dXduv = E @ np.linalg.inv(A)  # [F, 3, 2]
    X = np.einsum("sk,fkc->fsc", bary, Vc[F])  # [F, S, 3]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    z = X[..., 2]
    zs = np.where(z > _NEAR, z, 1.0)
    u = fx * X[..., 0] / zs + cx
    v = fy * X[..., 1] / zs + cy
    keep = (z > _NEAR) & (u >= 0) & (u <= width) & (v >= 0) & (v <= height)
    P = np.zeros(z.shape + (2, 3))
    P[..., 0, 0] = fx / zs
    P[..., 0, 2] = -fx * X[..., 0] / zs**2
    P[..., 1, 1] = fy / zs
    P[..., 1, 2] = -fy * X[..., 1] / zs**2
    J = np.einsum("fsij,fjk->fsik", P, dXduv)[keep]  # [N, 2, 2]
    det = np.linalg.det(J)
    good = np.abs(det) > 1e-12
    J, det = J[good], det[good]
    Ji = np.linalg.inv(J)
    Q = Ji @ np.swapaxes(Ji, -1, -2)  # (J^T J)^-1 = J^-1 J^-T
    uv_area = np.broadcast_to((np.abs(detA) / 2.0 / bary.shape[0])[:, None], z.shape)[keep][good]
    return Q, np.abs(det) * uv_area


def band_limit_from_footprint(
    Q: np.ndarray,
    area: np.ndarray,
    max_cycles_per_pixel: float,
    quantile: float,
    num_directions: int = 12,
) -> Optional[np.ndarray]:
    """The uv-frequency metric B (benchgen.textures.band_matrix) of a texture seen with footprints
    Q [N, 2, 2] weighted by area [N] (uv_footprint): for each of num_directions directions d in
    uv-frequency space, r(d) = the (1 - quantile) area-quantile of d^T Q d, so that on all but
    `quantile` of the area a frequency k along d lands at most at max_cycles_per_pixel when |k| <=
    max_cycles_per_pixel / sqrt(r(d)); B is the least-squares quadratic form fitted to r(d) /
    max_cycles_per_pixel^2, scaled up until it is at least that in every direction (the filter is
    never weaker than the footprint asks). None when the texture is never in view."""
    Q = np.asarray(Q, np.float64)
    w = np.asarray(area, np.float64)
    if Q.shape[0] == 0 or w.sum() <= 0:
        return None
    th = np.pi * np.arange(num_directions) / num_directions
    d = np.stack([np.cos(th), np.sin(th)], -1)  # [D, 2] (k_u, k_v)
    quad = np.einsum("di,nij,dj->dn", d, Q, d)  # [D, N]
    r = np.array([weighted_quantile(q, w, 1.0 - quantile) for q in quad])
    r = r / float(max_cycles_per_pixel) ** 2
    X = np.stack([d[:, 0] ** 2, 2 * d[:, 0] * d[:, 1], d[:, 1] ** 2], -1)
    (a, b, c), *_ = np.linalg.lstsq(X, r, rcond=None)
    B = np.array([[a, b], [b, c]])
    lam = np.linalg.eigvalsh(B)
    if not np.all(lam > 0):
        B = np.eye(2) * r.max()
    fit = np.einsum("di,ij,dj->d", d, B, d)
    return B * float(np.max(r / fit))


def weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """The q-quantile of values under weights (the smallest value whose cumulative weight reaches q
    of the total); nan when the weights sum to 0."""
    v = np.asarray(values, np.float64).ravel()
    w = np.asarray(weights, np.float64).ravel()
    if v.size == 0 or w.sum() <= 0:
        return float("nan")
    o = np.argsort(v, kind="stable")
    c = np.cumsum(w[o])
    return float(v[o][min(int(np.searchsorted(c, q * c[-1])), v.size - 1)])


class Scene:
    """A scene built from a validated spec (see benchgen.spec). ``frame(g, W, H)`` gives the full
    state of frame g."""

    def __init__(
        self,
        spec: dict,
        path: Optional[str] = None,
        band_limit: Optional[Tuple[int, int]] = BAND_LIMIT_SIZE,
    ):
        """band_limit: (width, height) of the pixel grid the textures are band-limited for
        (texture_band_limits); None keeps the raw patterns (generator version <= 4)."""
        self.spec = spec
        self.path = path
        self.name: str = spec["name"]
        self.description: str = spec["description"]
        self.fps: float = float(spec["fps"])
        self.num_frames: int = int(spec["num_frames"])
        self.seed: int = int(spec["seed"])
        self.fov_deg: float = float(spec["camera"]["fov_deg"])
        # trajectories are timed over the spec's clip, independent of capping
        self.duration: float = (int(spec["num_frames"]) - 1) / self.fps
        lit = spec["lighting"]
        sun = lit["sun"]
        self.lighting = Lighting(
            env_radiance=tuple(float(x) for x in lit["environment"]),
            sun_direction=None if sun is None else _motion.normalize(sun["direction"]),
            sun_irradiance=None if sun is None else tuple(float(x) for x in sun["irradiance"]),
        )
        self.objects: List[_Object] = []
        for i, o in enumerate(spec["objects"]):
            local = _meshes.mesh_from_spec(o["mesh"])
            tr = o["transform"]
            P = _motion.placement(tr["translate"], tr["rotate_deg"], tr["scale"])
            # geometry first: the textures' band limits depend on where the object is seen
            mat = _material({**o["material"], "texture": None}, self.seed * 1000 + i)
            obj = _Object(o["name"], i + 1, local, P, mat, o["motion"], o["mesh"], None)
            if not obj.dynamic:
                obj.static_vertices = _motion.apply(P, local.vertices)
            self.objects.append(obj)
        #: {object index: band limit (2x2 uv-frequency metric) or None} of the textured objects
        self.texture_band: Dict[int, Optional[np.ndarray]] = (
            self.texture_band_limits(*band_limit) if band_limit is not None else {}
        )
        self.band_limit = None if band_limit is None else tuple(int(x) for x in band_limit)
        for i, (o, obj) in enumerate(zip(spec["objects"], self.objects)):
            if o["material"]["kind"] != "emitter" and o["material"]["texture"] is not None:
                obj.material = _material(
                    o["material"], self.seed * 1000 + i, self.texture_band.get(i)
                )
            # arrays shared by every FrameState are read-only, so a consumer cannot corrupt later
            # frames
            for arr in (
                obj.static_vertices,
                obj.local.faces,
                obj.local.uvs,
                obj.local.vertices,
                obj.material.albedo,
            ):
                if arr is not None:
                    arr.setflags(write=False)

    def texture_band_limits(
        self,
        width: int,
        height: int,
        max_cycles_per_pixel: float = TEXTURE_MAX_CYCLES_PER_PIXEL,
        quantile: float = TEXTURE_FOOTPRINT_QUANTILE,
        num_frames: int = TEXTURE_FOOTPRINT_FRAMES,
    ) -> Dict[int, Optional[np.ndarray]]:
        """Band limit (a 2x2 uv-frequency metric, benchgen.textures.band_matrix) of each textured
        object's texture for a width x height grid, from its footprint (uv_footprint) in
        `num_frames` frames evenly spread over the spec's clip (band_limit_from_footprint): on all
        but `quantile` of the object's on-screen area, texture frequencies the filter keeps (gain
        above CUTOFF_GAIN) land below max_cycles_per_pixel. None for an object never in view (the
        texture keeps the bitmap's own limit, benchgen.textures.max_cutoff)."""
        tex = [
            i
            for i, o in enumerate(self.spec["objects"])
            if o["material"]["kind"] != "emitter" and o["material"]["texture"] is not None
        ]
        if not tex:
            return {}
        gs = np.unique(np.linspace(0, self.num_frames - 1, max(1, int(num_frames))).round())
        K = self.K(width, height)
        acc: Dict[int, List[Tuple[np.ndarray, np.ndarray]]] = {i: [] for i in tex}
        for g in gs.astype(int):
            t = self.time(int(g))
            c2w = self.c2w(int(g))
            for i in tex:
                ob = self.objects[i]
                acc[i].append(
                    uv_footprint(
                        self.object_vertices(i, t),
                        ob.local.faces,
                        ob.local.uvs,
                        c2w,
                        K,
                        width,
                        height,
                    )
                )
        return {
            i: band_limit_from_footprint(
                np.concatenate([q for q, _ in acc[i]]),
                np.concatenate([a for _, a in acc[i]]),
                max_cycles_per_pixel,
                quantile,
            )
            for i in tex
        }

    # ----------------------------------------------------------------------------------------------
    def time(self, g: int) -> float:
        return g / self.fps

    def c2w(self, g: int) -> np.ndarray:
        """[4, 4] OpenCV camera-to-world at global frame g."""
        return _motion.camera_c2w(
            self.spec["camera"]["trajectory"], self.time(g), self.duration, self.seed
        )

    def K(self, width: int, height: int) -> np.ndarray:
        """[3, 3] intrinsics from the horizontal field of view."""
        return K_from_fov(width, height, self.fov_deg)

    def object_vertices(self, index: int, t: float) -> np.ndarray:
        """[V, 3] world vertices of object `index` at time t (seconds)."""
        o = self.objects[index]
        if o.static_vertices is not None:
            return o.static_vertices
        m = o.motion
        if m["type"] == "articulated":
            links = o.mesh_spec["links"]
            frames = _motion.chain_fk(
                [ln["length"] for ln in links],
                [j["axis"] for j in m["joints"]],
                _motion.joint_angles(t, m["joints"]),
            )
            return _motion.apply(
                o.placement, _motion.chain_vertices(o.local.vertices, o.local.parts, frames)
            )
        if m["type"] == "flag":
            v = _motion.flag_deform(
                o.local.vertices,
                t,
                o.mesh_spec["size"][0],
                m["amplitude"],
                m["wavelength"],
                m["frequency_hz"],
                m["growth"],
                m["sag"],
            )
            return _motion.apply(o.placement, v)
        M = _motion.rigid_motion(m, t, default_pivot=o.placement[:3, 3])
        return _motion.apply(M @ o.placement, o.local.vertices)

    def frame(self, g: int, width: int, height: int) -> FrameState:
        """State of global frame g rendered at width x height."""
        t = self.time(g)
        states = [
            MeshState(
                o.name,
                o.instance_id,
                self.object_vertices(i, t),
                o.local.faces,
                o.local.uvs,
                o.material,
                o.dynamic,
            )
            for i, o in enumerate(self.objects)
        ]
        return FrameState(int(g), t, states, self.c2w(g), self.K(width, height), self.lighting)

    def capped(self, max_frames: Optional[int]) -> "Scene":
        """The same scene limited to its first max_frames frames (timing unchanged); None = no
        cap."""
        if max_frames is None or max_frames >= self.num_frames:
            return self
        s = copy.copy(self)
        s.num_frames = int(max_frames)
        return s

    def __repr__(self) -> str:
        return (
            f"Scene({self.name!r}, frames={self.num_frames}, fps={self.fps:g}, "
            f"objects={len(self.objects)})"
        )


def scene_from_dict(
    data: dict, file: str = "<dict>", band_limit: Optional[Tuple[int, int]] = BAND_LIMIT_SIZE
) -> Scene:
    """Validate a spec given as a dict and build the scene (band_limit: see Scene)."""
    return Scene(validate_scene(data, file), path=None, band_limit=band_limit)


def load_scene(path, band_limit: Optional[Tuple[int, int]] = BAND_LIMIT_SIZE) -> Scene:
    """Load and validate a scene YAML file (raises SpecError(file, key_path, expected));
    band_limit: the pixel grid (width, height) the textures are band-limited for (Scene)."""
    return Scene(load_scene_spec(path), path=str(path), band_limit=band_limit)


# --------------------------------------------------------------------------------------------------
# Cheap z-buffer rasterizer (coverage estimates)
# --------------------------------------------------------------------------------------------------
def _clip_near(tri: np.ndarray, near: float) -> List[np.ndarray]:
    """Clip one camera-space triangle [3, 3] against z >= near; 0, 1 or 2 triangles."""
    poly = []
    for k in range(3):
        a, b = tri[k], tri[(k + 1) % 3]
        ina, inb = a[2] >= near, b[2] >= near
        if ina:
            poly.append(a)
        if ina != inb:
            s = (near - a[2]) / (b[2] - a[2])
            poly.append(a + s * (b - a))
    return [np.stack([poly[0], poly[k], poly[k + 1]]) for k in range(1, len(poly) - 1)]


def rasterize_ids(
    state: FrameState, width: int, height: int, near: float = 0.02
) -> Tuple[np.ndarray, np.ndarray]:
    """Visible instance id [H, W] int32 (0 = none) and z-depth [H, W] (inf = none) at pixel centres.

    Pinhole projection with the frame's c2w; K is rescaled from the state's own resolution (2 cx, 2
    cy) to width x height. Triangles crossing the near plane are clipped; no back-face culling
    (sheets are two-sided)."""
    K = state.K.copy()
    sx, sy = width / (2 * K[0, 2]), height / (2 * K[1, 2])
    fx, fy, cx, cy = K[0, 0] * sx, K[1, 1] * sy, K[0, 2] * sx, K[1, 2] * sy
    R, T = state.c2w[:3, :3], state.c2w[:3, 3]
    tris, ids = [], []
    for m in state.meshes:
        pc = (m.vertices - T) @ R  # [V, 3] camera space
        tri = pc[m.faces]  # [F, 3, 3]
        zmin, zmax = tri[:, :, 2].min(1), tri[:, :, 2].max(1)
        keep = zmin >= near
        tris.append(tri[keep])
        ids.append(np.full(int(keep.sum()), m.instance_id, dtype=np.int32))
        for k in np.nonzero((zmax >= near) & ~keep)[0]:
            for c in _clip_near(tri[k], near):
                tris.append(c[None])
                ids.append(np.array([m.instance_id], dtype=np.int32))
    tri = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
    tid = np.concatenate(ids) if ids else np.zeros(0, np.int32)
    u = fx * tri[..., 0] / tri[..., 2] + cx  # [N, 3]
    v = fy * tri[..., 1] / tri[..., 2] + cy
    iz = 1.0 / tri[..., 2]
    # pixel-centre index ranges covered by each bounding box
    x0 = np.clip(np.ceil(u.min(1) - 0.5), 0, width - 1).astype(int)
    x1 = np.clip(np.floor(u.max(1) - 0.5), -1, width - 1).astype(int)
    y0 = np.clip(np.ceil(v.min(1) - 0.5), 0, height - 1).astype(int)
    y1 = np.clip(np.floor(v.max(1) - 0.5), -1, height - 1).astype(int)
    area = (u[:, 1] - u[:, 0]) * (v[:, 2] - v[:, 0]) - (u[:, 2] - u[:, 0]) * (v[:, 1] - v[:, 0])
    ok = (x1 >= x0) & (y1 >= y0) & (np.abs(area) > 1e-12) & (u.max(1) >= 0) & (v.max(1) >= 0)
    ok &= (u.min(1) <= width) & (v.min(1) <= height)
    size = np.maximum(x1 - x0 + 1, y1 - y0 + 1)
    frag_pix, frag_z, frag_id = [], [], []
    idx_all = np.nonzero(ok)[0]
    S = 1
    while len(idx_all):
        sel = idx_all[size[idx_all] <= S]
        idx_all = idx_all[size[idx_all] > S]
        o = np.arange(S)
        chunk = max(1, 2_000_000 // (S * S))
        for c0 in range(0, len(sel), chunk):
            k = sel[c0 : c0 + chunk]
            px = x0[k, None, None] + o[None, None, :]  # [n, 1, S]
            py = y0[k, None, None] + o[None, :, None]  # [n, S, 1]
            cxp, cyp = px + 0.5, py + 0.5
            ua, va = u[k], v[k]

            def edge(i, j, ua=ua, va=va, cxp=cxp, cyp=cyp):
                return (ua[:, j, None, None] - ua[:, i, None, None]) * (
                    cyp - va[:, i, None, None]
                ) - (va[:, j, None, None] - va[:, i, None, None]) * (cxp - ua[:, i, None, None])

            ar = area[k, None, None]
            w0 = edge(1, 2) / ar
            w1 = edge(2, 0) / ar
            w2 = 1.0 - w0 - w1
            inside = (
                (w0 >= 0)
                & (w1 >= 0)
                & (w2 >= 0)
                & (px <= x1[k, None, None])
                & (py <= y1[k, None, None])
            )
            izp = w0 * iz[k, 0, None, None] + w1 * iz[k, 1, None, None] + w2 * iz[k, 2, None, None]
            inside &= izp > 0
            n_, a_, b_ = np.nonzero(inside)
            frag_pix.append((py[n_, a_, 0] * width + px[n_, 0, b_]).astype(np.int64))
            frag_z.append(1.0 / izp[n_, a_, b_])
            frag_id.append(tid[k][n_])
        S *= 2
    ids_img = np.zeros(height * width, dtype=np.int32)
    depth = np.full(height * width, np.inf)
    if frag_pix:
        pix = np.concatenate(frag_pix)
        z = np.concatenate(frag_z)
        fid = np.concatenate(frag_id)
        order = np.lexsort((z, pix))
        pix, z, fid = pix[order], z[order], fid[order]
        first = np.ones(len(pix), dtype=bool)
        first[1:] = pix[1:] != pix[:-1]
        ids_img[pix[first]] = fid[first]
        depth[pix[first]] = z[first]
    return ids_img.reshape(height, width), depth.reshape(height, width)


def coverage(
    scene: Scene, width: int = 160, height: int = 90, frames: Optional[Sequence[int]] = None
) -> Dict[str, np.ndarray]:
    """Per-frame visible fractions from the z-buffer: {'frames', 'dynamic', 'emitter', 'background'}
    ([n] each).

    'dynamic': pixels whose nearest surface belongs to an object with its own motion; 'emitter':
    pixels showing an emitter mesh (lamp, window/sky); 'background': pixels showing no mesh
    (environment)."""
    frames = list(range(scene.num_frames)) if frames is None else list(frames)
    dyn_ids = np.array([0] + [o.instance_id for o in scene.objects if o.dynamic])
    emi_ids = np.array([0] + [o.instance_id for o in scene.objects if o.material.kind == "emitter"])
    out = {"frames": np.array(frames), "dynamic": [], "emitter": [], "background": []}
    for g in frames:
        ids, _ = rasterize_ids(scene.frame(g, width, height), width, height)
        out["dynamic"].append(float(np.isin(ids, dyn_ids[1:]).mean()))
        out["emitter"].append(float(np.isin(ids, emi_ids[1:]).mean()))
        out["background"].append(float((ids == 0).mean()))
    return {k: np.asarray(v) for k, v in out.items()}


def dynamic_pixel_fraction(
    scene: Scene, width: int = 160, height: int = 90, frames: Optional[Sequence[int]] = None
) -> np.ndarray:
    """[n] fraction of pixels whose visible surface (z-buffered against static geometry) is a
    dynamic object."""
    return coverage(scene, width, height, frames)["dynamic"]


def _main(argv: Optional[Sequence[str]] = None) -> None:
    """``python -m benchgen.scene [suite-or-scene.yaml ...]``: per-scene coverage table (z-buffered
    estimate)."""
    ap = argparse.ArgumentParser(description=_main.__doc__)
    ap.add_argument(
        "items", nargs="*", default=["syn-exp-3"], help="suite names/paths or scene YAML files"
    )
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=90)
    ap.add_argument("--step", type=int, default=3, help="evaluate every step-th frame")
    a = ap.parse_args(argv)
    paths: List[Path] = []
    for it in a.items:
        p = Path(it)
        paths += (
            [p]
            if p.suffix in (".yaml", ".yml") and "suites" not in p.parts
            else load_suite(it).scenes
        )
    print(
        "| scene | camera | object motions | dynamic px min / mean / max | frames with an emitter "
        "in view |"
    )
    print("|---|---|---|---|---|")
    for p in paths:
        sc = load_scene(p)
        c = coverage(sc, a.width, a.height, range(0, sc.num_frames, a.step))
        d, e = c["dynamic"], c["emitter"]
        mot = sorted({o.motion["type"] for o in sc.objects} - {"none"})
        print(
            f"| {sc.name} | {sc.spec['camera']['trajectory']['type']} | {', '.join(mot)} | "
            f"{100 * d.min():.1f} / {100 * d.mean():.1f} / {100 * d.max():.1f} % | "
            f"{int((e > 0).sum())} / {len(e)} |"
        )


if __name__ == "__main__":
    _main()
