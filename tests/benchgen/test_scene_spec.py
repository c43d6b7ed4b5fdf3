"""Scene specs, suites, procedural meshes/textures and the coverage rasterizer, against independent
answers."""

import copy
import math
from collections import Counter

import numpy as np
import pytest
import yaml

from benchgen import meshes, textures
from benchgen.scene import (
    FrameState,
    Scene,
    dynamic_pixel_fraction,
    load_scene,
    rasterize_ids,
    scene_from_dict,
)
from benchgen.spec import SpecError, load_scene_spec, validate_scene
from benchgen.suite import builtin_scenes_dir, builtin_suites, load_suite

MIN_SPEC = {
    "name": "mini",
    "num_frames": 5,
    "camera": {"trajectory": {"type": "static", "position": [0, -4, 1], "target": [0, 0, 1]}},
    "objects": [
        {"name": "floor", "mesh": {"type": "plane", "size": [4, 4]}},
        {
            "name": "box",
            "mesh": {"type": "box", "size": [1, 1, 1]},
            "motion": {"type": "translate", "velocity": [1, 0, 0]},
        },
        {"name": "ball", "mesh": {"type": "uv_sphere", "radius": 0.3}},
    ],
}


def _spec(**patch):
    s = copy.deepcopy(MIN_SPEC)
    for path, value in patch.items():
        d = s
        keys = path.split("__")
        for k in keys[:-1]:
            d = d[int(k)] if k.isdigit() else d[k]
        last = keys[-1]
        if value is _DELETE:
            del d[last]
        else:
            d[int(last) if last.isdigit() else last] = value
    return s


_DELETE = object()


# --------------------------------------------------------------------------------------------------
# Validation errors name the file, the key path and what was expected
# --------------------------------------------------------------------------------------------------
def test_minimal_spec_gets_defaults():
    s = validate_scene(copy.deepcopy(MIN_SPEC), "mini.yaml")
    assert s["fps"] == 30.0 and s["seed"] == 0 and s["camera"]["fov_deg"] == 60.0
    assert s["objects"][0]["material"] == {
        "kind": "diffuse",
        "color": [0.5, 0.5, 0.5],
        "texture": None,
    }
    assert s["objects"][0]["transform"]["scale"] == [1.0, 1.0, 1.0]
    assert s["objects"][0]["motion"] == {"type": "none"}
    assert s["objects"][0]["mesh"]["subdivisions"] == 4
    assert s["lighting"] == {"environment": [0.01, 0.01, 0.01], "sun": None}


@pytest.mark.parametrize(
    "patch, key_path, expected_part",
    [
        ({"fps": "fast"}, "fps", "number > 0"),  # wrong type
        ({"num_frames": 2.5}, "num_frames", "int"),  # wrong type (float for int)
        ({"objects__1__mesh__radius": 0.3}, "objects[1].mesh.radius", "a known key"),  # unknown key
        ({"colour": [1, 1, 1]}, "colour", "a known key"),  # unknown top-level key
        (
            {"camera__trajectory": {"type": "orbit", "radius": 3}},
            "camera.trajectory.target",
            "required key",
        ),  # missing
        # key of another variant
        ({"camera__trajectory__type": "orbit"}, "camera.trajectory.position", "a known key"),
        ({"objects__0__name": _DELETE}, "objects[0].name", "required key"),  # missing key
        (
            {"objects__2__motion": {"type": "foo"}},
            "objects[2].motion.type",
            "one of ['none', 'keyframes'",
        ),  # enum
        (
            {"objects__0__transform": {"translate": [1, 2]}},
            "objects[0].transform.translate",
            "list of 3",
        ),
        (
            {"objects__2__material": {"kind": "emitter"}},
            "objects[2].material.radiance",
            "required key",
        ),
        (
            {"objects__2__material": {"kind": "glossy", "roughness": 3}},
            "objects[2].material.roughness",
            "<= 1",
        ),
        ({"objects__1__name": "floor"}, "objects[1].name", "unique name"),
        # implausible magnitudes (typos): a kilometre-sized mesh, a far position, a blinding lamp
        (
            {"objects__1__mesh": {"type": "uv_sphere", "radius": 1e30}},
            "objects[1].mesh.radius",
            "<= 1000",
        ),
        (
            {"objects__0__transform": {"translate": [0, 5e3, 0]}},
            "objects[0].transform.translate[1]",
            "<= 1000",
        ),
        (
            {"objects__2__material": {"kind": "emitter", "radiance": [1e9, 1, 1]}},
            "objects[2].material.radiance[0]",
            "<= 1e+06",
        ),
        ({"objects": []}, "objects", "at least 1"),
    ],
)
def test_broken_spec_is_rejected_with_key_path(patch, key_path, expected_part):
    with pytest.raises(SpecError) as e:
        validate_scene(_spec(**patch), "scenes/x.yaml")
    assert e.value.key_path == key_path
    assert str(e.value).startswith(f"scenes/x.yaml: {key_path}: expected ")
    assert expected_part in str(e.value)


