"""Procedural triangle meshes with uvs (docs/scenes.md).

Every closed mesh is wound counter-clockwise seen from outside (right-hand rule normals point
outwards); open sheets (plane, grid) face local +z. Emitters are ordinary meshes with an emitter
material: an area light emits from the front side, so a window/sky quad must face into the room and
a lamp is a small closed sphere or box.

All builders return :class:`MeshData` in the object's local frame (metres).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np


@dataclass
class MeshData:
    """Local-frame mesh. vertices [V, 3] float64, faces [F, 3] int32, uvs [V, 2] float32 in [0, 1],
    parts [V] int32 link index of each vertex (articulated chains) or None."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    parts: Optional[np.ndarray] = None

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])


def _mesh(v, f, uv, parts=None) -> MeshData:
    return MeshData(
        np.asarray(v, dtype=np.float64).reshape(-1, 3),
        np.asarray(f, dtype=np.int32).reshape(-1, 3),
        np.clip(np.asarray(uv, dtype=np.float32).reshape(-1, 2), 0.0, 1.0),
        None if parts is None else np.asarray(parts, dtype=np.int32),
    )


def merge(meshes: Sequence[MeshData]) -> MeshData:
    """Concatenate meshes (faces re-indexed; parts kept when every input has them)."""
    vs, fs, uvs, ps = [], [], [], []
    off = 0
    for m in meshes:
        vs.append(m.vertices)
        fs.append(m.faces + off)
        uvs.append(m.uvs)
        ps.append(m.parts)
        off += m.num_vertices
    parts = np.concatenate(ps) if all(p is not None for p in ps) else None
    return _mesh(np.concatenate(vs), np.concatenate(fs), np.concatenate(uvs), parts)


def _sheet(xs: np.ndarray, ys: np.ndarray, x_range, y_range) -> MeshData:
    """Quad grid in the z = 0 plane over coordinates xs [nx+1] x ys [ny+1], normal +z."""
    nx, ny = len(xs) - 1, len(ys) - 1
    X, Y = np.meshgrid(xs, ys, indexing="xy")  # [ny+1, nx+1]
    v = np.stack([X, Y, np.zeros_like(X)], -1).reshape(-1, 3)
    uv = np.stack(
        [
            (X - x_range[0]) / (x_range[1] - x_range[0]),
            (Y - y_range[0]) / (y_range[1] - y_range[0]),
        ],
        -1,
    ).reshape(-1, 2)
    j, i = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    a = (j * (nx + 1) + i).ravel()
    b, c, d = a + 1, a + 1 + (nx + 1), a + (nx + 1)  # (i+1, j), (i+1, j+1), (i, j+1)
    f = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    return _mesh(v, f, uv)


def plane(size: Sequence[float], subdivisions: int = 1) -> MeshData:
    """Centred rectangle size = (sx, sy) in the local xy plane, normal +z, subdivisions quads per
    side."""
    sx, sy = size
    n = int(subdivisions)
    return _sheet(
        np.linspace(-sx / 2, sx / 2, n + 1),
        np.linspace(-sy / 2, sy / 2, n + 1),
        (-sx / 2, sx / 2),
        (-sy / 2, sy / 2),
    )


def grid(size: Sequence[float], resolution: Sequence[int] = (32, 16)) -> MeshData:
    """Sheet for cloth/flags: x in [0, w] (x = 0 = pole edge), y in [0, h], normal +z, resolution
    (nx, ny) quads."""
    w, h = size
    nx, ny = int(resolution[0]), int(resolution[1])
    return _sheet(np.linspace(0, w, nx + 1), np.linspace(0, h, ny + 1), (0, w), (0, h))


_BOX_FACES = [  # (normal, u axis, v axis) with u x v = normal
    ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    ((-1, 0, 0), (0, 0, 1), (0, 1, 0)),
    ((0, 1, 0), (0, 0, 1), (1, 0, 0)),
    ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    ((0, 0, 1), (1, 0, 0), (0, 1, 0)),
    ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
]


def box(size: Sequence[float], center: Sequence[float] = (0.0, 0.0, 0.0)) -> MeshData:
    """Axis-aligned box of extents size = (sx, sy, sz) around center: 24 vertices (per-face uvs), 12
    triangles."""
    half = np.asarray(size, dtype=np.float64) / 2
    c0 = np.asarray(center, dtype=np.float64)
    vs, fs, uvs = [], [], []
    for k, (n, u, v) in enumerate(_BOX_FACES):
        n, u, v = (np.asarray(a, dtype=np.float64) for a in (n, u, v))
        c = c0 + n * half
        hu, hv = u * half, v * half
        vs += [c - hu - hv, c + hu - hv, c + hu + hv, c - hu + hv]
        uvs += [(0, 0), (1, 0), (1, 1), (0, 1)]
        o = 4 * k
        fs += [(o, o + 1, o + 2), (o, o + 2, o + 3)]
    return _mesh(vs, fs, uvs)


