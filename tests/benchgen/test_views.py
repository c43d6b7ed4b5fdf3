"""Held-out views (benchgen.views): their placement, checked analytically; their geometry and
radiance, checked against the test frame's own ground truth by reprojection written here (not the
renderer's); the co-visibility mask on a hand-made case with an analytic answer; the camera-motion
statistics on analytic motions."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from benchgen.groundtruth import RayCast, pixel_rays, project
from benchgen.motion import axis_angle, look_at
from benchgen.views import (
    baseline,
    camera_motion,
    covisibility,
    pivot_distance,
    placement_problem,
    view_c2w,
)
from m4dgs.clip import Clip, ClipError


# -- placement ------------------------------------------------------------------------------------
def test_a_view_swings_about_the_look_at_point():
    c2w = look_at([0.0, -5.0, 1.0], [0.0, 0.0, 1.0])  # looking along +y, right = +x, up = +z
    pivot = np.array([0.0, 0.0, 1.0])
    yaw = view_c2w(c2w, 5.0, [10.0, 0.0], [0, 0, 0])
    np.testing.assert_allclose(
        yaw[:3, 3], pivot + 5 * np.array([np.sin(np.radians(10)), -np.cos(np.radians(10)), 0])
    )
    pitch = view_c2w(c2w, 5.0, [0.0, 10.0], [0, 0, 0])
    np.testing.assert_allclose(
        pitch[:3, 3], pivot + 5 * np.array([0, -np.cos(np.radians(10)), np.sin(np.radians(10))])
    )
    for v in (yaw, pitch, view_c2w(c2w, 5.0, [-20.0, 7.0], [0, 0, 0])):
        # still looking at the pivot, a rotation
        np.testing.assert_allclose(v[:3, 2], (pivot - v[:3, 3]) / 5.0, atol=1e-12)
        np.testing.assert_allclose(v[:3, :3] @ v[:3, :3].T, np.eye(3), atol=1e-12)
    b = baseline(c2w, yaw, 5.0)
    assert b["angle_deg"] == pytest.approx(10.0)
    assert b["translation"] == pytest.approx(2 * np.sin(np.radians(5)))
    off = view_c2w(c2w, 5.0, [0, 0], [0.2, 0.1, 0.3])  # right +x, up +z, forward +y, x 5
    np.testing.assert_allclose(off[:3, 3], [1.0, -3.5, 1.5])
    np.testing.assert_allclose(off[:3, :3], c2w[:3, :3])


def test_pivot_distance_and_placement_problems():
    depth = np.zeros((40, 80), np.float32)
    depth[10:30, 20:60] = 3.0  # the central half
    depth[:5] = 9.0
    assert pivot_distance(depth) == pytest.approx(3.0)
    assert np.isnan(pivot_distance(np.zeros((4, 4))))
    full = np.full((40, 80), 3.0, np.float32)
    assert placement_problem(full, 3.0, 1.0) is None
    near = full.copy()
    near[:4, :4] = 0.1  # a wall against the lens
    assert "inside or against geometry" in placement_problem(near, 3.0, 1.0)
    sky = np.zeros_like(full)
    sky[:5] = 3.0
    assert "looking past the scene" in placement_problem(sky, 3.0, 0.9)
    assert placement_problem(sky, 3.0, 0.2) is None  # its test frame sees as little


# -- co-visibility: a hand-made case ---------------------------------------------------------------
def _plane():
    """A 4 x 4 m square at z = 0 (two triangles), instance 1."""
    V = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], np.float64)
    F = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    return SimpleNamespace(vertices=V, faces=F)


def _down(x: float, h: float = 2.0):
    """A camera at (x, 0, h) looking straight down (image right = +x)."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[1, 0, 0], [0, -1, 0], [0, 0, -1]], np.float64)
    c2w[:3, 3] = [x, 0.0, h]
    return c2w


W, H, F_PX = 40, 20, 20.0
K = np.array([[F_PX, 0, W / 2], [0, F_PX, H / 2], [0, 0, 1]], np.float64)


