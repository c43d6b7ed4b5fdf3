"""3DGS .ply export, videos and induced tracks of a tiny hand-built trained run
(m4dgs.outputs.export, m4dgs.outputs.videos)."""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import pytest
import torch

from m4dgs.clip import Cameras, ClipMeta, ClipWriter, Exposures, Split
from m4dgs.core import camera as cam
from m4dgs.core import spline
from m4dgs.core.io import read_npz, write_json
from m4dgs.core.rotation import init_rotation_coeffs
from m4dgs.model.color import ColorMLP
from m4dgs.model.gaussians import WorldGaussians
from m4dgs.model.tonemap import ToneMapper
from m4dgs.model.trained import load_model
from m4dgs.outputs.export import (
    PLY_PROPERTIES,
    SH_C0,
    export_run_ply,
    gaussians_to_ply_arrays,
    ply_arrays_to_gaussians,
    read_ply,
    read_ply_header,
    write_ply,
)
from m4dgs.outputs.videos import exposure_sweep_levels, render_tracks, render_videos, sweep_times
from m4dgs.run import save_torch
from m4dgs.training.stage1 import Background

W, H, G = 33, 25, 9  # odd sizes on purpose (videos must pad to even)
TRAIN = [0, 2, 4, 6, 8]
T = len(TRAIN)
FX = 30.0
FEAT = 36


# --------------------------------------------------------------------------------------------------
# a tiny trained run, built by hand
# --------------------------------------------------------------------------------------------------
def _cameras():
    """Training cameras looking along +z, sliding along x (OpenCV axes, identity rotation)."""
    K = np.array([[FX, 0, W / 2], [0, FX, H / 2], [0, 0, 1]], np.float64)
    c2w = np.stack([np.eye(4) for _ in range(T)])
    c2w[:, 0, 3] = np.linspace(-0.2, 0.2, T)
    return K, c2w


def _gaussians():
    g = torch.Generator().manual_seed(0)
    static_means = torch.tensor([[-0.9, -0.5, 4.0], [0.9, 0.55, 4.5], [0.0, 0.0, 6.0]])
    ns = static_means.shape[0]
    knots = spline.make_knots(T, 4)  # [0, 4]
    nd = 2
    start = torch.tensor([[-0.3, 0.4, 3.5], [0.4, -0.45, 3.8]])
    # [nd, 2, 3]
    ctrl = torch.stack([start, start + torch.tensor([[0.5, 0.0, 0.0], [-0.2, 0.2, 0.3]])], dim=1)
    rotc = init_rotation_coeffs(nd, 3, "paper")
    rotc[:, 1, 1] = 0.4  # a rotation that changes over time
    static = {
        "means": static_means,
        "quats": torch.randn(ns, 4, generator=g),
        "scales": torch.log(
            torch.tensor([[0.08, 0.05, 0.06], [0.07, 0.07, 0.04], [0.3, 0.3, 0.1]])
        ),
        "opacities": torch.logit(torch.tensor([0.95, 0.9, 0.6])),
        "features": torch.randn(ns, FEAT, generator=g),
    }
    dynamic = {
        "ctrl": ctrl,
        "rot": rotc,
        "scales": torch.log(torch.full((nd, 3), 0.05)),
        "opacities": torch.logit(torch.tensor([0.8, 0.7])),
        "features": torch.randn(nd, FEAT, generator=g),
    }
    return WorldGaussians(static, dynamic, knots, T, "exp", 1.0)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return _write_run(tmp_path_factory.mktemp("m4dgs_export"))


