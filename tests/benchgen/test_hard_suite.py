"""The hard suite (scenes/suites/hard.yaml) and its lit variant (hard-lit.yaml): every scene
validates, keeps the syn-exp-3 exposure protocol and the default held-out views, and puts a small
bright mover in the frame at the small preset (measured from the spec's geometry: z-buffered pixels
and projected motion, no rendering). hard-lit's own scenes are the lit counterparts of hard scenes
whose mover lights the room: same geometry, camera and motion, and (from the spec's geometry and
lights, no rendering) a mover whose light on the static surfaces it shines on is small against the
static light there. The rendering checks (placement targets of the tiny clips, and the lit scenes'
measured relighting) are marked slow."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from benchgen.make import get_preset
from benchgen.scene import FrameState, Scene, load_scene, rasterize_ids
from benchgen.spec import DEFAULT_VIEWS
from benchgen.suite import load_suite

SUITE = load_suite("hard")
SCENES = {p.stem: p for p in SUITE.scenes}
LIT_SUITE = load_suite("hard-lit")
#: hard-lit's own scenes (the lit counterparts); the rest of hard-lit is hard's
LIT_SCENES = {p.stem: p for p in LIT_SUITE.scenes if p.stem not in SCENES}
ALL_SCENES = {**SCENES, **LIT_SCENES}
SMALL = get_preset("small")
W, H = SMALL.width, SMALL.height

#: a "small" mover covers at most this many pixels across (median over the frames it is seen in)
MAX_EXTENT_PX = 6
#: and it moves at least this fast on screen at its fastest (pixels per frame at the small preset)
MIN_SPEED_PX = 2.0
#: brightness of a "bright" emitter (every shipped lamp is >= 1000; windows are ~10-50)
MIN_RADIANCE = 1000.0
#: a mirror-like glossy surface (GGX alpha) whose glints count as bright movers
MAX_GLINT_ROUGHNESS = 0.05
FRAME_STEP = 6


def _project(state: FrameState, p: np.ndarray) -> np.ndarray:
    """World points [N, 3] -> pixel coordinates [N, 2] and z [N] (OpenCV camera)."""
    R, T = state.c2w[:3, :3], state.c2w[:3, 3]
    pc = (np.atleast_2d(p) - T) @ R
    uv = (state.K @ pc.T).T
    return uv[:, :2] / uv[:, 2:3], pc[:, 2]


def _glint_point(state: FrameState, sphere, lamp) -> np.ndarray:
    """Where a mirror sphere shows a small lamp: the surface point whose normal bisects the
    directions to the camera and to the lamp."""
    c = sphere.vertices.mean(0)
    r = np.linalg.norm(sphere.vertices - c, axis=1).max()
    to_cam = state.c2w[:3, 3] - c
    to_lamp = lamp.vertices.mean(0) - c
    n = to_cam / np.linalg.norm(to_cam) + to_lamp / np.linalg.norm(to_lamp)
    return c + r * n / np.linalg.norm(n)


def _movers(scene: Scene) -> dict:
    """{name: {'seen', 'frames', 'extent', 'speed'}} for every bright emitter and every glint of a
    bright emitter on a moving mirror-like sphere, sampled every FRAME_STEP frames at the small
    preset: 'seen' frames where it is visible (z-buffered), its median pixel extent there, its
    fastest on-screen speed (px per frame, between frame g and g + 1)."""
    lamps = [
        o
        for o in scene.objects
        if o.material.kind == "emitter" and max(o.material.radiance) >= MIN_RADIANCE
    ]
    spheres = [
        o
        for o in scene.objects
        if o.material.kind == "glossy"
        and o.material.roughness <= MAX_GLINT_ROUGHNESS
        and o.dynamic
        and o.mesh_spec["type"] == "uv_sphere"
    ]
    out = {}
    frames = list(range(0, scene.num_frames - 1, FRAME_STEP))
    for g in frames:
        st, nxt = scene.frame(g, W, H), scene.frame(g + 1, W, H)
        ids, _ = rasterize_ids(st, W, H)
        mesh = {m.name: m for m in st.meshes}
        mesh1 = {m.name: m for m in nxt.meshes}
        for o in lamps:
            rec = out.setdefault(
                o.name, {"seen": 0, "frames": len(frames), "extent": [], "speed": 0.0}
            )
            ys, xs = np.nonzero(ids == o.instance_id)
            if len(xs) == 0:
                continue
            rec["seen"] += 1
            rec["extent"].append(max(np.ptp(xs), np.ptp(ys)) + 1)
            a, _ = _project(st, mesh[o.name].vertices.mean(0))
            b, _ = _project(nxt, mesh1[o.name].vertices.mean(0))
            rec["speed"] = max(rec["speed"], float(np.linalg.norm(b - a)))
        for s in spheres:
            for o in lamps:
                key = f"glint of {o.name} on {s.name}"
                rec = out.setdefault(
                    key, {"seen": 0, "frames": len(frames), "extent": [], "speed": 0.0}
                )
                p = _glint_point(st, mesh[s.name], mesh[o.name])
                (uv,), (z,) = _project(st, p)
                col, row = int(math.floor(uv[0])), int(math.floor(uv[1]))
                if not (z > 0 and 0 <= col < W and 0 <= row < H and ids[row, col] == s.instance_id):
                    continue
                rec["seen"] += 1
                # a convex mirror (radius r) images a lamp (radius a, distance d) at radius a r / 2d
                lamp = mesh[o.name].vertices
                a_lamp = np.linalg.norm(lamp - lamp.mean(0), axis=1).max()
                c = mesh[s.name].vertices.mean(0)
                r = np.linalg.norm(mesh[s.name].vertices - c, axis=1).max()
                image = a_lamp * r / (2 * np.linalg.norm(lamp.mean(0) - c))
                rec["extent"].append(2 * st.K[0, 0] * image / z + 1)
                (uv1,), _ = _project(nxt, _glint_point(nxt, mesh1[s.name], mesh1[o.name]))
                rec["speed"] = max(rec["speed"], float(np.linalg.norm(uv1 - uv)))
    return out


def test_the_suite_uses_the_syn_exp_3_protocol_and_requires_placement():
    base = load_suite("syn-exp-3")
    assert len(SCENES) == 6
    assert list(SUITE.observed) == list(base.observed) == [0.125, 2.0, 32.0]
    assert list(SUITE.novel) == list(base.novel) == [0.5, 8.0]
    assert SUITE.schedule == base.schedule == "alternating"
    assert SUITE.placement == "require"
    assert not set(SCENES) & {p.stem for p in base.scenes}, "the hard scenes are new scenes"


@pytest.mark.parametrize("name", sorted(ALL_SCENES))
def test_hard_scene_validates_and_keeps_the_default_views(name):
    sc = load_scene(ALL_SCENES[name], band_limit=None)
    assert sc.name == name
    assert sc.spec["camera"]["views"] == DEFAULT_VIEWS
    assert sc.num_frames == 100 and sc.fps == 30
    # the first frames (all a tiny clip renders) already hold a dynamic object and a bright lamp
    tiny = get_preset("tiny")
    st = sc.frame(tiny.max_frames - 1, W, H)
    assert any(m.dynamic for m in st.meshes) or sc.spec["camera"]["trajectory"]["type"] != "static"
    assert any(
        m.material.kind == "emitter" and max(m.material.radiance) >= MIN_RADIANCE for m in st.meshes
    )


@pytest.mark.parametrize("name", sorted(ALL_SCENES))
def test_hard_scene_has_a_small_bright_mover(name):
    movers = _movers(load_scene(ALL_SCENES[name], band_limit=None))
    small_fast = {
        k: v
        for k, v in movers.items()
        if v["seen"] >= v["frames"] / 3
        and np.median(v["extent"]) <= MAX_EXTENT_PX
        and v["speed"] >= MIN_SPEED_PX
    }
    assert small_fast, f"{name}: no small bright mover: {json.dumps(movers, default=str)}"


def test_the_mover_check_can_fail():
    """A big slow lamp and a small lamp out of view are not small bright movers."""
    sc = load_scene(SCENES["spark-crossing-static"], band_limit=None)
    movers = _movers(sc)
    assert np.median(movers["spark"]["extent"]) <= MAX_EXTENT_PX and movers["spark"]["speed"] > 8
    assert movers["wall-lamp"]["speed"] < 0.5  # static camera, static lamp
    spec = sc.spec
    spec["objects"] = [o for o in spec["objects"] if o["name"] != "spark"]
    spec["objects"].append(
        {
            **spec["objects"][-1],
            "name": "big-lamp",
            "mesh": {"type": "uv_sphere", "radius": 0.5, "segments": 16, "rings": 8},
            "transform": {
                "translate": [0.0, 0.0, 1.3],
                "rotate_deg": [0, 0, 0],
                "scale": [1, 1, 1],
            },
            "motion": {
                "type": "translate",
                "velocity": [0.3, 0, 0],
                "start_time": 0.0,
                "end_time": None,
            },
        }
    )
    movers = _movers(Scene(spec, band_limit=None))
    assert np.median(movers["big-lamp"]["extent"]) > MAX_EXTENT_PX
    assert movers["big-lamp"]["speed"] < MIN_SPEED_PX


def test_the_glint_scene_has_mirror_like_movers_under_a_small_lamp():
    sc = load_scene(SCENES["glints-turntable-orbit"], band_limit=None)
    glossy = [o for o in sc.objects if o.material.kind == "glossy" and o.dynamic]
    assert len(glossy) >= 3 and all(o.material.roughness <= MAX_GLINT_ROUGHNESS for o in glossy)
    movers = _movers(sc)
    glint = movers["glint of lamp on chrome-ball"]
    # seen on the ball in most frames (it passes behind the box), far below a pixel across
    assert glint["seen"] >= 2 * glint["frames"] / 3 and max(glint["extent"]) < 2


@pytest.mark.parametrize("name", ["sun-patch-dolly", "sun-patch-lit-dolly"])
def test_sun_patch_scene_is_closed_and_sunlit(name):
    """The sunlit patch comes from the sun through the window; the room is closed around it (the
    doorway leads to nothing), so its shadows stay deep."""
    sc = load_scene(ALL_SCENES[name], band_limit=None)
    assert sc.lighting.sun_direction is not None and sc.lighting.sun_direction[2] > 0
    names = {o.name for o in sc.objects}
    assert {"floor", "ceiling", "back-wall", "left-wall", "right-wall", "front-wall"} <= names
    assert max(sc.lighting.env_radiance) <= 0.005


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SCENES))
def test_hard_scene_tiny_clip_meets_the_placement_targets(name, tmp_path):
    from benchgen.make import make_suite

    make_suite("hard", tmp_path, preset="tiny", scenes=[name], progress=False)
    clip = json.loads((tmp_path / "hard" / name / "clip.json").read_text())
    assert clip["gt"]["placement"]["all_met"], clip["gt"]["placement"]["targets"]
    assert set(clip["gt"]["views"]) == {v["name"] for v in DEFAULT_VIEWS}


# ------------------------------------------------------------------------------- the hard-lit suite
def _original_of(lit_name: str) -> str:
    """A lit counterpart's original: its name without the "-lit" before the camera kind."""
    return lit_name.replace("-lit-", "-")