def uv_sphere(radius: float, segments: int = 32, rings: int = 16) -> MeshData:
    """Sphere centred at the origin; poles on local z; seam column duplicated for uvs; no degenerate
    triangles."""
    th = np.linspace(0, np.pi, rings + 1)
    ph = np.linspace(0, 2 * np.pi, segments + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")  # [rings+1, seg+1]
    v = radius * np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(
        -1, 3
    )
    uv = np.stack([P / (2 * np.pi), 1 - T / np.pi], -1).reshape(-1, 2)
    row = segments + 1
    f = []
    for i in range(rings):
        for j in range(segments):
            a, b, c, d = i * row + j, (i + 1) * row + j, (i + 1) * row + j + 1, i * row + j + 1
            if i > 0 and i < rings - 1:
                f += [(a, b, c), (a, c, d)]
            elif i == 0:  # a and d are the north pole
                f.append((a, b, c))
            else:  # b and c are the south pole
                f.append((a, c, d))
    return _mesh(v, f, uv)


def cylinder(
    radius: float, height: float, segments: int = 24, caps: bool = True, origin: str = "center"
) -> MeshData:
    """Cylinder along local z; origin 'center' (z in [-h/2, h/2]) or 'base' (z in [0, h])."""
    z0, z1 = (-height / 2, height / 2) if origin == "center" else (0.0, height)
    ph = np.linspace(0, 2 * np.pi, segments + 1)
    ring = np.stack([radius * np.cos(ph), radius * np.sin(ph)], -1)
    row = segments + 1
    v = np.concatenate([np.c_[ring, np.full(row, z0)], np.c_[ring, np.full(row, z1)]])
    uv = np.concatenate(
        [np.c_[ph / (2 * np.pi), np.zeros(row)], np.c_[ph / (2 * np.pi), np.ones(row)]]
    )
    j = np.arange(segments)
    a, b, c, d = j, j + 1, row + j + 1, row + j
    f = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    parts = [_mesh(v, f, uv)]
    if caps:
        cap_uv = np.c_[0.5 + 0.5 * np.cos(ph[:-1]), 0.5 + 0.5 * np.sin(ph[:-1])]
        for z, up in ((z1, True), (z0, False)):
            cv = np.concatenate([[[0.0, 0.0, z]], np.c_[ring[:-1], np.full(segments, z)]])
            cu = np.concatenate([[[0.5, 0.5]], cap_uv])
            k = np.arange(segments)
            r0, r1 = 1 + k, 1 + (k + 1) % segments
            cf = np.stack(
                [np.zeros(segments, int), r0, r1] if up else [np.zeros(segments, int), r1, r0], -1
            )
            parts.append(_mesh(cv, cf, cu))
    return merge(parts)


def wall(
    size: Sequence[float], thickness: float = 0.1, opening: Optional[Sequence[float]] = None
) -> MeshData:
    """Upright wall: x in [-w/2, w/2], y in [-t/2, t/2], z in [0, h], optional hole [x0, z0, x1,
    z1].

    Built from up to four boxes around the hole; uvs are the planar (x, z) projection so a texture
    runs continuously across the pieces."""
    w, h = size
    t = thickness
    spans = []  # (xa, xb, za, zb)
    if opening is None:
        spans.append((-w / 2, w / 2, 0.0, h))
    else:
        x0, z0, x1, z1 = opening
        spans += [(-w / 2, x0, 0.0, h), (x1, w / 2, 0.0, h), (x0, x1, z1, h)]
        if z0 > 0:  # a window has a sill; a door (z0 = 0) does not
            spans.append((x0, x1, 0.0, z0))
    boxes = [
        box((xb - xa, t, zb - za), ((xa + xb) / 2, 0.0, (za + zb) / 2)) for xa, xb, za, zb in spans
    ]
    m = merge(boxes)
    m.uvs = np.clip(
        np.stack([(m.vertices[:, 0] + w / 2) / w, m.vertices[:, 2] / h], -1), 0, 1
    ).astype(np.float32)
    return m


def chain(links: Sequence[dict], segments: int = 16) -> MeshData:
    """Articulated chain in its rest pose: link i spans z in [0, length_i] of ITS OWN joint frame.

    The returned vertices are link-local (not stacked): benchgen.motion.chain_vertices places each
    link with forward kinematics using ``parts`` (link index per vertex)."""
    ms = []
    for i, ln in enumerate(links):
        L = float(ln["length"])
        if ln.get("shape", "box") == "box":
            wd = float(ln.get("width", 0.1))
            m = box((wd, wd, L), (0.0, 0.0, L / 2))
        else:
            m = cylinder(float(ln.get("radius", 0.05)), L, segments, caps=True, origin="base")
        m.parts = np.full(m.num_vertices, i, dtype=np.int32)
        ms.append(m)
    return merge(ms)


def mesh_from_spec(spec: dict) -> MeshData:
    """Build the local mesh of a validated ``objects[i].mesh`` spec."""
    t = spec["type"]
    if t == "plane":
        return plane(spec["size"], spec["subdivisions"])
    if t == "box":
        return box(spec["size"])
    if t == "uv_sphere":
        return uv_sphere(spec["radius"], spec["segments"], spec["rings"])
    if t == "cylinder":
        return cylinder(
            spec["radius"], spec["height"], spec["segments"], spec["caps"], spec["origin"]
        )
    if t == "grid":
        return grid(spec["size"], spec["resolution"])
    if t == "wall":
        return wall(spec["size"], spec["thickness"], spec["opening"])
    if t == "chain":
        return chain(spec["links"], spec["segments"])
    raise ValueError(f"unknown mesh type {t!r}")


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unnormalised right-hand-rule face normals [F, 3] (length = 2 x area)."""
    p = vertices[faces]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


__all__: List[str] = [
    "MeshData",
    "merge",
    "plane",
    "grid",
    "box",
    "uv_sphere",
    "cylinder",
    "wall",
    "chain",
    "mesh_from_spec",
    "face_normals",
]