def _cast_plane(c2w, occluder=None):
    """The exact ray cast of the plane (analytic: ray-plane hits and barycentrics), with an
    optional occluder: pixels [v0:v1, u0:u1] of another object (instance 2) at depth 1."""
    o, d = pixel_rays(K, c2w, W, H)
    t = -o[2] / d[:, 2]  # z-depth (camera z of d is 1)
    p = o + t[:, None] * d
    V, Fc = _plane().vertices, _plane().faces
    inside = (np.abs(p[:, 0]) <= 2) & (np.abs(p[:, 1]) <= 2)
    tri = np.where(p[:, 1] <= p[:, 0], 0, 1)  # triangle 0 holds y <= x
    bary = np.zeros((len(p), 3))
    for k in (0, 1):
        a, b, c = V[Fc[k]]
        T = np.stack([a - c, b - c], 1)[:2]
        sel = tri == k
        lam = np.linalg.solve(T, (p[sel] - c)[:, :2].T).T
        bary[sel] = np.column_stack([lam, 1 - lam.sum(1)])
    depth = np.where(inside, t, 0).reshape(H, W).astype(np.float32)
    inst = np.where(inside, 1, 0).reshape(H, W).astype(np.int32)
    if occluder is not None:
        v0, v1, u0, u1 = occluder
        depth[v0:v1, u0:u1], inst[v0:v1, u0:u1] = 1.0, 2
    return RayCast(
        depth=depth,
        instance=inst,
        mesh=np.where(inside, 0, -1).reshape(H, W).astype(np.int32),
        triangle=np.where(inside, tri, -1).reshape(H, W).astype(np.int64),
        bary=bary.reshape(H, W, 3),
    )


def test_covisibility_of_a_plane_seen_by_shifted_cameras_and_an_occluder():
    """Training cameras at x = 0.5, 1.0 and 1.5 looking down from 2 m (each sees x in [cx - 2, cx +
    2]); the view at x = 0 sees x in [-2, 2]. A view pixel is co-visible when >= 2 training
    cameras hold its point in frame: x >= -0.5 (cameras 0.5 and 1.0). The second training camera
    has an occluder over its pixels u in [20, 30): plane points at x in [1.0, 2.0) are hidden from
    it, so there only cameras 0.5 and 1.5 see them (still 2), except where camera 0.5's frame ends
    (x >= 2.5: off the plane anyway)."""
    plane = _plane()
    view = _cast_plane(_down(0.0))
    states, casts = [], []
    for i, x in enumerate((0.5, 1.0, 1.5)):
        states.append(SimpleNamespace(meshes=[plane], K=K, c2w=_down(x)))
        casts.append(_cast_plane(_down(x), occluder=(0, H, 20, 30) if i == 1 else None))
    covis = covisibility(view, states, casts, min_count=2)
    u = np.arange(W) + 0.5
    x = (u - W / 2) / F_PX * 2.0  # plane x of each view column
    # how many training cameras see x: in frame (|x - cx| < 2) and not behind the occluder
    seen = np.zeros(W, int)
    for i, cx in enumerate((0.5, 1.0, 1.5)):
        uu = (x - cx) / 2.0 * F_PX + W / 2
        ok = (uu >= 0) & (uu < W)
        if i == 1:
            ok &= ~((uu >= 20) & (uu < 30))
        seen += ok
    want = np.broadcast_to(seen >= 2, (H, W))
    np.testing.assert_array_equal(covis, want)
    assert 0 < covis.mean() < 1
    # the occluder over all of camera 1.0: points that only camera 0.5 also holds lose it
    casts[1] = _cast_plane(_down(1.0), occluder=(0, H, 0, W))
    assert covisibility(view, states, casts, min_count=2).sum() < covis.sum()


# -- camera motion --------------------------------------------------------------------------------
def test_camera_motion_of_an_orbit_and_a_moving_point():
    """A camera orbiting its look-at point at 2 degrees a frame (30 fps: 60 deg/s) 5 m away, and one
    moving point at 0.5 m/s: scene 0.5 / 5 rad/s."""
    G, fps, r = 12, 30.0, 5.0
    c2w, dist = [], []
    for g in range(G):
        a = np.radians(2.0 * g)
        c2w.append(look_at([r * np.cos(a), r * np.sin(a), 0.0], [0, 0, 0]))
        dist.append(r)
    pts = np.zeros((2, G, 3))
    pts[0, :, 0] = 0.5 * np.arange(G) / fps  # moving
    m = camera_motion(np.array(c2w), np.array(dist), fps, pts, np.array([True, False]))
    assert m["camera_deg_s"] == pytest.approx(60.0)
    assert m["camera_speed"] == pytest.approx(2 * np.sin(np.radians(1.0)) * fps)
    assert m["scene_speed_m_s"] == pytest.approx(0.5)
    assert m["scene_deg_s"] == pytest.approx(np.degrees(0.1))
    assert m["emf"] == pytest.approx(60.0 / np.degrees(0.1))
    still = camera_motion(np.array(c2w), np.array(dist), fps, pts, np.array([False, False]))
    assert still["emf"] is None and still["scene_speed_m_s"] is None