def test_the_lit_suite_is_the_hard_suite_with_lit_counterparts():
    assert list(LIT_SUITE.observed) == list(SUITE.observed)
    assert list(LIT_SUITE.novel) == list(SUITE.novel)
    assert LIT_SUITE.schedule == SUITE.schedule and LIT_SUITE.placement == "require"
    # scene for scene, in hard's order: hard's own scene or its lit counterpart
    lit = [p.stem for p in LIT_SUITE.scenes]
    assert [_original_of(n) for n in lit] == [p.stem for p in SUITE.scenes]
    assert set(LIT_SCENES) == {
        "spark-crossing-lit-static",
        "headlights-pass-lit-dolly",
        "bare-bulb-swing-lit-handheld",
        "sun-patch-lit-dolly",
    }


def _motionless(obj: dict) -> bool:
    return (obj.get("motion") or {"type": "none"})["type"] == "none"


@pytest.mark.parametrize("name", sorted(LIT_SCENES))
def test_lit_counterpart_keeps_the_original_scene(name):
    """Same camera, clip length, objects, placement and motion as the original; only emitter
    radiance changes, the movers get dimmer, and what is added stands still."""
    lit = load_scene(LIT_SCENES[name], band_limit=None).spec
    orig = load_scene(SCENES[_original_of(name)], band_limit=None).spec
    for key in ("fps", "num_frames", "seed", "camera"):
        assert lit[key] == orig[key], key
    lit_objs = {o["name"]: o for o in lit["objects"]}
    movers = 0
    for o in orig["objects"]:
        mine = lit_objs.pop(o["name"])
        for key in ("mesh", "transform", "motion"):
            assert mine.get(key) == o.get(key), (o["name"], key)
        if o["material"]["kind"] != "emitter":
            assert mine["material"] == o["material"], o["name"]
            continue
        assert mine["material"]["kind"] == "emitter"
        if not _motionless(o):
            movers += 1
            assert max(mine["material"]["radiance"]) < max(o["material"]["radiance"]), o["name"]
    assert movers >= 1
    # the added light: static objects only, at least one of them a static emitter
    assert lit_objs and all(_motionless(o) for o in lit_objs.values())
    assert any(o["material"]["kind"] == "emitter" for o in lit_objs.values())


