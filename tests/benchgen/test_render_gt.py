"""Mitsuba rendering and exact ground truth (benchgen.render, benchgen.groundtruth,
benchgen.clip_pass), each against an independent answer: analytic plane depths, m4dgs.core.camera
projection, analytic ray-box tests, an analytic flag deformation, inverse-depth interpolation on
planes, and re-rendering from scratch."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import pytest
import torch

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from benchgen.clip_pass import render_clip_gt
from benchgen.groundtruth import (
    cameras_from_states,
    dynamic_mask,
    flow_between,
    project,
    render_noise,
    sample_tracks,
    surface_points,
)
from benchgen.render import Renderer, sensor_to_world
from m4dgs.core.camera import K_from_fov, c2w_to_w2c, make_K, project_pinhole, transform_points
from m4dgs.core.warp import backward_warp

# the scene interface (API.md contract); local stand-ins with the same fields until benchgen.scene
# lands
try:
    from benchgen.scene import FrameState, Lighting, Material, MeshState
except ImportError:  # pragma: no cover - depends on the sibling module's progress

    @dataclass
    class Material:
        kind: str
        albedo: np.ndarray | None
        color: tuple = (0.5, 0.5, 0.5)
        roughness: float = 0.2
        radiance: tuple | None = None

    @dataclass
    class MeshState:
        name: str
        instance_id: int
        vertices: np.ndarray
        faces: np.ndarray
        uvs: np.ndarray
        material: Material
        dynamic: bool

    @dataclass
    class Lighting:
        env_radiance: tuple
        sun_direction: np.ndarray | None
        sun_irradiance: tuple | None

    @dataclass
    class FrameState:
        g: int
        time: float
        meshes: list
        c2w: np.ndarray
        K: np.ndarray
        lighting: Lighting


W, H = 48, 32


# --------------------------------------------------------------------------------------------------
# Fixtures
# --------------------------------------------------------------------------------------------------
def look_at_c2w(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV c2w (x right, y down, z forward) looking from eye at target, z-up world."""
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
    return c2w


def quad(center, u_axis, v_axis):
    """Two-triangle quad center +- u_axis +- v_axis; normal = u x v."""
    c, u, v = (np.asarray(a, np.float64) for a in (center, u_axis, v_axis))
    V = np.stack([c - u - v, c + u - v, c + u + v, c - u + v])
    F = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    UV = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    return V, F, UV


def box(center, half):
    """Axis-aligned box with 24 vertices (per-face uvs), outward normals."""
    c, h = np.asarray(center, np.float64), np.asarray(half, np.float64)
    Vs, Fs, UVs = [], [], []
    for axis in range(3):
        for s in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = s
            a, b = np.zeros(3), np.zeros(3)
            a[(axis + 1) % 3] = h[(axis + 1) % 3]
            b[(axis + 2) % 3] = h[(axis + 2) % 3]
            if s < 0:
                a, b = b, a
            V, F, UV = quad(c + n * h, a, b)
            Fs.append(F + 4 * len(Vs))
            Vs.append(V)
            UVs.append(UV)
    return np.concatenate(Vs), np.concatenate(Fs).astype(np.int32), np.concatenate(UVs)