def _write_run(root, gain=None, reflected=False):
    """The hand-built run in root/run (its clip in root/clip); `gain` [5, K]: log2 gains over
    time of its Gaussians (beyond the paper), static first; `reflected`: a view-dependent colour
    over the reflected direction with bright specular lobes (beyond the paper). Returns (run
    folder, loaded model)."""
    clip_dir, run_dir = root / "clip", root / "run"
    test = [g for g in range(G) if g not in TRAIN]
    dts = [0.25 if i % 2 == 0 else 2.0 for i in range(T)]
    meta = ClipMeta(
        name="tiny",
        width=W,
        height=H,
        fps=10.0,
        frames=list(range(G)),
        split=Split(TRAIN, test),
        exposures=Exposures(train_dt=dts, observed=[0.25, 2.0], novel=[1.0]),
        crf="hdrnerf",
    )
    cw = ClipWriter(clip_dir, meta)
    for g in TRAIN:
        cw.write_input_ldr(g, np.full((H, W, 3), 128, np.uint8))
    cw.finalize()
    torch.manual_seed(0)
    gauss = _gaussians()
    if gain is not None:
        state = gauss.to_state()
        state["static"]["log2_gain"], state["dynamic"]["log2_gain"] = gain[:3], gain[3:]
        gauss = WorldGaussians.from_state(state)
    color = ColorMLP(FEAT, 36, view_dependent=reflected, direction="reflected", specular=reflected)
    tonemap = {"color_hidden": 36, "tonemap_hidden": 128}
    if reflected:
        with torch.no_grad():
            color.spec.bias[:3] += 6.0  # lobes of amplitude about 2^2, which the export must drop
        tonemap.update(color_view_dependent=True, color_direction="reflected", color_specular=True)
    tm = ToneMapper(hidden=128, generator=torch.Generator().manual_seed(1))
    bg = Background()
    K, c2w = _cameras()
    save_torch(
        run_dir / "model" / "final.pt",
        {
            "gaussians": gauss.to_state(),
            "color": color.state_dict(),
            "tonemap": tm.state_dict(),
            "background": bg.state_dict(),
            "K": torch.tensor(K, dtype=torch.float32),
            "c2w": torch.tensor(c2w, dtype=torch.float32),
            "frames": TRAIN,
            "log2_dt": torch.log2(torch.tensor(dts)),
            "config": {"tonemap": tonemap},
            "variant": "full",
            "feature_dim": FEAT,
        },
    )
    write_json(
        run_dir / "run.json", {"clip": os.path.relpath(clip_dir, run_dir), "variant": "full"}
    )
    allK = np.repeat(K[None], G, 0)
    allc2w = cam.interpolate_trajectory(np.array(TRAIN, float), c2w, np.arange(G, dtype=float))
    write_json(run_dir / "cameras.json", Cameras(np.arange(G), allK, allc2w).to_json())
    model = load_model(run_dir, backend="torch")
    return run_dir, model


# --------------------------------------------------------------------------------------------------
# independent numpy references of the colour MLP and the tone mapper
# --------------------------------------------------------------------------------------------------
def _np_color(model, feats: np.ndarray) -> np.ndarray:
    sd = {k: v.double().numpy() for k, v in model.color.state_dict().items()}
    x = np.concatenate([feats, np.zeros((feats.shape[0], 3))], 1)
    h = np.maximum(x @ sd["fc1.weight"].T + sd["fc1.bias"], 0)
    return 2.0 ** (h @ sd["fc2.weight"].T + sd["fc2.bias"])


def _np_tonemap(model, hdr: np.ndarray, log2_dt: float) -> np.ndarray:
    sd = {k: v.double().numpy() for k, v in model.tm.state_dict().items()}
    z = np.log2(hdr + 1e-6) + log2_dt  # [N, 3]
    pre = z[..., None] * sd["w1"] + sd["b1"]  # [N, 3, D]
    sp = np.logaddexp(0.0, pre)
    out = (sp * sd["w2"]).sum(-1) + sd["b2"]
    return 1.0 / (1.0 + np.exp(-out))


# --------------------------------------------------------------------------------------------------
# PLY
# --------------------------------------------------------------------------------------------------
def test_ply_roundtrip_and_header(tmp_path):
    rng = np.random.default_rng(0)
    n = 17
    means = rng.normal(size=(n, 3))
    quats = rng.normal(size=(n, 4))
    scales = rng.uniform(0.01, 2.0, size=(n, 3))
    opac = rng.uniform(0.01, 0.99, size=n)
    rgb = rng.uniform(0, 1, size=(n, 3))
    arr = gaussians_to_ply_arrays(means, quats, scales, opac, rgb)
    p = write_ply(tmp_path / "g.ply", arr, comments=["m4dgs test"])
    assert not [f for f in os.listdir(tmp_path) if f != "g.ply"], "temporary file left behind"
    back = read_ply(p)
    assert back.shape == (n,) and back.dtype.names == PLY_PROPERTIES
    for k in PLY_PROPERTIES:
        np.testing.assert_array_equal(back[k], arr[k])
    # header text, checked line by line against the standard 3DGS layout
    raw = p.read_bytes()
    head = raw[: raw.index(b"end_header\n") + len(b"end_header\n")].decode("ascii").splitlines()
    expect = (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(45)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )
    assert head[0] == "ply" and head[1] == "format binary_little_endian 1.0"
    assert head[2] == "comment m4dgs test"
    assert head[3] == f"element vertex {n}"
    assert head[4:-1] == [f"property float {e}" for e in expect]
    assert len(raw) == len("\n".join(head)) + 1 + n * 62 * 4
    # the body is plain little-endian float32 in property order
    body = np.frombuffer(raw[len("\n".join(head)) + 1 :], dtype="<f4").reshape(n, 62)
    np.testing.assert_array_equal(body[:, 0:3], means.astype(np.float32))
    np.testing.assert_array_equal(body[:, 3:6], 0)
    np.testing.assert_array_equal(body[:, 9:54], 0)
    h = read_ply_header(p)
    assert h["format"] == "binary_little_endian" and h["elements"][0][:2] == ("vertex", n)