# The mover's light against the static light, from the spec alone: from the mover's centre, rays in
# DIRECTIONS directions find the static surface points it shines on (every FRAME_STEP-th frame of
# the whole clip); at each, the mover's irradiance is bounded above by its radiance times the solid
# angle of its bounding sphere, and the static light's is the irradiance of every static emitter
# (area-weighted points on its front faces, with visibility) plus the sun (with visibility). The
# constant environment is left out, which can only raise the ratio. A point lit by the mover at a
# fraction f of its static light changes brightness by at most a factor 1 + f as the mover comes
# and goes, so the median f over those points bounds the relighting that the mover causes there;
# MAX_MOVER_LIGHT is the relighting target of the lit scenes (median_ratio <= 1.3) in that form.
MAX_MOVER_LIGHT = 0.3
DIRECTIONS = 24
_EPS = 1e-4


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def _first_hit(o: np.ndarray, d: np.ndarray, tris: np.ndarray, chunk: int = 512):
    """Moller-Trumbore: rays o + t d ([R, 3] each) against triangles [T, 3, 3] -> (t [R], triangle
    index [R]); t = inf and index -1 where nothing is hit."""
    v0 = tris[:, 0]
    e1, e2 = tris[:, 1] - v0, tris[:, 2] - v0
    t_best = np.full(len(o), np.inf)
    i_best = np.full(len(o), -1)
    for a in range(0, len(o), chunk):
        oo, dd = o[a : a + chunk, None, :], d[a : a + chunk, None, :]
        p = np.cross(dd, e2[None])
        det = (e1[None] * p).sum(-1)
        good = np.abs(det) > 1e-12
        inv = np.where(good, 1.0 / np.where(good, det, 1.0), 0.0)
        s = oo - v0[None]
        u = (s * p).sum(-1) * inv
        q = np.cross(s, e1[None])
        v = (dd * q).sum(-1) * inv
        t = (e2[None] * q).sum(-1) * inv
        t = np.where(good & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > _EPS), t, np.inf)
        j = t.argmin(1)
        t_best[a : a + chunk] = t[np.arange(len(j)), j]
        i_best[a : a + chunk] = np.where(np.isfinite(t_best[a : a + chunk]), j, -1)
    return t_best, i_best


