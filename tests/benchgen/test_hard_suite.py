"""The hard suite (scenes/suites/hard.yaml): every scene validates, keeps the syn-exp-3 exposure
protocol and the default held-out views, and puts a small bright mover in the frame at the small
preset (measured from the spec's geometry: z-buffered pixels and projected motion, no rendering).
The rendering check (placement targets of the tiny clips) is marked slow."""

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


@pytest.mark.parametrize("name", sorted(SCENES))
def test_hard_scene_validates_and_keeps_the_default_views(name):
    sc = load_scene(SCENES[name], band_limit=None)
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


@pytest.mark.parametrize("name", sorted(SCENES))
def test_hard_scene_has_a_small_bright_mover(name):
    movers = _movers(load_scene(SCENES[name], band_limit=None))
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


def test_sun_patch_scene_is_closed_and_sunlit():
    """The sunlit patch comes from the sun through the window; the room is closed around it (the
    doorway leads to nothing), so its shadows stay deep."""
    sc = load_scene(SCENES["sun-patch-dolly"], band_limit=None)
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