# -- the views of a generated clip ---------------------------------------------------------------
def _bilinear(img: np.ndarray, uv: np.ndarray):
    """img [H, W, ...] sampled at pixels uv [N, 2] (centres at +0.5), and which uv had all four
    neighbours inside."""
    Hh, Ww = img.shape[:2]
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    ok = (x0 >= 0) & (y0 >= 0) & (x0 + 1 < Ww) & (y0 + 1 < Hh)
    x0, y0 = np.clip(x0, 0, Ww - 2), np.clip(y0, 0, Hh - 2)
    fx, fy = x - x0, y - y0
    if img.ndim == 3:
        fx, fy = fx[:, None], fy[:, None]
    v = (
        img[y0, x0] * (1 - fx) * (1 - fy)
        + img[y0, x0 + 1] * fx * (1 - fy)
        + img[y0 + 1, x0] * (1 - fx) * fy
        + img[y0 + 1, x0 + 1] * fx * fy
    )
    return v, ok


def _reprojection(clip, view, j, g, c2w=None):
    """View pixels with a surface, lifted with the view's depth and camera (`c2w` overrides it)
    and projected into test frame g's ground-truth camera: (z there, uv, the test frame's depth
    there (bilinear), in-frame flags, view pixel indices)."""
    vc = clip.load_view_cameras(view)
    cams = clip.load_gt_cameras()
    i = list(cams.frames).index(g)
    d = clip.load_view_depth(view, g)
    o, dirs = pixel_rays(vc.K[j], vc.c2w[j] if c2w is None else c2w, clip.width, clip.height)
    hit = np.flatnonzero(d.reshape(-1) > 0)
    p = o + dirs[hit] * d.reshape(-1)[hit, None]
    uv, z = project(p, (cams.K[i], cams.c2w[i]))
    dt, ok = _bilinear(clip.load_gt_depth(g), np.nan_to_num(uv, nan=-10.0))
    return z, uv, dt, ok & (z > 0), hit


def test_view_depth_reprojects_onto_the_test_frame_s_surfaces(tiny_clip_oracle):
    """Each view pixel's depth, lifted with the view camera and projected into the test frame's
    own camera, lands on a surface of the same depth (1 %) wherever nothing hides it there; a view
    camera turned by 2 degrees does not."""
    clip = Clip.open(tiny_clip_oracle)
    assert clip.view_names() == ["small", "medium", "large"]
    worse = []
    for view in clip.view_names():
        vc = clip.load_view_cameras(view)
        for j, g in enumerate(clip.test_frames):
            z, _, dt, ok, _ = _reprojection(clip, view, j, g)
            match = np.abs(dt[ok] - z[ok]) <= 0.01 * z[ok]
            assert ok.mean() > 0.8 and match.mean() > 0.8, (view, g, ok.mean(), match.mean())
            turned = vc.c2w[j].copy()
            turned[:3, :3] = axis_angle(turned[:3, 1], np.radians(2.0)) @ turned[:3, :3]
            z2, _, dt2, ok2, _ = _reprojection(clip, view, j, g, turned)
            worse.append(match.mean() - np.mean(np.abs(dt2[ok2] - z2[ok2]) <= 0.01 * z2[ok2]))
    assert np.mean(worse) > 0.2


def test_view_radiance_matches_the_test_frame_on_diffuse_surfaces(tiny_clip_oracle):
    """Lambertian surfaces send the same radiance every way: a view pixel on a diffuse object
    equals the test frame's HDR where it reprojects onto the same surface (median relative
    difference: render noise and the denoiser, a few per cent); the view's LDR is the clip's
    response of its HDR."""
    from benchgen.spec import load_scene_spec
    from benchgen.suite import builtin_scenes_dir
    from m4dgs.core.crf import clip_crf, tonemap_ldr

    clip = Clip.open(tiny_clip_oracle)
    spec = load_scene_spec(builtin_scenes_dir() / "tiny-flag-arm.yaml")
    # the same instant: moving objects are where the test frame has them
    diffuse = [i + 1 for i, o in enumerate(spec["objects"]) if o["material"]["kind"] == "diffuse"]
    assert diffuse
    crf = clip_crf(clip.meta.crf)
    for view in clip.view_names():
        for j, g in enumerate(clip.test_frames):
            z, uv, dt, ok, hit = _reprojection(clip, view, j, g)
            same = ok & (np.abs(dt - z) <= 0.005 * z)
            inst = _instance_of(clip, view, g).reshape(-1)[hit]
            sel = same & np.isin(inst, diffuse)
            assert sel.sum() > 50
            hv = clip.load_view_hdr(view, g).reshape(-1, 3)[hit][sel]
            ht, _ = _bilinear(clip.load_gt_hdr(g), uv[sel])
            rel = np.abs(hv.mean(1) - ht.mean(1)) / np.maximum(ht.mean(1), 1e-6)
            assert np.median(rel) < 0.06, (view, g, np.median(rel))
            level = clip.meta.test_levels_of(g)[0]
            np.testing.assert_array_equal(
                clip.load_view_ldr(view, level, g),
                tonemap_ldr(clip.load_view_hdr(view, g), float(level), crf),
            )