def _emitter_points(tris: np.ndarray, n: int = 3):
    """Points on every triangle (a barycentric grid of n (n + 1) / 2), their area weights and the
    triangle's front normal (the emitting side: counter-clockwise winding)."""
    bary = [((i + 1 / 3) / n, (j + 1 / 3) / n) for i in range(n) for j in range(n - i)]
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    cr = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    normal = cr / np.maximum(2 * area[:, None], 1e-20)
    pts = np.concatenate([tris[:, 0] + u * e1 + v * e2 for u, v in bary])
    return pts, np.tile(area / len(bary), len(bary)), np.tile(normal, (len(bary), 1))


def _static_irradiance(st: FrameState, x: np.ndarray, n: np.ndarray, tris: np.ndarray) -> float:
    """Irradiance at x (surface normal n) from the static emitters and the sun, with visibility."""
    xo = x + n * 1e-3
    e = 0.0
    for m in st.meshes:
        if m.material.kind != "emitter" or m.dynamic:
            continue
        pts, w, en = _emitter_points(m.vertices[m.faces])
        v = pts - xo
        dist = np.linalg.norm(v, axis=1)
        u = v / dist[:, None]
        cos_x, cos_y = u @ n, -(u * en).sum(1)
        use = (cos_x > 0) & (cos_y > 0)
        if not use.any():
            continue
        th, _ = _first_hit(np.repeat(xo[None], use.sum(), 0), u[use], tris)
        seen = th >= dist[use] * (1 - 1e-6)
        contrib = np.mean(m.material.radiance) * w * cos_x * cos_y / dist**2
        e += float(contrib[use][seen].sum())
    sun = st.lighting.sun_direction
    if sun is not None and n @ sun > 0:
        th, _ = _first_hit(xo[None], sun[None], tris)
        if not np.isfinite(th[0]):
            e += float(np.mean(st.lighting.sun_irradiance)) * float(n @ sun)
    return e