def test_ply_conversions_against_numpy():
    rng = np.random.default_rng(1)
    n = 11
    means = rng.normal(size=(n, 3))
    quats = rng.normal(size=(n, 4))
    scales = rng.uniform(0.001, 3.0, size=(n, 3))
    opac = rng.uniform(0.001, 0.999, size=n)
    rgb = rng.uniform(0, 1, size=(n, 3))
    arr = gaussians_to_ply_arrays(
        torch.tensor(means),
        torch.tensor(quats),
        torch.tensor(scales),
        torch.tensor(opac),
        torch.tensor(rgb),
    )
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    np.testing.assert_allclose(arr["opacity"], f32(np.log(opac / (1 - opac))), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(
        np.stack([arr[f"scale_{i}"] for i in range(3)], 1), f32(np.log(scales)), rtol=1e-6
    )
    qn = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    np.testing.assert_allclose(
        np.stack([arr[f"rot_{i}"] for i in range(4)], 1), f32(qn), rtol=1e-6, atol=1e-7
    )
    back = ply_arrays_to_gaussians(arr)
    np.testing.assert_allclose(back["opacities"], opac, rtol=1e-5)
    np.testing.assert_allclose(back["scales"], scales, rtol=1e-5)
    np.testing.assert_allclose(back["rgb"], rgb, atol=1e-6)


def test_sh_dc_of_known_colour():
    one = np.ones((1, 3))
    rgb = np.array([[1.0, 0.5, 0.0]])
    arr = gaussians_to_ply_arrays(np.zeros((1, 3)), [[1, 0, 0, 0]], one, [0.5], rgb)
    # Y_0^0 = 1 / (2 sqrt(pi)): f_dc = (c - 0.5) * 2 sqrt(pi)
    expect = (rgb[0] - 0.5) * 2.0 * np.sqrt(np.pi)
    got = np.array([arr[f"f_dc_{i}"][0] for i in range(3)])
    np.testing.assert_allclose(got, expect, rtol=1e-6)
    assert SH_C0 == pytest.approx(1.0 / (2.0 * np.sqrt(np.pi)), rel=1e-15)
    assert arr["opacity"][0] == 0.0  # logit(0.5)
    assert arr["scale_0"][0] == 0.0  # log(1)


def test_ply_rejects_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="scales"):
        gaussians_to_ply_arrays(
            np.zeros((2, 3)), np.ones((2, 4)), -np.ones((2, 3)), [0.5, 0.5], np.zeros((2, 3))
        )
    with pytest.raises(ValueError, match="rows"):
        gaussians_to_ply_arrays(
            np.zeros((2, 3)), np.ones((3, 4)), np.ones((2, 3)), [0.5, 0.5], np.zeros((2, 3))
        )


def test_read_ascii_ply(tmp_path):
    p = tmp_path / "a.ply"
    p.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty uchar "
        "red\nend_header\n"
        "1.5 7\n-2 255\n"
    )
    a = read_ply(p)
    np.testing.assert_array_equal(a["x"], [1.5, -2.0])
    np.testing.assert_array_equal(a["red"], [7, 255])


def test_export_run_ply_refuses_a_frame_outside_the_clip_and_a_bad_exposure(run, tmp_path):
    from m4dgs.core.errors import InputError

    run_dir, model = run
    with pytest.raises(InputError, match=r"frame 99 is not a frame of the clip"):
        export_run_ply(run_dir, 99, tmp_path / "x.ply", model=model)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="--exposure must be a finite exposure time > 0"):
            export_run_ply(run_dir, 0, tmp_path / "x.ply", exposure=bad, model=model)
    assert not (tmp_path / "x.ply").exists()