def test_bad_enum_message_format():
    with pytest.raises(SpecError) as e:
        validate_scene(_spec(objects__2__motion={"type": "foo"}), "scenes/x.yaml")
    msg = str(e.value)
    assert msg == (
        "scenes/x.yaml: objects[2].motion.type: expected one of "
        "['none', 'keyframes', 'translate', 'rotate', 'oscillate', 'articulated', 'flag'], got "
        "'foo'"
    )


@pytest.mark.parametrize(
    "obj, key_path",
    [
        (
            {
                "name": "a",
                "mesh": {"type": "box", "size": [1, 1, 1]},
                "motion": {"type": "articulated", "joints": [{"axis": [0, 0, 1]}]},
            },
            "objects[3].mesh.type",
        ),
        (
            {
                "name": "a",
                "mesh": {"type": "chain", "links": [{"length": 1}, {"length": 1}]},
                "motion": {"type": "articulated", "joints": [{"axis": [0, 0, 1]}]},
            },
            "objects[3].motion.joints",
        ),
        (
            {"name": "a", "mesh": {"type": "chain", "links": [{"length": 1}]}},
            "objects[3].motion.type",
        ),
        (
            {"name": "a", "mesh": {"type": "plane", "size": [1, 1]}, "motion": {"type": "flag"}},
            "objects[3].mesh.type",
        ),
        (
            {
                "name": "a",
                "mesh": {"type": "box", "size": [1, 1, 1]},
                "motion": {
                    "type": "keyframes",
                    "keys": [
                        {"time": 1, "position": [0, 0, 0]},
                        {"time": 0.5, "position": [1, 0, 0]},
                    ],
                },
            },
            "objects[3].motion.keys[1].time",
        ),
        (
            {
                "name": "a",
                "mesh": {"type": "box", "size": [1, 1, 1]},
                "motion": {
                    "type": "keyframes",
                    "keys": [
                        {"time": 0, "position": [0, 0, 0]},
                        {"time": 1, "position": [0, 0, 0], "rotate_deg": [0, 0, 200]},
                    ],
                },
            },
            "objects[3].motion.keys[1].rotate_deg",
        ),
        (
            {
                "name": "a",
                "mesh": {"type": "wall", "size": [2, 2], "opening": [-0.5, 0.5, 1.5, 1.0]},
            },
            "objects[3].mesh.opening",
        ),
        (
            {
                "name": "a",
                "mesh": {"type": "box", "size": [1, 1, 1]},
                "motion": {"type": "rotate", "axis": [0, 0, 0], "speed_deg_s": 1},
            },
            "objects[3].motion.axis",
        ),
    ],
)
def test_cross_field_checks(obj, key_path):
    s = copy.deepcopy(MIN_SPEC)
    s["objects"].append(obj)
    with pytest.raises(SpecError) as e:
        validate_scene(s, "f.yaml")
    assert e.value.key_path == key_path