def _mover_light(scene: Scene) -> float:
    """Median over the static surface points the moving emitters shine on of the ratio of their
    irradiance there (an upper bound) to the static light's (a lower bound); see MAX_MOVER_LIGHT."""
    movers = {o.name for o in scene.objects if o.material.kind == "emitter" and o.dynamic}
    dirs = _fibonacci_sphere(DIRECTIONS)
    ratios = []
    for g in range(0, scene.num_frames, FRAME_STEP):
        st = scene.frame(g, W, H)
        tris = np.concatenate([m.vertices[m.faces] for m in st.meshes])
        owner = np.concatenate([np.full(len(m.faces), i) for i, m in enumerate(st.meshes)])
        for mv in (m for m in st.meshes if m.name in movers):
            c = mv.vertices.mean(0)
            r = np.linalg.norm(mv.vertices - c, axis=1).max()
            o = c + dirs * (1.01 * r)
            t, idx = _first_hit(o, dirs, tris)
            for k in np.nonzero(np.isfinite(t))[0]:
                hit = st.meshes[owner[idx[k]]]
                if hit.dynamic or hit.material.kind == "emitter":
                    continue  # the mover's own object or another light, not a static surface
                x = o[k] + t[k] * dirs[k]
                tri = tris[idx[k]]
                n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
                n = n / np.linalg.norm(n)
                n = -n if n @ dirs[k] > 0 else n  # the side facing the mover
                d = float(np.linalg.norm(c - x))
                solid_angle = 2 * math.pi * (1 - math.sqrt(max(0.0, 1 - (r / d) ** 2)))
                e_mover = np.mean(mv.material.radiance) * solid_angle * max(0.0, n @ (c - x) / d)
                ratios.append(e_mover / max(_static_irradiance(st, x, n, tris), 1e-30))
    assert len(ratios) >= 50, f"{scene.name}: the movers shine on too few static points"
    return float(np.median(ratios))


@pytest.mark.parametrize("name", sorted(LIT_SCENES))
def test_lit_scene_mover_barely_lights_the_static_surfaces(name):
    ratio = _mover_light(load_scene(LIT_SCENES[name], band_limit=None))
    assert ratio <= MAX_MOVER_LIGHT, f"{name}: the mover adds {ratio:.2f} of the static light"


def test_the_mover_light_bound_can_fail():
    """Every original of a lit scene fails it: its mover is the main light of what it shines on."""
    for name in sorted(LIT_SCENES):
        orig = _original_of(name)
        ratio = _mover_light(load_scene(SCENES[orig], band_limit=None))
        assert ratio > 10 * MAX_MOVER_LIGHT, (orig, ratio)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(LIT_SCENES))
def test_lit_scene_tiny_clip_meets_the_targets_and_is_not_relit(name, tmp_path):
    """Placement and views as for the hard scenes, and the measured relighting of the static
    surfaces (benchgen.relighting, over the tiny clip's 17 frames) stays where scenes whose lights
    stand still are."""
    from benchgen.make import make_suite
    from benchgen.relighting import clip_relighting

    make_suite("hard-lit", tmp_path, preset="tiny", scenes=[name], progress=False)
    root = tmp_path / "hard-lit" / name
    clip = json.loads((root / "clip.json").read_text())
    assert clip["gt"]["placement"]["all_met"], clip["gt"]["placement"]["targets"]
    assert set(clip["gt"]["views"]) == {v["name"] for v in DEFAULT_VIEWS}
    rel = clip_relighting(root)
    assert rel["median_ratio"] <= 1.3 and rel["relit_fraction"] <= 0.25, rel