def smooth_texture(seed, n=64):
    """Low-frequency linear texture (bilinear warping of it is accurate)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n] / n
    img = np.zeros((n, n, 3), np.float32)
    for c in range(3):
        fx, fy, ph = rng.uniform(1, 2), rng.uniform(1, 2), rng.uniform(0, 6)
        img[..., c] = 0.45 + 0.3 * np.sin(2 * np.pi * (fx * x + fy * y) + ph)
    return img


def lighting():
    return Lighting(
        env_radiance=(0.3, 0.3, 0.3),
        sun_direction=np.array([0.3, -0.4, 0.87]) / np.linalg.norm([0.3, -0.4, 0.87]),
        sun_irradiance=(2.0, 1.9, 1.7),
    )


def box_scene_state(g, width=W, height=H):
    """A textured box translating in front of a textured background wall; the camera moves
    sideways."""
    t = g / 10.0
    wall_V, wall_F, wall_UV = quad([0.0, 6.0, 1.0], [9.0, 0, 0], [0, 0, 6.0])
    wall = MeshState(
        "wall", 1, wall_V, wall_F, wall_UV, Material("diffuse", smooth_texture(1)), False
    )
    bV, bF, bUV = box([-0.4 + 0.5 * t, 1.0, 1.0], [0.5, 0.5, 0.5])
    bx = MeshState("box", 2, bV, bF, bUV, Material("diffuse", smooth_texture(2)), True)
    c2w = look_at_c2w([0.2 * t - 0.3, -4.0, 1.3], [0.2 * t - 0.3, 3.0, 1.0])
    K = K_from_fov(width, height, 60.0)
    return FrameState(g=g, time=t, meshes=[wall, bx], c2w=c2w, K=K, lighting=lighting())


class BoxScene:
    name = "boxes"
    num_frames = 5
    fps = 10.0

    def frame(self, g, width, height):
        return box_scene_state(g, width, height)


def ray_box_hit(o, d, lo, hi):
    """Analytic slab test: [N] bool and entry parameter of rays o [3], d [N, 3] against the AABB
    [lo, hi]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o) / d
        t2 = (hi - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    return (tmax >= tmin) & (tmax > 0), tmin


# --------------------------------------------------------------------------------------------------
# Tests
# --------------------------------------------------------------------------------------------------
def test_zdepth_tilted_plane_is_analytic():
    n = np.array([0.2, -0.9, 0.4])
    n /= np.linalg.norm(n)
    p0 = np.array([0.5, 5.0, 0.8])
    a = np.cross(n, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    V, F, UV = quad(p0, 30 * a, 30 * b)
    plane = MeshState("plane", 3, V, F, UV, Material("diffuse", None), False)
    c2w = look_at_c2w([0.3, -1.0, 1.2], [0.0, 5.0, 0.2])
    K = make_K(40.0, 40.0, 22.0, 17.5)  # off-centre principal point
    fs = FrameState(0, 0.0, [plane], c2w, K, lighting())
    cast = Renderer(fs, W, H, "tiny").cast_rays()
    # independent: ray (u, v) -> world direction, plane intersection, camera z
    v, u = np.mgrid[0:H, 0:W] + 0.5
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    d_w = d_cam @ c2w[:3, :3].T
    o = c2w[:3, 3]
    t = (n @ p0 - n @ o) / (d_w @ n)
    pw = o + t[..., None] * d_w
    z_ref = ((pw - o) @ c2w[:3, :3])[..., 2]
    assert cast.hit.all() and (cast.instance == 3).all()
    np.testing.assert_allclose(cast.depth, z_ref, rtol=1e-4)
    # the correspondences give back the hit points themselves
    np.testing.assert_allclose(surface_points(cast, fs), pw, rtol=0, atol=1e-6 * np.abs(pw).max())


def test_camera_convention_bright_spot():
    c2w = look_at_c2w([1.0, -3.0, 2.0], [-0.5, 2.0, 0.5])
    K = make_K(45.0, 45.0, 21.0, 18.0)
    target_px = np.array([[9.5, 7.5], [36.5, 25.5], [30.5, 6.5]])
    for uv_t in target_px:
        # the bright point, 6 m in front of the camera, unprojected through OpenCV K, c2w
        p_cam = np.array(
            [
                (uv_t[0] + 0.05 - K[0, 2]) / K[0, 0] * 6,
                (uv_t[1] - 0.08 - K[1, 2]) / K[1, 1] * 6,
                6.0,
            ]
        )
        p_w = c2w[:3, :3] @ p_cam + c2w[:3, 3]
        # a tiny emitter facing the camera (normal towards the eye), about 0.3 px across
        to_eye = c2w[:3, 3] - p_w
        to_eye /= np.linalg.norm(to_eye)
        s = 0.15 * 6 / K[0, 0]
        a = np.cross(to_eye, [0, 0, 1.0])
        a /= np.linalg.norm(a)
        b = np.cross(to_eye, a)
        V, F, UV = quad(p_w, s * a, s * b)
        if np.cross(V[1] - V[0], V[2] - V[0]) @ to_eye < 0:
            F = F[:, ::-1].copy()
        em = MeshState(
            "spot", 1, V, F, UV, Material("emitter", None, radiance=(5000.0, 5000.0, 5000.0)), False
        )
        fs = FrameState(0, 0.0, [em], c2w, K, Lighting((0.01, 0.01, 0.01), None, None))
        img = Renderer(fs, W, H, {"spp": 16, "max_depth": 2}).render_hdr()
        j, i = np.unravel_index(np.argmax(img.sum(-1)), img.shape[:2])
        # independent answer: m4dgs.core.camera projection of the world point
        uv = project_pinhole(
            transform_points(c2w_to_w2c(torch.tensor(c2w)), torch.tensor(p_w)), torch.tensor(K)
        ).numpy()
        assert (i, j) == (int(np.floor(uv[0])), int(np.floor(uv[1]))), (uv_t, (i, j), uv)
        assert img[j, i].sum() > 100 * np.median(img.sum(-1))


def test_sensor_to_world_flips_x_and_y():
    c2w = look_at_c2w([0, 0, 0], [0, 1, 0])
    M = sensor_to_world(c2w)
    # Mitsuba camera +x is image-left = OpenCV -x; +y image-up = OpenCV -y; +z forward in both
    np.testing.assert_allclose(M[:3, 0], -c2w[:3, 0])
    np.testing.assert_allclose(M[:3, 1], -c2w[:3, 1])
    np.testing.assert_allclose(M[:3, 2], c2w[:3, 2])


@pytest.fixture(scope="module")
def box_renders():
    """Frames 0 and 1 of the moving-box scene: states, casts, HDR renders (two seeds of frame 0)."""
    states = [box_scene_state(g) for g in (0, 1)]
    r = Renderer(states[0], W, H, {"spp": 256, "max_depth": 2, "sampler": "multijitter"})
    casts, hdrs = [], []
    for s in states:
        r.update(s)
        casts.append(r.cast_rays())
        hdrs.append(r.render_hdr())
    r.update(states[0])
    other0 = r.render_hdr(seed=12345)
    return states, casts, hdrs, other0


def test_instance_ids_and_dynamic_mask_match_analytic_box(box_renders):
    states, casts, _, _ = box_renders
    for s, c in zip(states, casts):
        o = s.c2w[:3, 3]
        v, u = np.mgrid[0:H, 0:W] + 0.5
        d = (
            np.stack(
                [(u - s.K[0, 2]) / s.K[0, 0], (v - s.K[1, 2]) / s.K[1, 1], np.ones_like(u)], -1
            )
            @ s.c2w[:3, :3].T
        )
        bV = s.meshes[1].vertices
        hit, tmin = ray_box_hit(o, d.reshape(-1, 3), bV.min(0), bV.max(0))
        hit = hit.reshape(H, W)
        np.testing.assert_array_equal(c.instance == 2, hit)
        np.testing.assert_array_equal(c.instance == 1, ~hit)  # the wall fills the rest of the view
        np.testing.assert_array_equal(dynamic_mask(c.instance, s), hit)
        # box z-depth: ray parameter with camera-z-1 directions is the z-depth
        np.testing.assert_allclose(c.depth[hit], tmin.reshape(H, W)[hit], rtol=1e-5)


def test_warp_by_gt_flow_reproduces_frame(box_renders):
    states, casts, hdrs, other0 = box_renders
    flow, vis = flow_between(
        casts[0], states[1], states[1], casts[1].depth, casts[1].instance, cam_a=states[0]
    )
    # independent check of the flow on the wall: analytic plane y = 6 seen from both cameras
    wall = casts[0].instance == 1
    v, u = np.mgrid[0:H, 0:W] + 0.5
    s0, s1 = states
    d = (
        np.stack(
            [(u - s0.K[0, 2]) / s0.K[0, 0], (v - s0.K[1, 2]) / s0.K[1, 1], np.ones_like(u)], -1
        )
        @ s0.c2w[:3, :3].T
    )
    t = (6.0 - s0.c2w[1, 3]) / d[..., 1]
    pw = s0.c2w[:3, 3] + t[..., None] * d
    uv1 = project_pinhole(
        transform_points(c2w_to_w2c(torch.tensor(s1.c2w)), torch.tensor(pw)), torch.tensor(s1.K)
    ).numpy()
    np.testing.assert_allclose(flow[wall], (uv1 - np.stack([u, v], -1))[wall], atol=1e-4)
    assert vis.mean() > 0.8 and (~vis).sum() > 0  # the moving box occludes part of the wall
    # warp frame 1 onto frame 0 and compare on visible pixels away from instance edges
    warped = backward_warp(torch.tensor(hdrs[1]), torch.tensor(flow)).numpy()
    inst = casts[0].instance
    pad = np.pad(inst, 1, mode="edge")
    interior = np.ones_like(vis)
    for dj in range(3):
        for di in range(3):
            interior &= pad[dj : dj + H, di : di + W] == inst
    x1 = np.stack([u, v], -1) + flow
    i1 = np.clip(np.floor(x1[..., 0]).astype(int), 0, W - 1)
    j1 = np.clip(np.floor(x1[..., 1]).astype(int), 0, H - 1)
    pad1 = np.pad(casts[1].instance, 1, mode="edge")
    for dj in range(3):
        for di in range(3):
            interior &= pad1[j1 + dj, i1 + di] == inst
    good = vis & interior
    assert good.sum() > 0.5 * H * W
    rel = lambda a, b: (np.abs(a - b) / (a + b + 1e-10)).sum(-1)
    warp_err = rel(hdrs[0], warped)[good].mean()
    noise_err = rel(hdrs[0], other0)[good].mean()  # same frame, two seeds: the render-noise level
    flicker = 3 * (1.1 - 1) / (1.1 + 1)  # a 10 % brightness flicker would read this much
    assert warp_err < 2.0 * noise_err + 0.01, (warp_err, noise_err)
    assert warp_err < flicker / 3
    # a wrong flow (off by one pixel) is clearly worse
    bad = backward_warp(
        torch.tensor(hdrs[1]), torch.tensor(flow + np.array([1.0, 0.0], np.float32))
    ).numpy()
    assert rel(hdrs[0], bad)[good].mean() > 2 * warp_err


def test_tracks_project_onto_2d_and_depth(box_renders):
    states, casts, _, _ = box_renders
    ts = sample_tracks(casts, states, ref_indices=[0, 1], num_grid=64, num_dynamic=16, seed=0)
    N, G = ts.visible.shape
    assert G == 2 and N > 64 and ts.dynamic.any() and not ts.dynamic.all()
    for k, s in enumerate(states):
        uv = project_pinhole(
            transform_points(
                c2w_to_w2c(torch.tensor(s.c2w)), torch.tensor(ts.points3d[:, k].astype(np.float64))
            ),
            torch.tensor(s.K),
        ).numpy()
        np.testing.assert_allclose(ts.tracks[:, k], uv, atol=2e-3)
        # z of visible points equals the depth map, interpolated exactly on planes: 1/z is affine in
        # pixel space
        vis = ts.visible[:, k]
        z = ((ts.points3d[:, k].astype(np.float64) - s.c2w[:3, 3]) @ s.c2w[:3, :3])[:, 2]
        c = casts[k]
        checked = 0
        for n_ in np.nonzero(vis)[0]:
            x, y = ts.tracks[n_, k] - 0.5
            i0, j0 = int(np.floor(x)), int(np.floor(y))
            if not (0 <= i0 < W - 1 and 0 <= j0 < H - 1):
                continue
            nb = [(j0, i0), (j0, i0 + 1), (j0 + 1, i0), (j0 + 1, i0 + 1)]
            if len({(c.instance[p], _face_normal_key(s, c, p)) for p in nb}) != 1:
                continue
            fx, fy = x - i0, y - j0
            invz = (
                (1 - fx) * (1 - fy) / c.depth[nb[0]]
                + fx * (1 - fy) / c.depth[nb[1]]
                + (1 - fx) * fy / c.depth[nb[2]]
                + fx * fy / c.depth[nb[3]]
            )
            assert abs(1.0 / invz - z[n_]) < 1e-4 * z[n_]
            checked += 1
        assert checked > N // 3
    # the queries picked on frame 0 sit exactly on pixel centres there and are visible
    frac = ts.tracks[:, 0] - np.floor(ts.tracks[:, 0])
    at_centre = (np.abs(frac - 0.5) < 1e-4).all(-1)
    assert at_centre.sum() >= 40 and ts.visible[at_centre, 0].all()


def _face_normal_key(state, cast, p):
    ms = state.meshes[cast.mesh[p]]
    tri = ms.vertices[ms.faces[cast.triangle[p]]]
    n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    n /= np.linalg.norm(n)
    return tuple(np.round(np.append(n, n @ tri[0]), 6))


def flag_vertices(nx, ny, t):
    """Flag grid in the x-z plane (y = 0), waving along y and sliding in x; t = 0 is flat."""
    s, r = np.meshgrid(np.linspace(0, 1, nx + 1), np.linspace(0, 1, ny + 1), indexing="xy")
    x = -1.5 + 3.0 * s + 0.1 * t * s
    z = -1.0 + 2.0 * r
    y = 0.4 * t * s * np.sin(3.0 * s + 2.0 * r)
    return np.stack([x, y, z], -1).reshape(-1, 3)


def flag_faces(nx, ny):
    F = []
    for j in range(ny):
        for i in range(nx):
            a, b, c, d = (
                j * (nx + 1) + i,
                j * (nx + 1) + i + 1,
                (j + 1) * (nx + 1) + i + 1,
                (j + 1) * (nx + 1) + i,
            )
            F += [[a, b, c], [a, c, d]]
    return np.array(F, np.int32)


def test_deforming_flag_flow_follows_surface():
    nx, ny = 8, 6
    F = flag_faces(nx, ny)
    UV = flag_vertices(nx, ny, 0.0)[:, [0, 2]].astype(np.float32)
    c2w = look_at_c2w([0.2, -4.0, 0.3], [0.0, 0.0, 0.0])
    K = K_from_fov(W, H, 50.0)

    def state(g, t):
        ms = MeshState(
            "flag",
            5,
            flag_vertices(nx, ny, t),
            F,
            UV,
            Material("glossy", None, roughness=0.3),
            True,
        )
        return FrameState(g, t, [ms], c2w, K, lighting())

    sa, sb = state(0, 0.0), state(1, 1.0)
    r = Renderer(sa, W, H, "tiny")
    ca = r.cast_rays()
    img_a = r.render_hdr()
    r.update(sb)
    cb = r.cast_rays()
    img_b = r.render_hdr()
    assert np.abs(img_a - img_b).mean() > 1e-3  # the deformation is visible
    flow, vis = flow_between(ca, sb, sb, cb.depth, cb.instance)
    # independent answer: ray / plane y = 0 at t = 0 -> grid cell (s, r) -> the same triangle's
    # barycentrics at t = 1
    v, u = np.mgrid[0:H, 0:W] + 0.5
    d = (
        np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
        @ c2w[:3, :3].T
    )
    t = -c2w[1, 3] / d[..., 1]
    p = c2w[:3, 3] + t[..., None] * d
    s_, r_ = (p[..., 0] + 1.5) / 3.0, (p[..., 2] + 1.0) / 2.0
    inside = (s_ > 0) & (s_ < 1) & (r_ > 0) & (r_ < 1)
    np.testing.assert_array_equal(ca.hit, inside)
    ci, cj = np.clip((s_ * nx).astype(int), 0, nx - 1), np.clip((r_ * ny).astype(int), 0, ny - 1)
    fx, fy = s_ * nx - ci, r_ * ny - cj
    Vb = flag_vertices(nx, ny, 1.0)
    idx = lambda i, j: j * (nx + 1) + i
    lower = fx >= fy  # triangle (a, b, c): below the diagonal a-c
    pa, pb, pc, pd = (
        Vb[idx(ci, cj)],
        Vb[idx(ci + 1, cj)],
        Vb[idx(ci + 1, cj + 1)],
        Vb[idx(ci, cj + 1)],
    )
    P1 = np.where(
        lower[..., None],
        (1 - fx)[..., None] * pa + (fx - fy)[..., None] * pb + fy[..., None] * pc,
        (1 - fy)[..., None] * pa + fx[..., None] * pc + (fy - fx)[..., None] * pd,
    )
    uv1 = project_pinhole(
        transform_points(c2w_to_w2c(torch.tensor(c2w)), torch.tensor(P1)), torch.tensor(K)
    ).numpy()
    ref = uv1 - np.stack([u, v], -1)
    np.testing.assert_allclose(flow[inside], ref[inside], atol=1e-3)
    assert np.abs(ref[inside]).max() > 1.0  # real motion
    assert vis[inside].mean() > 0.7
    # the chosen vertex's pixel: the vertex (4, 3) projected at t = 0
    vi = idx(4, 3)
    uva, _ = project(flag_vertices(nx, ny, 0.0)[vi], sa)
    uvb, _ = project(Vb[vi], sb)
    jj, ii = int(uva[1]), int(uva[0])
    assert (
        np.linalg.norm(flow[jj, ii] - (uvb - uva)) < 0.3
    )  # within the pixel's sub-pixel offset from the vertex


def test_update_reuses_scene_and_matches_fresh_load():
    s0, s1 = box_scene_state(0), box_scene_state(3)
    r = Renderer(s0, W, H, "tiny")
    scene_obj, params_obj = r.scene, r.params
    img0 = r.render_hdr(seed=7)
    r.update(s1)
    assert r.scene is scene_obj and r.params is params_obj and r.num_updates == 1
    img1 = r.render_hdr(seed=7)
    assert np.abs(img1 - img0).mean() > 1e-3
    fresh = Renderer(s1, W, H, "tiny").render_hdr(seed=7)
    np.testing.assert_allclose(img1, fresh, rtol=1e-4, atol=1e-5)
    c_upd, c_new = r.cast_rays(), Renderer(s1, W, H, "tiny").cast_rays()
    np.testing.assert_array_equal(c_upd.instance, c_new.instance)
    np.testing.assert_allclose(c_upd.depth, c_new.depth, rtol=1e-6)


def test_render_noise_rel_std_is_unbiased_for_gaussian_noise():
    """Two renders with independent Gaussian noise of known relative std: rel_std recovers it (the
    two-sample |A - B| / sqrt(2) reads sqrt(2 / pi) of it), checked against the analytic value and
    against the per-pixel std of 16 draws."""
    rng = np.random.default_rng(3)
    mu = rng.uniform(0.01, 100.0, (64, 64, 3))
    for sigma in (0.02, 0.05):
        draws = mu * (1 + sigma * rng.standard_normal((16, 64, 64, 3)))
        n = render_noise(draws[0], draws[1])
        assert n["rel_std"] == pytest.approx(sigma, rel=0.02)
        assert n["rel_std_two_sample"] == pytest.approx(sigma * math.sqrt(2 / math.pi), rel=0.02)
        per_pixel = (draws.std(0, ddof=1) / draws.mean(0)).mean()
        assert n["rel_std"] == pytest.approx(per_pixel, rel=0.03)


def test_render_noise_known_answers():
    rng = np.random.default_rng(0)
    a = rng.uniform(0.5, 2.0, (16, 16, 3)).astype(np.float32)
    n = render_noise(a, a * 1.1)
    assert abs(n["tae_two_seeds"] - 3 * 0.1 / 2.1) < 1e-6
    assert abs(n["rel_std_two_sample"] - 0.1 / math.sqrt(2) / 1.05) < 1e-6
    assert abs(n["rel_std"] - 0.1 * math.sqrt(math.pi) / 2 / 1.05) < 1e-6
    assert render_noise(a, a)["mu_psnr"] == float("inf")
    b = a.copy()
    b[:, :8] *= 1.1
    left = np.zeros((16, 16), bool)
    left[:, :8] = True
    assert abs(render_noise(a, b, left)["tae_two_seeds"] - 3 * 0.1 / 2.1) < 1e-6
    assert render_noise(a, b, ~left)["tae_two_seeds"] == 0.0


def test_render_clip_gt_writes_and_resumes(tmp_path):
    from m4dgs.clip import ClipMeta, ClipWriter, Exposures, Split, load_flowset, load_trackset
    from m4dgs.core import io as mio

    G = 5
    meta = ClipMeta(
        name="boxes",
        width=W,
        height=H,
        fps=10.0,
        frames=list(range(G)),
        split=Split(train=[0, 2, 4], test=[1, 3]),
        exposures=Exposures(
            train_dt=[0.125, 2.0, 32.0], observed=[0.125, 2.0, 32.0], novel=[0.5, 8.0]
        ),
    )
    out = ClipWriter(tmp_path / "clip", meta)
    notes = render_clip_gt(
        BoxScene(),
        W,
        H,
        list(range(G)),
        {"spp": 16, "max_depth": 2},
        out,
        progress=False,
        num_grid=32,
        num_dynamic=8,
    )
    root = tmp_path / "clip"
    for g in range(G):
        for rel in (
            f"gt/hdr/{g:05d}.exr",
            f"gt/depth/{g:05d}.exr",
            f"gt/masks/dynamic/{g:05d}.png",
        ):
            assert (root / rel).exists(), rel
    fs = load_flowset(root / "gt/flow.npz", W, H)
    assert sorted(map(tuple, fs.pairs.tolist())) == [(0, 2), (2, 0), (2, 4), (4, 2)]
    ts = load_trackset(root / "gt/tracks.npz", num_frames=G, width=W, height=H)
    assert ts.points3d.shape[:2] == ts.tracks.shape[:2] and ts.dynamic is not None
    cams = mio.read_json(root / "gt/cameras.json")
    np.testing.assert_allclose(np.array(cams["c2w"][3]), box_scene_state(3).c2w, atol=1e-12)
    depth2 = mio.read_exr(root / "gt/depth/00002.exr")
    assert (depth2 > 0).all()  # the wall fills the view: no "no surface" pixels
    assert notes["render_noise"]["rel_std"] > 0 and 0 < notes["hdr_tae_floor"] < 0.3
    assert out.meta.gt["hdr_tae_floor"] == notes["hdr_tae_floor"]
    # the edge-excluded floor beside it, and the parts adding up
    parts = notes["hdr_tae_floor_parts"]
    assert notes["hdr_tae_floor_interior"] == parts["interior"] > 0
    assert parts["edges"] == pytest.approx(notes["hdr_tae_floor"] - parts["interior"])
    assert parts["rest_interior"] == pytest.approx(
        parts["interior"] - parts["noise_interior_two_seeds"]
    )
    # resume: existing HDR frames are not re-rendered
    mtime = (root / "gt/hdr/00003.exr").stat().st_mtime_ns
    notes2 = render_clip_gt(
        BoxScene(),
        W,
        H,
        list(range(G)),
        {"spp": 16, "max_depth": 2},
        out,
        progress=False,
        num_grid=32,
        num_dynamic=8,
    )
    assert (root / "gt/hdr/00003.exr").stat().st_mtime_ns == mtime
    assert notes2["timing_s_per_frame"]["render"] is None
    assert abs(notes2["hdr_tae_floor"] - notes["hdr_tae_floor"]) < 1e-6
    np.testing.assert_array_equal(
        cameras_from_states([box_scene_state(g) for g in range(G)]).frames, np.arange(G)
    )


# --------------------------------------------------------------------------------------------------
# Light selection (emitter sampling weights)
# --------------------------------------------------------------------------------------------------
def lamp_scene_state():
    """A textured wall 5 m in front of the camera, a 0.2 m x 0.2 m lamp panel facing it, a dim
    environment, a sun."""
    # normal u x v = -y: towards the camera
    wall_V, wall_F, wall_UV = quad([0.0, 5.0, 1.0], [6.0, 0, 0], [0, 0, 4.0])
    wall = MeshState(
        "wall", 1, wall_V, wall_F, wall_UV, Material("diffuse", smooth_texture(3)), False
    )
    lV, lF, lUV = quad([0.6, 3.5, 1.2], [0.1, 0, 0], [0, 0, -0.1])  # normal +y: towards the wall
    lamp = MeshState(
        "lamp", 2, lV, lF, lUV, Material("emitter", None, radiance=(3000.0, 2500.0, 2000.0)), False
    )
    c2w = look_at_c2w([0.0, 0.0, 1.0], [0.0, 5.0, 1.0])
    lt = Lighting(
        env_radiance=(0.01, 0.01, 0.01),
        sun_direction=np.array([0.0, -0.6, 0.8]),
        sun_irradiance=(0.5, 0.5, 0.5),
    )
    return FrameState(0, 0.0, [wall, lamp], c2w, K_from_fov(W, H, 60.0), lt)


def test_emitter_sampling_weights_analytic():
    from benchgen.sampling import emitter_sampling_weights, emitter_weights_for

    fs = lamp_scene_state()
    # hand computation: the wall's vertices all lie at camera z = 5; lamp area 0.2 * 0.2 = 0.04 m^2,
    # mean radiance 2500
    lamp = 2500.0 * 0.04 / 4.0 / 5.0**2
    env, sun = math.pi * 0.01, 0.5
    top = max(lamp, env, sun)
    w = emitter_sampling_weights(fs)
    assert set(w) == {"env", "sun", "lamp"}
    np.testing.assert_allclose(
        [w["lamp"], w["env"], w["sun"]], [lamp / top, env / top, sun / top], rtol=1e-9
    )
    assert emitter_weights_for("uniform", fs) == {}
    np.testing.assert_allclose(
        emitter_weights_for("power-sqrt", fs)["env"], math.sqrt(env / top), rtol=1e-9
    )
    # the floor keeps every light sampled
    assert min(emitter_sampling_weights(fs, min_weight=0.05).values()) >= 0.05
    with pytest.raises(ValueError, match="emitter_sampling"):
        emitter_weights_for("bogus", fs)


def test_light_selection_weights_do_not_bias_the_render():
    """Next-event estimation with MIS stays unbiased for any selection weights: uniform vs
    power-weighted renders of the same frame agree up to Monte Carlo noise (the independent answer
    is the uniform render)."""
    fs = lamp_scene_state()
    imgs = {
        m: Renderer(fs, W, H, {"spp": 1024, "max_depth": 2, "emitter_sampling": m}).render_hdr(
            seed=7
        )
        for m in ("uniform", "power")
    }
    a, b = imgs["uniform"].astype(np.float64), imgs["power"].astype(np.float64)
    assert a.mean() > 0
    assert abs(a.mean() - b.mean()) / a.mean() < 0.01
    # per pixel: the difference is noise, centred on zero (a wrong pdf would shift every pixel the
    # same way)
    rel = (a - b) / (a + b + 1e-12)
    assert abs(np.median(rel)) < 0.01
    # and the weighting did change the sampling (not a no-op)
    assert np.abs(a - b).max() > 0


def test_choose_emitter_sampling_picks_the_least_noisy_mode():
    from benchgen.render import RenderSettings, choose_emitter_sampling
    from benchgen.sampling import EMITTER_SAMPLING_MODES

    fs = lamp_scene_state()
    mode, scores = choose_emitter_sampling(fs, W, H, RenderSettings(spp=64))
    assert set(scores) == set(EMITTER_SAMPLING_MODES) and all(v > 0 for v in scores.values())
    assert scores[mode] == min(scores.values())
    # independent check of the score: the noise term of two renders made directly with the chosen
    # mode
    r = Renderer(fs, W, H, {"spp": 16, "emitter_sampling": mode})
    n = render_noise(r.render_hdr(seed=1), r.render_hdr(seed=2), r.cast_rays().hit)["tae_two_seeds"]
    assert abs(n - scores[mode]) < 1e-9
    # deterministic
    assert choose_emitter_sampling(fs, W, H, RenderSettings(spp=64)) == (mode, scores)
    # a Renderer asked for "auto" makes the same choice
    assert Renderer(fs, W, H, {"spp": 16, "emitter_sampling": "auto"}).emitter_sampling == mode
    # with the environment as the only light there is nothing to choose
    env_only = FrameState(
        0, 0.0, [fs.meshes[0]], fs.c2w, fs.K, Lighting((0.2, 0.2, 0.2), None, None)
    )
    assert choose_emitter_sampling(env_only, W, H, RenderSettings(spp=64)) == ("uniform", {})