def test_load_scene_error_names_the_file(tmp_path):
    p = tmp_path / "broken.yaml"
    p.write_text(yaml.safe_dump(_spec(objects__1__mesh={"type": "cube", "size": [1, 1, 1]})))
    with pytest.raises(SpecError) as e:
        load_scene(p)
    assert str(e.value).startswith(f"{p}: objects[1].mesh.type: expected one of [")
    bad = tmp_path / "bad-yaml.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(SpecError) as e:
        load_scene(bad)
    assert e.value.file == str(bad)


def test_broken_suite_is_rejected(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text(
        yaml.safe_dump(
            {"name": "s", "scenes": ["tiny-lamp-box"], "exposures": {"observed": [1, -2]}}
        )
    )
    with pytest.raises(SpecError) as e:
        load_suite(p)
    assert e.value.key_path == "exposures.observed[1]"
    p.write_text(
        yaml.safe_dump({"name": "s", "scenes": ["no-such-scene"], "exposures": {"observed": [1]}})
    )
    with pytest.raises(SpecError) as e:
        load_suite(p)
    assert e.value.key_path == "scenes[0]"


# --------------------------------------------------------------------------------------------------
# Shipped scenes and suites
# --------------------------------------------------------------------------------------------------
SCENE_FILES = sorted(p for p in builtin_scenes_dir().glob("*.yaml"))


def _check_frame(sc: Scene, fs: FrameState, W: int, H: int):
    assert isinstance(fs, FrameState) and fs.time == pytest.approx(fs.g / sc.fps)
    R = fs.c2w[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_array_equal(fs.c2w[3], [0, 0, 0, 1])
    fx = (W / 2) / math.tan(math.radians(sc.fov_deg) / 2)
    np.testing.assert_allclose(fs.K, [[fx, 0, W / 2], [0, fx, H / 2], [0, 0, 1]])
    ids = [m.instance_id for m in fs.meshes]
    assert ids == list(range(1, len(fs.meshes) + 1))
    for m in fs.meshes:
        assert m.vertices.dtype == np.float64 and m.vertices.ndim == 2 and m.vertices.shape[1] == 3
        assert np.isfinite(m.vertices).all()
        assert m.faces.dtype == np.int32 and m.faces.min() >= 0 and m.faces.max() < len(m.vertices)
        assert m.uvs.dtype == np.float32 and m.uvs.shape == (len(m.vertices), 2)
        assert m.uvs.min() >= 0 and m.uvs.max() <= 1
        mat = m.material
        assert mat.kind in ("diffuse", "glossy", "emitter")
        if mat.kind == "emitter":
            assert mat.radiance is not None and min(mat.radiance) >= 0
        elif mat.albedo is not None:
            assert (
                mat.albedo.dtype == np.float32 and mat.albedo.ndim == 3 and mat.albedo.shape[2] == 3
            )
            assert 0 <= mat.albedo.min() and mat.albedo.max() <= 1


@pytest.mark.parametrize("path", SCENE_FILES, ids=[p.stem for p in SCENE_FILES])
def test_shipped_scene_loads_and_gives_valid_frames(path):
    sc = load_scene(path)
    assert sc.name == path.stem
    W, H = 64, 36
    frames = [0, sc.num_frames // 2, sc.num_frames - 1]
    states = [sc.frame(g, W, H) for g in frames]
    for fs in states:
        _check_frame(sc, fs, W, H)
    # same meshes, topology and names every frame; static meshes do not move
    for a, b in zip(states[0].meshes, states[-1].meshes):
        assert a.name == b.name and a.faces is b.faces and a.vertices.shape == b.vertices.shape
        if not a.dynamic:
            np.testing.assert_array_equal(a.vertices, b.vertices)
        else:
            assert not np.allclose(a.vertices, b.vertices), f"dynamic object {a.name} does not move"
    assert any(
        m.material.kind == "emitter" and max(m.material.radiance) >= 1000 for m in states[0].meshes
    ), "every scene has a small very bright lamp"
    for g in range(sc.num_frames):  # every camera pose is a proper rotation with a finite centre
        c2w = sc.c2w(g)
        assert np.isfinite(c2w).all()
        np.testing.assert_allclose(c2w[:3, :3].T @ c2w[:3, :3], np.eye(3), atol=1e-9)
        assert np.linalg.det(c2w[:3, :3]) == pytest.approx(1.0, abs=1e-9)


def test_builtin_suites():
    assert {"syn-exp-3", "tiny"} <= set(builtin_suites())
    s = load_suite("syn-exp-3")
    assert s.name == "syn-exp-3" and len(s.scenes) == 9 and len(set(s.scene_names)) == 9
    assert (
        s.observed == [0.125, 2.0, 32.0] and s.novel == [0.5, 8.0] and s.schedule == "alternating"
    )
    # the validated specs (no Scene: its band-limited textures are what test_shipped_scene_* checks)
    specs = [load_scene_spec(p) for p in s.scenes]
    assert all(90 <= sp["num_frames"] <= 110 and sp["fps"] == 30 for sp in specs)
    cams = Counter(sp["camera"]["trajectory"]["type"] for sp in specs)
    assert {"handheld", "dolly", "orbit"} <= set(cams)
    motions = {o["motion"]["type"] for sp in specs for o in sp["objects"]}
    assert {"keyframes", "translate", "rotate", "oscillate", "articulated", "flag"} <= motions
    assert any(sp["lighting"]["sun"] is not None for sp in specs)
    # a bright window/sky: a large emitter quad with moderate radiance
    assert any(
        o["material"]["kind"] == "emitter"
        and o["mesh"]["type"] == "plane"
        and 5 <= max(o["material"]["radiance"]) <= 50
        for sp in specs
        for o in sp["objects"]
    )
    # thin structures: cylinders of radius <= 2 cm in most scenes
    thin = [
        any(o["mesh"]["type"] == "cylinder" and o["mesh"]["radius"] <= 0.02 for o in sp["objects"])
        for sp in specs
    ]
    assert sum(thin) >= 7
    tiny = load_suite("tiny")
    assert all(load_scene_spec(p)["num_frames"] <= 10 for p in tiny.scenes)


def test_suite_by_path_equals_by_name():
    a = load_suite("tiny")
    b = load_suite(builtin_scenes_dir() / "suites" / "tiny.yaml")
    assert a.scenes == b.scenes and a.observed == b.observed


def test_capped_scene_keeps_timing():
    sc = load_scene(builtin_scenes_dir() / "tiny-lamp-box.yaml")
    c = sc.capped(4)
    assert c.num_frames == 4 and sc.num_frames == 9
    np.testing.assert_array_equal(c.frame(3, 32, 18).c2w, sc.frame(3, 32, 18).c2w)


# --------------------------------------------------------------------------------------------------
# Meshes: winding, closure, analytic volumes
# --------------------------------------------------------------------------------------------------
def _signed_volume(v, f):
    p = v[f]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


def _welded_edges_ok(v, f):
    """Closed and consistently wound: after welding equal positions, each directed edge appears once
    and its reverse once."""
    _, inv = np.unique(np.round(v, 9), axis=0, return_inverse=True)
    ff = inv.reshape(-1)[f]
    edges = Counter()
    for a, b, c in ff:
        for e in ((a, b), (b, c), (c, a)):
            edges[e] += 1
    return all(n == 1 and edges.get((e[1], e[0]), 0) == 1 for e, n in edges.items())


@pytest.mark.parametrize(
    "mesh, volume",
    [
        (meshes.box((1.0, 2.0, 3.0)), 6.0),
        (meshes.box((0.5, 0.5, 0.5), center=(3, -1, 2)), 0.125),
        (meshes.cylinder(0.5, 2.0, 64), None),
        (meshes.cylinder(0.5, 2.0, 64, origin="base"), None),
        (meshes.uv_sphere(1.0, 64, 32), None),
        (meshes.wall((4.0, 3.0), 0.2, None), 4 * 3 * 0.2),
    ],
)
def test_closed_meshes_outward_and_watertight(mesh, volume):
    v, f = mesh.vertices, mesh.faces
    assert _welded_edges_ok(v, f)
    vol = _signed_volume(v, f)
    assert vol > 0  # outward winding gives a positive signed volume
    if volume is not None:
        assert vol == pytest.approx(volume, rel=1e-9)
    # convex: every face normal points away from the centroid
    c = v.mean(0) if volume is not None else (v.min(0) + v.max(0)) / 2
    n = meshes.face_normals(v, f)
    centre = v[f].mean(1)
    assert (np.einsum("ij,ij->i", n, centre - c) > 0).all()


def test_sphere_and_cylinder_volume_converge():
    # inscribed polyhedra: volume below the analytic one and converging to it
    for seg, rings in ((32, 16), (128, 64)):
        s = meshes.uv_sphere(1.0, seg, rings)
        vol = _signed_volume(s.vertices, s.faces)
        assert vol < 4 / 3 * math.pi
    assert vol == pytest.approx(4 / 3 * math.pi, rel=2e-3)
    c = meshes.cylinder(0.5, 2.0, 256)
    # prism with a regular n-gon base: area = n/2 r^2 sin(2 pi / n)
    assert _signed_volume(c.vertices, c.faces) == pytest.approx(
        256 / 2 * 0.25 * math.sin(2 * math.pi / 256) * 2.0, rel=1e-9
    )


def test_wall_with_opening_volume_and_chain_parts():
    w = meshes.wall((4.0, 3.0), 0.2, (-1.0, 1.0, 0.5, 2.0))
    assert _signed_volume(w.vertices, w.faces) == pytest.approx((4 * 3 - 1.5 * 1.0) * 0.2, rel=1e-9)
    door = meshes.wall((4.0, 3.0), 0.2, (-0.5, 0.0, 0.5, 2.0))
    assert _signed_volume(door.vertices, door.faces) == pytest.approx((12 - 2.0) * 0.2, rel=1e-9)
    ch = meshes.chain(
        [
            {"shape": "box", "length": 1.0, "width": 0.2},
            {"shape": "cylinder", "length": 0.5, "radius": 0.1},
        ]
    )
    assert set(ch.parts.tolist()) == {0, 1}
    z0 = ch.vertices[ch.parts == 0, 2]
    assert z0.min() == pytest.approx(0) and z0.max() == pytest.approx(1.0)


def test_open_sheets_face_plus_z():
    for m, lo, hi in (
        (meshes.plane((2, 3), 4), (-1, -1.5), (1, 1.5)),
        (meshes.grid((2, 1), (8, 4)), (0, 0), (2, 1)),
    ):
        n = meshes.face_normals(m.vertices, m.faces)
        assert (n[:, 2] > 0).all() and np.allclose(n[:, :2], 0)
        np.testing.assert_allclose(m.vertices[:, :2].min(0), lo)
        np.testing.assert_allclose(m.vertices[:, :2].max(0), hi)
        assert n[:, 2].sum() / 2 == pytest.approx((hi[0] - lo[0]) * (hi[1] - lo[1]))  # total area


# --------------------------------------------------------------------------------------------------
# Textures
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["checker", "stripes", "noise"])
def test_textures_deterministic_in_range_textured(kind):
    a = textures.make_texture(kind, frequency=6, noise_amount=0.3, resolution=128, seed=3)
    b = textures.make_texture(kind, frequency=6, noise_amount=0.3, resolution=128, seed=3)
    c = textures.make_texture(kind, frequency=6, noise_amount=0.3, resolution=128, seed=4)
    assert a.shape == (128, 128, 3) and a.dtype == np.float32
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)  # the noise overlay (or the noise itself) follows the seed
    assert a.min() >= 0.02 and a.max() <= 0.95
    assert a.std() > 0.05


def test_checker_matches_parity():
    m = textures.checker_mask(64, 4)
    i, j = 37, 5  # row, column
    u, v = (j + 0.5) / 64, (i + 0.5) / 64
    assert m[i, j] == (math.floor(u * 4) + math.floor(v * 4)) % 2
    assert m.mean() == pytest.approx(0.5)


def test_value_noise_is_smooth_and_tileable():
    n = textures.value_noise(256, frequency=4, octaves=1, seed=0)
    assert n.min() == 0 and n.max() == 1
    # one smooth octave: neighbouring texels differ little; wrap-around neighbours too (tileable)
    assert np.abs(np.diff(n, axis=1)).max() < 0.1
    assert np.abs(n[:, 0] - n[:, -1]).max() < 0.1


# --------------------------------------------------------------------------------------------------
# Coverage rasterizer against analytic areas
# --------------------------------------------------------------------------------------------------
def _quad_scene(with_occluder: bool):
    objs = [
        {
            "name": "card",
            "mesh": {"type": "plane", "size": [1.0, 1.0], "subdivisions": 3},
            "transform": {"translate": [0, 0, 0], "rotate_deg": [90, 0, 0]},
            "motion": {
                "type": "oscillate",
                "axis": [1, 0, 0],
                "amplitude": 0.0,
                "frequency_hz": 1.0,
            },
        },
        {
            "name": "backdrop",
            "mesh": {"type": "plane", "size": [20, 20]},
            "transform": {"translate": [0, 3, 0], "rotate_deg": [90, 0, 0]},
        },
    ]
    if with_occluder:  # static box in front covering the card's left half (x < 0)
        objs.append(
            {
                "name": "occluder",
                "mesh": {"type": "box", "size": [1.0, 0.2, 2.0]},
                "transform": {"translate": [-0.5, -1.0, 0]},
            }
        )
    return scene_from_dict(
        {
            "name": "quad",
            "num_frames": 3,
            "camera": {
                "fov_deg": 90,
                "trajectory": {"type": "static", "position": [0, -4, 0], "target": [0, 0, 0]},
            },
            "objects": objs,
        }
    )


def test_dynamic_fraction_matches_analytic_area_and_respects_occlusion():
    W, H = 400, 200
    sc = _quad_scene(False)
    # card 1 m x 1 m at distance 4 with fx = W/2 / tan(45 deg) = 200 px: u, v in [175, 225] x [75,
    # 125], so exactly 50 x 50 pixel centres (no edge passes through a centre)
    expected = 50 * 50 / (W * H)
    frac = dynamic_pixel_fraction(sc, W, H, [0, 1])
    np.testing.assert_allclose(frac, expected, rtol=1e-9)
    occ = dynamic_pixel_fraction(_quad_scene(True), W, H, [0])
    np.testing.assert_allclose(occ, expected / 2, rtol=1e-9)


def test_rasterizer_depth_and_near_plane_clipping():
    W, H = 80, 40
    sc = _quad_scene(False)
    ids, depth = rasterize_ids(sc.frame(0, W, H), W, H)
    assert ids[H // 2, W // 2] == 1 and depth[H // 2, W // 2] == pytest.approx(4.0)
    # backdrop plane at y = 3, z-depth 7
    assert ids[2, 2] == 2 and depth[2, 2] == pytest.approx(7.0)
    # a floor plane that passes under and behind the camera is clipped, not dropped or mirrored
    sc2 = scene_from_dict(
        {
            "name": "floor",
            "num_frames": 2,
            "camera": {
                "fov_deg": 90,
                "trajectory": {"type": "static", "position": [0, 0, 1], "target": [0, 5, 1]},
            },
            "objects": [
                {"name": "floor", "mesh": {"type": "plane", "size": [400, 400], "subdivisions": 1}}
            ],
        }
    )
    ids, depth = rasterize_ids(sc2.frame(0, W, H), W, H)
    assert (ids[: H // 2] == 0).all() and (ids[H // 2 :] == 1).all()
    # a floor pixel below the horizon at row v: ray slope (v - cy) / fy, z-depth = height / slope
    v = H - 0.5
    assert depth[H - 1, W // 2] == pytest.approx(1.0 / ((v - H / 2) / (W / 2)), rel=1e-6)