@pytest.mark.parametrize("g,exposure", [(0, None), (8, 0.25), (3, 2.0)])
def test_export_run_ply(run, tmp_path, g, exposure):
    run_dir, model = run
    out = export_run_ply(run_dir, g, tmp_path / f"f{g}.ply", exposure=exposure, model=model)
    arr = read_ply(out)
    gauss = model.gauss
    n = gauss.num_gaussians
    assert arr.shape == (n,)
    t = model.time_of(g)
    assert t == pytest.approx(np.interp(g, TRAIN, np.arange(T)))
    pos = np.stack([arr["x"], arr["y"], arr["z"]], 1)
    np.testing.assert_allclose(pos, gauss.positions(t).detach().numpy(), atol=1e-6)
    ctrl = gauss.dynamic["ctrl"].detach().numpy()
    np.testing.assert_allclose(pos[:3], gauss.static["means"].detach().numpy(), atol=1e-6)
    if t in (0.0, 4.0):  # on a knot the Hermite spline passes through its control point
        np.testing.assert_allclose(pos[3:], ctrl[:, int(t) // 4], atol=1e-6)
    # t = 1.5 on the single segment [0, 4]: Hermite with one-sided (chord) tangents is a straight
    # line
    else:
        np.testing.assert_allclose(
            pos[3:], ctrl[:, 0] + (t / 4) * (ctrl[:, 1] - ctrl[:, 0]), atol=1e-5
        )
    # colours: numpy colour MLP + tone mapper at log2(dt)
    feats = gauss.features().detach().double().numpy()
    ref = np.clip(_np_tonemap(model, _np_color(model, feats), np.log2(exposure or 1.0)), 0, 1)
    rgb = 0.5 + SH_C0 * np.stack([arr[f"f_dc_{i}"] for i in range(3)], 1).astype(np.float64)
    np.testing.assert_allclose(rgb, ref, atol=2e-6)
    np.testing.assert_allclose(
        1 / (1 + np.exp(-arr["opacity"].astype(np.float64))),
        gauss.opacities().detach().numpy(),
        rtol=1e-5,
    )
    # header says what the coordinates are
    comments = read_ply_header(out)["comments"]
    assert any(c.startswith("m4dgs") and "OpenCV" in c for c in comments)


def _np_gain(values: np.ndarray, t: float) -> np.ndarray:
    """log2 gains [N] at time t of knot values [N, K] spread evenly over the T training frames:
    the Catmull-Rom Hermite curve written out in numpy."""
    k = values.shape[1]
    h = (T - 1) / (k - 1)
    slope = np.diff(values, axis=1) / h
    m = np.concatenate([slope[:, :1], 0.5 * (slope[:, 1:] + slope[:, :-1]), slope[:, -1:]], 1)
    i = min(int(t // h), k - 2)
    s = (t - i * h) / h
    h00, h10, h01, h11 = (
        2 * s**3 - 3 * s**2 + 1,
        s**3 - 2 * s**2 + s,
        -2 * s**3 + 3 * s**2,
        s**3 - s**2,
    )
    return h00 * values[:, i] + h10 * h * m[:, i] + h01 * values[:, i + 1] + h11 * h * m[:, i + 1]


@pytest.fixture(scope="module")
def relit_run(tmp_path_factory):
    """The hand-built run with a gain over time (beyond the paper): 3 knots per Gaussian."""
    gain = torch.randn(5, 3, generator=torch.Generator().manual_seed(5))
    return (*_write_run(tmp_path_factory.mktemp("m4dgs_relit"), gain), gain)


def test_a_model_with_a_gain_over_time_loads_renders_and_exports_it(relit_run, tmp_path):
    """Saved and loaded, the gain renders as in memory at a fractional time, and the .ply export
    bakes colour(features) * 2 ** g(t) through the tone mapper (numpy references)."""
    from m4dgs.model.render import render_world

    run_dir, model, gain = relit_run
    assert torch.equal(model.gauss.gain_values(), gain)
    g, t = 3, model.time_of(3)  # a test frame: t = 1.5
    assert t == pytest.approx(1.5)
    K, c2w = model.camera(g)
    kept = _gaussians()
    state = kept.to_state()
    state["static"]["log2_gain"], state["dynamic"]["log2_gain"] = gain[:3], gain[3:]
    with torch.no_grad():
        want = render_world(
            WorldGaussians.from_state(state), model.color, model.bg, t,
            torch.tensor(c2w, dtype=torch.float32), torch.tensor(K, dtype=torch.float32),
            W, H, "torch",
        ).hdr  # fmt: skip
    torch.testing.assert_close(model.render(t, c2w, K)["hdr"], want, rtol=0, atol=0)
    out = export_run_ply(run_dir, g, tmp_path / "relit.ply", model=model)
    arr = read_ply(out)
    feats = model.gauss.features().detach().double().numpy()
    hdr = _np_color(model, feats) * 2.0 ** _np_gain(gain.double().numpy(), t)[:, None]
    ref = np.clip(_np_tonemap(model, hdr, 0.0), 0, 1)
    rgb = 0.5 + SH_C0 * np.stack([arr[f"f_dc_{i}"] for i in range(3)], 1).astype(np.float64)
    np.testing.assert_allclose(rgb, ref, atol=2e-6)
    # and not what the model without the gain exports
    plain = np.clip(_np_tonemap(model, _np_color(model, feats), 0.0), 0, 1)
    assert np.abs(rgb - plain).max() > 1e-2


def test_a_view_dependent_colour_exports_its_direction_free_colour(tmp_path):
    """A run whose colour depends on the reflected direction and has specular lobes: the .ply
    (view-independent) bakes the colour at the zero direction, as stage 1 trains it, without the
    lobes (numpy reference), not the colour a camera of the clip sees."""
    from m4dgs.model.color import color_directions

    run_dir, model = _write_run(tmp_path, reflected=True)
    assert model.color.view_dependent and model.color.specular
    g = 2
    t = model.time_of(g)
    gauss, feats = model.gauss, model.gauss.features().detach()
    _, c2w = model.camera(g)
    with torch.no_grad():
        dirs = color_directions(
            model.color, gauss.positions(t), gauss.quats(t), gauss.scales(),
            torch.tensor(c2w[:3, 3], dtype=torch.float32),
        )  # fmt: skip
        seen, free = model.color(feats, dirs), model.color(feats)
    assert (seen / free).max() > 1.5  # the camera's colour (lobes included) is another
    out = export_run_ply(run_dir, g, tmp_path / "refl.ply", model=model)
    arr = read_ply(out)
    ref = np.clip(_np_tonemap(model, _np_color(model, feats.double().numpy()), 0.0), 0, 1)
    rgb = 0.5 + SH_C0 * np.stack([arr[f"f_dc_{i}"] for i in range(3)], 1).astype(np.float64)
    np.testing.assert_allclose(rgb, ref, atol=2e-6)


def test_export_cli(run, tmp_path):
    from click.testing import CliRunner

    from m4dgs.cli import main

    run_dir, _ = run
    out = tmp_path / "cli.ply"
    res = CliRunner().invoke(main, ["export-ply", str(run_dir), "--frame", "2", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert read_ply(out).shape == (5,)


# --------------------------------------------------------------------------------------------------
# videos and tracks
# --------------------------------------------------------------------------------------------------
def _count_frames(path):
    """Decode with OpenCV's own ffmpeg build (independent of the imageio-ffmpeg writer)."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    n, shape = 0, None
    while True:
        ok, fr = cap.read()
        if not ok:
            break
        n += 1
        shape = fr.shape
    cap.release()
    return n, shape


def test_sweeps():
    np.testing.assert_allclose(sweep_times(5, 2), [0, 0.5, 1, 1.5, 2, 2.5, 3, 3.5, 4])
    np.testing.assert_allclose(sweep_times(1, 3), [0])


def test_render_videos(run, tmp_path):
    run_dir, model = run
    paths = render_videos(
        run_dir, model=model, out_dir=tmp_path / "v", progress=False, substeps=2, ev_steps=2
    )
    assert [p.name for p in paths] == [
        "fix_view_change_time.mp4",
        "fix_time_change_view.mp4",
        "exposure_sweep.mp4",
    ]
    levels = exposure_sweep_levels(model, 2.0, 2)
    # observed levels 0.25 and 2 -> log2 dt from -2 - 2 to 1 + 2, 2 samples per stop
    np.testing.assert_allclose(levels, np.linspace(-4, 3, 15))
    ev = lambda x: x + x % 2  # noqa: E731  (padded to even sizes)
    # LDR | HDR side by side
    expect = {
        "fix_view_change_time.mp4": ((T - 1) * 2 + 1, (ev(H), ev(2 * W))),
        "fix_time_change_view.mp4": ((T - 1) * 2 + 1, (ev(H), ev(2 * W))),
        "exposure_sweep.mp4": (15, (ev(H), ev(W))),
    }
    for p in paths:
        assert p.exists() and p.stat().st_size > 0
        n, shape = _count_frames(p)
        assert n == expect[p.name][0], p.name
        assert shape[:2] == expect[p.name][1], p.name
    assert sorted(os.listdir(tmp_path / "v")) == sorted(expect), "temporary files left behind"


def test_render_tracks(run, tmp_path):
    run_dir, model = run
    K, c2w0 = model.camera(TRAIN[0])
    p_static = model.gauss.static["means"][0].detach().double().numpy()  # alone in its image region
    uv0 = cam.project_pinhole(cam.transform_points(cam.invert_rigid(c2w0), p_static), K)
    paths = render_tracks(
        run_dir, model=model, out_dir=tmp_path / "tr", query_uv=uv0[None], progress=False
    )
    assert [p.name for p in paths] == [
        "tracks_2d.mp4",
        "tracks_2d.npz",
        "tracks_3d.npz",
        "tracks_3d.png",
    ]
    for p in paths:
        assert p.exists() and p.stat().st_size > 0
    d2 = read_npz(paths[1])
    assert d2["tracks"].shape == (1, T, 2)
    np.testing.assert_array_equal(d2["frames"], TRAIN)
    assert d2["query_alpha"][0] > 0.5
    # a static Gaussian's induced track is its projection in every estimated camera
    for f, g in enumerate(TRAIN):
        Kg, c2w = model.camera(g)
        uv = cam.project_pinhole(cam.transform_points(cam.invert_rigid(c2w), p_static), Kg)
        np.testing.assert_allclose(d2["tracks"][0, f], uv, atol=2e-3)
    # the camera moved: the track is not constant
    assert abs(d2["tracks"][0, -1, 0] - d2["tracks"][0, 0, 0]) > 1.0
    n, shape = _count_frames(paths[0])
    assert n == T and shape[0] % 2 == 0 and shape[1] % 2 == 0
    d3 = read_npz(paths[2])
    assert d3["tracks"].shape == (2, T, 3)
    ctrl = model.gauss.dynamic["ctrl"].detach().numpy()
    np.testing.assert_allclose(d3["tracks"][:, 0], ctrl[:, 0], atol=1e-6)
    np.testing.assert_allclose(d3["tracks"][:, -1], ctrl[:, -1], atol=1e-6)
    # straight segment
    np.testing.assert_allclose(d3["tracks"][:, 2], 0.5 * (ctrl[:, 0] + ctrl[:, 1]), atol=1e-5)
    from PIL import Image

    with Image.open(paths[3]) as im:
        assert im.size[0] > 100 and im.size[1] > 100


def test_render_tracks_default_grid(run, tmp_path):
    run_dir, model = run
    paths = render_tracks(
        run_dir, model=model, out_dir=tmp_path / "tg", grid_step=1, progress=False
    )
    d2 = read_npz(paths[1])
    n = d2["queries"].shape[0]
    # only pixels on the (sparse) scene are queried
    assert d2["tracks"].shape == (n, T, 2) and 1 <= n < W * H
    assert (d2["query_alpha"] >= 0.5).all()
    assert np.isfinite(d2["tracks"]).all()
    # every query is a pixel centre; the pixel under the first static Gaussian's centre is among
    # them
    np.testing.assert_array_equal(d2["queries"] % 1, 0.5)
    K, c2w0 = model.camera(TRAIN[0])
    p = model.gauss.static["means"][0].detach().double().numpy()
    uv = cam.project_pinhole(cam.transform_points(cam.invert_rigid(c2w0), p), K)
    assert (np.abs(d2["queries"] - (np.floor(uv) + 0.5)).max(1) == 0).any()
    # zero queries (min_alpha above 1) still writes valid, empty outputs
    paths = render_tracks(
        run_dir, model=model, out_dir=tmp_path / "te", grid_step=8, min_alpha=1.1, progress=False
    )
    assert read_npz(paths[1])["tracks"].shape == (0, T, 2)
    assert _count_frames(paths[0])[0] == T


def test_write_mp4_atomic_on_failure(tmp_path):
    from m4dgs.core.video import write_mp4

    def frames():
        yield np.zeros((10, 12, 3), np.uint8)
        raise RuntimeError("render failed")

    with pytest.raises(RuntimeError, match="render failed"):
        write_mp4(tmp_path / "x.mp4", frames(), 5)
    assert os.listdir(tmp_path) == []
    p = write_mp4(tmp_path / "y.mp4", (np.full((9, 11, 3), 40 * i, np.uint8) for i in range(4)), 5)
    n, shape = _count_frames(p)
    assert n == 4 and shape[:2] == (10, 12) and os.listdir(tmp_path) == ["y.mp4"]