def _instance_of(clip, view, g):
    """The view's object ids, from the scene (a ray cast of the view camera): the clip stores only
    the dynamic mask."""
    from benchgen.render import Renderer, RenderSettings
    from benchgen.scene import load_scene
    from benchgen.suite import builtin_scenes_dir
    from benchgen.views import view_state

    key = (view, g)
    if key not in _INSTANCES:
        scene = load_scene(
            builtin_scenes_dir() / "tiny-flag-arm.yaml", band_limit=(clip.width, clip.height)
        )
        st = scene.frame(g, clip.width, clip.height)
        j = clip.test_frames.index(g)
        r = Renderer(st, clip.width, clip.height, RenderSettings.resolve("tiny"))
        r.update(view_state(st, clip.load_view_cameras(view).c2w[j]))
        _INSTANCES[key] = r.cast_rays().instance
    return _INSTANCES[key]


_INSTANCES: dict = {}


def test_views_are_in_clip_json_and_validated(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    gt = clip.meta.gt
    assert [v for v in gt["views"]] == ["small", "medium", "large"]
    angles = [gt["views"][v]["angle_deg"] for v in ("small", "medium", "large")]
    assert angles == sorted(angles) and angles[0] == pytest.approx(6.0)
    assert all(0.3 < gt["views"][v]["covisible"] <= 1 for v in gt["views"])
    assert gt["camera_motion"]["camera_deg_s"] > 0 and gt["camera_motion"]["emf"] > 0
    for view in clip.view_names():
        for g in clip.test_frames:
            covis = clip.load_view_covis(view, g)
            assert not (covis & (clip.load_view_depth(view, g) == 0)).any()
    copy = tmp_path / "clip"
    shutil.copytree(tiny_clip_oracle, copy)
    Clip.open(copy).validate()
    victim = copy / "gt" / "views" / "large" / "covis" / f"{clip.test_frames[-1]:05d}.png"
    victim.unlink()
    with pytest.raises(ClipError, match="large/covis"):
        Clip.open(copy).validate()


SHIPPED_BENCHMARK_SUITES = ("syn-exp-3", "hard", "hard-lit")


@pytest.mark.slow  # ~1 min a suite on 2 idle cores: Mitsuba scenes built at the small preset
@pytest.mark.parametrize("suite", SHIPPED_BENCHMARK_SUITES)
def test_every_shipped_scene_places_its_views_at_the_small_preset(suite):
    """The generator refuses a view inside or against geometry only when it gets there, after
    the frames are rendered; ray casts alone say it up front. Every benchmark scene's views, at
    every 4th test frame of the small preset (waving-flag-window's default large swing stood in
    its wall at the first nine)."""
    from benchgen.make import _prepare_job
    from benchgen.render import Renderer
    from benchgen.suite import builtin_scenes_dir, load_suite
    from benchgen.views import pivot_distance, placement_problem, view_c2w, view_state

    problems = []
    for path in load_suite(suite).scenes:
        job = _prepare_job(path, "unused", "small", None, "realistic", 0, "hdrnerf", None, None)
        W, H, scene = job.preset.width, job.preset.height, job.scene
        caster = Renderer(scene.frame(job.test[0], W, H), W, H, job.render)
        for g in job.test[::4]:
            st = scene.frame(g, W, H)
            caster.update(st)
            cast = caster.cast_rays()
            dist, surface = pivot_distance(cast.depth), float(cast.hit.mean())
            for v in scene.spec["camera"]["views"]:
                caster.update(view_state(st, view_c2w(st.c2w, dist, v["orbit_deg"], v["offset"])))
                p = placement_problem(caster.cast_rays().depth, dist, surface)
                if p is not None:
                    problems.append(f"{path.stem} {v['name']} frame {g}: {p}")
    assert builtin_scenes_dir().is_dir() and not problems, problems
