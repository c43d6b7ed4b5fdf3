"""Tests of the eval command: score_run on a fake run, suites, job lists, tables and figures (fast,
fakes only).

The trainer API (m4dgs.training.pipeline / m4dgs.outputs.render / m4dgs.model.trained) is replaced
by fake modules in sys.modules; every expected value is computed independently here with numpy
(PSNR, mu-law, analytic HDR-TAE of a flicker, ...)."""

from __future__ import annotations

import json
import math
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from eval.cli import main
from m4dgs.clip import (
    Cameras,
    Clip,
    ClipMeta,
    ClipWriter,
    Exposures,
    FlowSet,
    Split,
    TrackSet,
    frame_name,
    level_name,
)
from m4dgs.core import io as mio
from m4dgs.core.crf import get_crf, tonemap_ldr

W, H, G = 48, 40, 7
OBS, NOV = [0.5, 2.0], [1.0]
# training-frame HDR renders alternate between x1 and x1.2 -> HDR-TAE = 3 (r - 1) / (r + 1)
FLICKER = 1.2
TRACK_OFFSET = (0.3, 0.4)  # fake induced tracks = gt + this -> EPE 0.5 px


def _rot(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _hdr(rng, g):
    y, x = np.mgrid[0:H, 0:W] / 10.0
    base = np.stack([1 + np.sin(x + 0.3 * g), 1 + np.cos(y), 1 + np.sin(x * y / 3)], -1) * 0.8
    return (base + 0.05 * rng.random((H, W, 3))).astype(np.float32)


def make_fake_clip(root: Path, seed: int = 0) -> Clip:
    rng = np.random.default_rng(seed)
    train, test = list(range(0, G, 2)), list(range(1, G, 2))
    train_dt = [OBS[i % 2] for i in range(len(train))]
    meta = ClipMeta(
        name=root.name,
        width=W,
        height=H,
        fps=10.0,
        frames=list(range(G)),
        split=Split(train, test),
        exposures=Exposures(train_dt=train_dt, observed=OBS, novel=NOV),
        crf="hdrnerf",
    )
    w = ClipWriter(root, meta)
    crf = get_crf("hdrnerf")
    base = _hdr(rng, 0)
    for g in range(G):
        # static training frames: the flicker test needs zero motion
        hdr = base if g in train else _hdr(rng, g)
        w.write_gt_hdr(g, hdr)
        w.write_gt_depth(g, (2.0 + rng.random((H, W))).astype(np.float32))
        mask = np.zeros((H, W), bool)
        mask[10:20, 10 + g : 25 + g] = True
        w.write_gt_dynamic_mask(g, mask)
    for g, dt in zip(train, train_dt):
        w.write_input_ldr(g, tonemap_ldr(base, dt, crf))
        w.write_prior_depth(g, np.ones((H, W), np.float32))
    for g in test:
        for lv in OBS + NOV:
            w.write_gt_ldr(
                lv, g, tonemap_ldr(mio.read_exr(root / "gt/hdr" / frame_name(g, "exr")), lv, crf)
            )
    K = np.array([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]])
    c2w = np.stack(
        [
            np.block(
                [
                    [_rot(0.1 * g), np.array([[0.2 * g], [0.05 * g * g], [0.1]])],
                    [np.zeros((1, 3)), np.ones((1, 1))],
                ]
            )
            for g in range(G)
        ]
    )
    w.write_gt_cameras(Cameras(np.arange(G), np.repeat(K[None], G, 0), c2w))
    pairs = [(a, b) for a, b in zip(train[:-1], train[1:])] + [
        (b, a) for a, b in zip(train[:-1], train[1:])
    ]
    w.write_gt_flow(
        FlowSet(
            np.array(pairs),
            np.zeros((len(pairs), H, W, 2), np.float32),
            np.ones((len(pairs), H, W), bool),
        )
    )
    n = 40
    tr = rng.uniform([2, 2], [W - 2, H - 2], size=(n, 1, 2)) + np.arange(G)[None, :, None] * 0.5
    vis = np.ones((n, G), bool)
    vis[:5, 0] = False  # not visible at the first frame: never sampled
    w.write_gt_tracks(TrackSet(tr.astype(np.float32), vis, np.arange(G), dynamic=np.zeros(n, bool)))
    w.write_prior_tracks(TrackSet(tr[:, train].astype(np.float32), vis[:, train], np.array(train)))
    w.finalize()
    return Clip.open(root)


def make_fake_run(
    run_dir: Path,
    clip: Clip,
    noise: float = 0.02,
    seed: int = 1,
    renders: bool = True,
    hdr_gain: float = 1.0,
    variant: str = "full",
) -> dict:
    """A finished run: run.json, status, log.jsonl, cameras (a Sim(3) copy of the gt), renders
    (noisy gt)."""
    rng = np.random.default_rng(seed)
    run_dir.mkdir(parents=True, exist_ok=True)
    mio.write_json(
        run_dir / "run.json",
        {
            "clip": str(clip.root),
            "variant": variant,
            "preset": "tiny",
            "train_seconds": 120.0,
            "num_gaussians": 1000,
            "peak_memory_mib": 321.0,
        },
    )
    mio.write_json(run_dir / "status.json", {"stage": "done", "step": 0})
    with open(run_dir / "log.jsonl", "w") as f:
        for st, n in (("stage1", 5), ("stage2", 5)):
            for s in range(n):
                f.write(
                    json.dumps(
                        {
                            "stage": st,
                            "step": s * 10,
                            "total": 1.0 / (s + 1),
                            "rgb": 0.5 / (s + 1),
                            "depth": 0.1 + 0.01 * s,
                            "num_gaussians": 100,
                            "sec": 0.1,
                        }
                    )
                    + "\n"
                )
    gt = clip.load_gt_cameras()
    s, R, t = 2.0, _rot(0.7), np.array([1.0, -2.0, 0.5])
    c2w = gt.c2w.copy()
    c2w[:, :3, :3] = R @ gt.c2w[:, :3, :3]
    c2w[:, :3, 3] = s * gt.c2w[:, :3, 3] @ R.T + t
    mio.write_json(run_dir / "cameras.json", Cameras(gt.frames, gt.K, c2w).to_json())
    truth = {"ldr": {}, "hdr": {}}
    if not renders:
        return truth
    write_renders(run_dir, clip, noise, rng, hdr_gain, truth)
    return truth


def write_renders(run_dir, clip, noise, rng, hdr_gain, truth):
    Rr = Path(run_dir) / "renders"
    for i, g in enumerate(clip.train_frames):
        h = clip.load_gt_hdr(g) * (FLICKER if i % 2 else 1.0)
        mio.write_exr(Rr / "train/hdr" / frame_name(g, "exr"), h.astype(np.float32))
        mio.write_png(Rr / "train/ldr" / frame_name(g, "png"), clip.load_ldr(g))
    for g in clip.test_frames:
        h = (clip.load_gt_hdr(g) * hdr_gain * (1 + noise * rng.standard_normal((H, W, 3)))).astype(
            np.float32
        )
        h = np.maximum(h, 0)
        mio.write_exr(Rr / "test/hdr" / frame_name(g, "exr"), h)
        truth["hdr"][g] = h
        mio.write_exr(
            Rr / "test/depth" / frame_name(g, "exr"),
            (2.5 * clip.load_gt_depth(g)).astype(np.float32),
        )
        for lv in OBS + NOV:
            gt = clip.load_gt_ldr(lv, g).astype(np.int32)
            p = np.clip(gt + rng.integers(-6, 7, gt.shape), 0, 255).astype(np.uint8)
            mio.write_png(Rr / "test/ldr" / level_name(lv) / frame_name(g, "png"), p)
            truth["ldr"][(lv, g)] = p


class FakeModel:
    """The TrainedModel interface (API.md) with known answers: the true CRF, gt tracks + a fixed
    offset."""

    def __init__(self, clip):
        self.clip = clip
        self.width, self.height, self.num_gaussians = clip.width, clip.height, 1000
        self.calls = 0

    def time_of(self, g):
        return g / 10.0

    def camera(self, g):
        cams = self.clip.load_gt_cameras()
        return cams.K[g], cams.c2w[g]

    def render(self, t, c2w, K, width, height, log2_dt=None):
        self.calls += 1
        return {
            "hdr": torch.zeros(height, width, 3),
            "ldr": None,
            "depth": torch.zeros(height, width),
            "alpha": torch.zeros(height, width),
        }

    def tonemap_curve(self, log2_x):
        y = get_crf("hdrnerf")(torch.exp2(log2_x.double()))
        return y[:, None].repeat(1, 3)

    def track_2d(self, uv, g0, frames):
        ts = self.clip.load_gt_tracks()
        uv = np.asarray(uv)
        idx = [int(np.argmin(np.abs(ts.tracks[:, g0] - u).sum(-1))) for u in uv]
        return torch.tensor(ts.tracks[idx][:, list(frames)] + np.array(TRACK_OFFSET))


@pytest.fixture
def fake_trainer(monkeypatch):
    """Fake m4dgs.model.trained / m4dgs.outputs.render / m4dgs.training.pipeline modules; returns a
    dict recording the calls."""
    calls = {"render_run": [], "train": []}
    mod = types.ModuleType("m4dgs.model.trained")
    mod.load_model = lambda run_dir, device="cpu": FakeModel(
        Clip.open(mio.read_json(Path(run_dir) / "run.json")["clip"])
    )
    rmod = types.ModuleType("m4dgs.outputs.render")

    def render_run(run_dir, overwrite=False, progress=True):
        calls["render_run"].append(str(run_dir))
        clip = Clip.open(mio.read_json(Path(run_dir) / "run.json")["clip"])
        write_renders(run_dir, clip, 0.02, np.random.default_rng(5), 1.0, {"ldr": {}, "hdr": {}})
        return {}

    rmod.render_run = render_run
    pmod = types.ModuleType("m4dgs.training.pipeline")

    def train(
        clip_dir,
        run_dir,
        preset="small",
        variant="full",
        overrides=None,
        device="auto",
        progress=True,
        share_dir=None,
    ):
        calls["train"].append((str(run_dir), variant, overrides))
        calls.setdefault("share_dir", []).append(share_dir)
        run_dir = Path(run_dir)
        make_fake_run(run_dir, Clip.open(clip_dir), seed=len(calls["train"]), variant=variant)
        return run_dir

    pmod.train = train
    monkeypatch.setitem(sys.modules, "m4dgs.model.trained", mod)
    monkeypatch.setitem(sys.modules, "m4dgs.outputs.render", rmod)
    monkeypatch.setitem(sys.modules, "m4dgs.training.pipeline", pmod)
    return calls


# --------------------------------------------------------------------------------------------------
def _psnr_np(p, g):
    mse = np.mean((p.astype(np.float64) / 255 - g.astype(np.float64) / 255) ** 2)
    return 10 * np.log10(1 / mse)


def _mu_np(x):
    return np.log1p(5000 * x) / np.log1p(5000)


def test_score_run_values(tmp_path, fake_trainer):
    from eval.experiments.score import METRIC_KEYS, score_run

    clip = make_fake_clip(tmp_path / "clip")
    run = tmp_path / "run"
    truth = make_fake_run(run, clip)
    m = score_run(run, fps=True)
    assert fake_trainer["render_run"] == []  # nothing was missing
    on_disk = json.loads((run / "metrics.json").read_text())
    assert set(METRIC_KEYS) <= set(on_disk) and on_disk["ldr_oe_psnr"] == pytest.approx(
        m["ldr_oe_psnr"]
    )
    # LDR: per image PSNR (numpy), mean over frames then levels
    exp = {
        lv: np.mean(
            [_psnr_np(truth["ldr"][(lv, g)], clip.load_gt_ldr(lv, g)) for g in clip.test_frames]
        )
        for lv in OBS + NOV
    }
    assert m["ldr_oe_psnr"] == pytest.approx(np.mean([exp[lv] for lv in OBS]), abs=1e-9)
    assert m["ldr_ne_psnr"] == pytest.approx(exp[1.0], abs=1e-9)
    assert m["per_level"]["0.5"]["psnr"] == pytest.approx(exp[0.5], abs=1e-9)
    assert m["per_level"]["1"]["kind"] == "novel"
    # HDR mu-law with the GT max
    hp = []
    for g in clip.test_frames:
        gt = clip.load_gt_hdr(g).astype(np.float64)
        s = gt.max()
        hp.append(
            10
            * np.log10(
                1 / np.mean((_mu_np(np.clip(truth["hdr"][g] / s, 0, 1)) - _mu_np(gt / s)) ** 2)
            )
        )
    assert m["hdr_psnr"] == pytest.approx(np.mean(hp), abs=1e-6)
    # HDR-TAE of a global flicker with zero flow: 3 |r - 1| / (r + 1)
    assert m["hdr_tae"] == pytest.approx(3 * (FLICKER - 1) / (FLICKER + 1), rel=1e-5)
    # the ground truth's training frames do not change, so all of that change is an error
    assert m["hdr_tce"] == pytest.approx(3 * (FLICKER - 1) / (FLICKER + 1), rel=1e-5)
    # training LDR renders equal the input: capped PSNR, SSIM 1
    assert m["ldr_train_psnr"] == 100.0 and m["ldr_train_ssim"] == pytest.approx(1.0, abs=1e-6)
    # cameras are a Sim(3) copy of the gt; depth a scaled copy; tracks offset by 0.5 px; the true
    # CRF
    assert m["ate"] == pytest.approx(0, abs=1e-6) and m["rpe_rot"] == pytest.approx(0, abs=1e-3)
    assert m["ate_ba"] is None  # no cameras_ba.json
    assert m["depth_absrel"] == pytest.approx(0, abs=1e-6)
    assert m["track_epe"] == pytest.approx(0.5, abs=1e-5) and m["track_delta_avg"] == pytest.approx(
        1.0
    )
    assert m["track_epe_median"] == pytest.approx(0.5, abs=1e-5)
    assert m["crf_rmse"] == pytest.approx(0, abs=1e-6)
    # 8-bit codes
    assert m["crf_error"] == pytest.approx(0, abs=1e-3) and "crf_error" in m["conventions"]
    assert all(r is not None and r[0] < 1 < r[1] for r in m["crf_error_detail"]["ranges"])
    # no LPIPS weights -> None; run.json values; FPS measured; conventions present
    assert m["ldr_oe_lpips"] is None and m["hdr_lpips"] is None and "lpips_na" in m["conventions"]
    assert m["train_minutes"] == pytest.approx(2.0) and m["peak_memory_mib"] == 321.0
    assert m["fps"] > 0 and m["fps_864x480"] > 0
    assert "hdr_mu_law" in m["conventions"] and "hdr_tae_gt_flow" in m["conventions"]
    assert m["options"]["roundtrip"] is None and m["hdr_flip"] is None
    assert m["dyn_hdr_psnr"] is not None and m["dyn_ldr_psnr"] is not None


def test_score_dynamic_mask_metrics(tmp_path, fake_trainer):
    """Epipolar masks vs gt: the fake gt mask of frame g is rows 10:20, columns 10+g:25+g; the run's
    mask is the same box shifted 3 columns right, so precision = recall = 12/15 and IoU = 12/18
    (analytic)."""
    from eval.experiments.score import score_run

    clip = make_fake_clip(tmp_path / "clip")
    run = tmp_path / "run"
    make_fake_run(run, clip)
    m = score_run(run, fps=False, model=False)
    assert m["mask_iou"] is None and "dyn_masks" not in m["conventions"]  # no camera_init.pt
    masks = torch.zeros(len(clip.train_frames), H, W, dtype=torch.bool)
    for i, g in enumerate(clip.train_frames):
        masks[i, 10:20, 13 + g : 28 + g] = True
    (run / "model").mkdir()
    torch.save({"masks": masks}, run / "model" / "camera_init.pt")
    m = score_run(run, fps=False, model=False)
    assert m["mask_precision"] == pytest.approx(0.8) and m["mask_recall"] == pytest.approx(0.8)
    assert m["mask_iou"] == pytest.approx(2 / 3) and "dyn_masks" in m["conventions"]
    torch.save({"masks": masks[1:]}, run / "model" / "camera_init.pt")
    with pytest.raises(ValueError, match="camera_init.pt: 'masks' has"):
        score_run(run, fps=False, model=False)


def test_score_renders_missing_and_identical(tmp_path, fake_trainer):
    from eval.experiments.score import PSNR_CAP_DB, score_run

    clip = make_fake_clip(tmp_path / "clip")
    run = tmp_path / "run"
    make_fake_run(run, clip, renders=False)
    m = score_run(run, fps=False, model=False)
    assert fake_trainer["render_run"] == [str(run)]  # rendered what was missing
    assert (
        m["track_epe"] is None
        and m["fps"] is None
        and m["crf_rmse"] is None
        and m["crf_error"] is None
    )
    # identical HDR renders: PSNR capped, not inf, and valid JSON
    for g in clip.test_frames:
        mio.write_exr(run / "renders/test/hdr" / frame_name(g, "exr"), clip.load_gt_hdr(g))
    m = score_run(run, fps=False, model=False)
    assert m["hdr_psnr"] == PSNR_CAP_DB
    json.loads(
        (run / "metrics.json").read_text(),
        parse_constant=lambda c: pytest.fail(f"non-standard JSON {c}"),
    )


def test_score_refuses_non_finite_renders(tmp_path, fake_trainer):
    """A NaN in one test render stops scoring with the file named, instead of a mean over the
    finite frames."""
    from eval.experiments.score import score_run
    from m4dgs.core.errors import NonFiniteError

    clip = make_fake_clip(tmp_path / "clip")
    run = tmp_path / "run"
    make_fake_run(run, clip)
    g = clip.test_frames[0]
    bad = clip.load_gt_hdr(g).copy()
    bad[3, 4, 1] = np.nan
    path = run / "renders/test/hdr" / frame_name(g, "exr")
    mio.write_exr(path, bad)
    with pytest.raises(NonFiniteError, match=rf"{frame_name(g, 'exr')}: 1 of \d+ values are NaN"):
        score_run(run, fps=False, model=False)
    assert not (run / "metrics.json").exists()


def test_score_refuses_a_read_only_run_folder_up_front(tmp_path, fake_trainer, monkeypatch):
    """A run folder that cannot take metrics.json is refused before any metric is computed (the
    permission test is replaced: CI runs as root, who may write anywhere)."""
    import eval.experiments.score as score_mod
    from m4dgs.core.errors import InputError

    clip = make_fake_clip(tmp_path / "clip")
    run = tmp_path / "run"
    make_fake_run(run, clip)
    monkeypatch.setattr(score_mod.os, "access", lambda p, mode: False)
    real_ensure = score_mod.ensure_renders
    monkeypatch.setattr(score_mod, "ensure_renders", lambda *a, **k: pytest.fail("scored on"))
    with pytest.raises(InputError, match="read-only; metrics.json cannot be written"):
        score_mod.score_run(run, fps=False, model=False)
    # only when writing
    monkeypatch.setattr(score_mod, "ensure_renders", real_ensure)
    assert score_mod.score_run(run, fps=False, model=False, write=False)["ldr_oe_psnr"] is not None


def test_cli_score(tmp_path, fake_trainer):
    clip = make_fake_clip(tmp_path / "clip")
    run = tmp_path / "run"
    make_fake_run(run, clip)
    r = CliRunner().invoke(main, ["score", str(run), "--no-fps", "--roundtrip", "jpeg"])
    assert r.exit_code == 0, r.output
    head = json.loads(r.output.strip().splitlines()[-1])
    assert head["ldr_oe_psnr"] > 20
    m = json.loads((run / "metrics.json").read_text())
    assert m["options"]["roundtrip"] == "jpeg" and "ldr_jpeg" in m["conventions"]
    r2 = CliRunner().invoke(main, ["score", str(run)])
    assert r2.exit_code == 0 and "exists" in r2.output


def test_score_add_missing_fills_only_what_an_older_metrics_json_lacks(tmp_path, fake_trainer):
    clip = make_fake_clip(tmp_path / "clip")
    run = tmp_path / "run"
    make_fake_run(run, clip)
    r = CliRunner().invoke(main, ["score", str(run), "--no-fps"])
    assert r.exit_code == 0, r.output
    full = json.loads((run / "metrics.json").read_text())
    # as an earlier version wrote it: no hdr_tce, and a marker value that must survive
    old = {k: v for k, v in full.items() if k != "hdr_tce"}
    old["conventions"] = {k: v for k, v in full["conventions"].items() if k != "hdr_tce"}
    old["ldr_oe_psnr"] = 12.5
    (run / "metrics.json").write_text(json.dumps(old))
    r = CliRunner().invoke(main, ["score", str(run), "--add-missing"])
    assert r.exit_code == 0 and "added hdr_tce" in r.output, r.output
    new = json.loads((run / "metrics.json").read_text())
    assert new["hdr_tce"] == pytest.approx(full["hdr_tce"], rel=1e-12)
    assert new["conventions"]["hdr_tce"] == full["conventions"]["hdr_tce"]
    assert new["ldr_oe_psnr"] == 12.5  # nothing else recomputed
    assert {k: v for k, v in new.items() if k not in ("hdr_tce", "conventions")} == {
        k: v for k, v in old.items() if k != "conventions"
    }
    r = CliRunner().invoke(main, ["score", str(run), "--add-missing"])
    assert r.exit_code == 0 and "nothing missing" in r.output
    r = CliRunner().invoke(main, ["score", str(run), "--add-missing", "--force"])
    assert r.exit_code == 2 and "exclude each other" in r.output
    r = CliRunner().invoke(main, ["score", str(tmp_path / "clip"), "--add-missing"])
    assert r.exit_code == 1 and "no metrics.json to add to" in r.output


# --------------------------------------------------------------------------------------------------
def test_suites_load_and_variants():
    from eval.records.suite import (
        LAYOUTS,
        builtin_suites,
        known_variants,
        load_eval_suite,
        metric_columns,
    )

    names = builtin_suites()
    assert {
        "paper-main",
        "paper-ablation",
        "control-points",
        "exposure-schedules",
        "exposure-noise",
        "priors",
        "tiny",
    } <= set(names)
    known = known_variants()
    reg = metric_columns()
    for n in names:
        s = load_eval_suite(n)
        assert s.rows and s.tables
        for t in s.tables:
            keys = LAYOUTS[t.columns] if isinstance(t.columns, str) else t.columns
            assert all(k in reg for k in keys)
        if known is not None:
            assert set(s.variants) <= set(known), (n, set(s.variants) - set(known))
        # every shipped suite reads its rows against the 2D rows, on its reference row's clips
        ref = next(r for r in s.rows if r.name == (s.reference or "full"))
        cal = {r.calibration: r.clip for r in s.rows if r.calibration is not None}
        assert {"copy-nearest", "flow-merge"} <= set(cal), n
        assert set(cal.values()) == {ref.clip}, n

    def trained(suite):
        return [r for r in suite.rows if r.calibration is None]

    abl = load_eval_suite("paper-ablation")
    assert [r.variant for r in trained(abl)] == [
        "no-video-init",
        "no-occlusion",
        "no-cov-invariance",
        "no-reproj",
        "no-tlr",
        "full",
    ]
    cp = load_eval_suite("control-points")
    assert [r.variant for r in trained(cp)] == [f"ns-{k}" for k in (1, 2, 4, 8, 16)]
    noise = load_eval_suite("exposure-noise")
    assert sorted(r.overrides.get("exposure.perturb_ev", 0.0) for r in trained(noise)) == [
        0.0,
        0.25,
        0.5,
        0.75,
    ]
    sched = load_eval_suite("exposure-schedules")
    assert {c.schedule or "alternating" for c in sched.clips.values()} == {
        "alternating",
        "random-order",
        "random-values",
    }
    pri = load_eval_suite("priors")
    assert {c.priors for c in pri.clips.values()} == {"oracle", "realistic", "harsh"}
    assert {"no-depth-loss", "no-track-loss"} <= set(pri.variants)


def test_suite_errors(tmp_path):
    from eval.records.suite import SuiteError, parse_suite

    base = {"name": "x", "scenes": "tiny", "rows": [{"variant": "full"}]}
    assert parse_suite(base).rows[0].name == "full"
    with pytest.raises(SuiteError, match="rows\\[0\\].clip"):
        parse_suite({**base, "rows": [{"variant": "full", "clip": "nope"}]})
    with pytest.raises(SuiteError, match="clips.a.schedule"):
        parse_suite({**base, "clips": {"a": {"schedule": "weekly"}}})
    with pytest.raises(SuiteError, match="duplicate"):
        parse_suite({**base, "rows": [{"variant": "full"}, {"variant": "full"}]})
    with pytest.raises(SuiteError, match="unknown layout"):
        parse_suite({**base, "tables": [{"columns": "nope"}]})


def test_list_jobs(tmp_path):
    from eval.records.suite import load_eval_suite, scene_suite_names

    r = CliRunner().invoke(
        main,
        ["run", "exposure-schedules", "--out", str(tmp_path), "--preset", "tiny", "--list-jobs"],
    )
    assert r.exit_code == 0, r.output
    lines = [json.loads(x) for x in r.output.strip().splitlines()]
    s = load_eval_suite("exposure-schedules")
    assert len(lines) == len(s.rows) * len(scene_suite_names(s))
    assert all(x["cmd"].startswith("python -m eval job exposure-schedules ") for x in lines)
    assert {x["setting_id"] for x in lines} == {
        "syn-exp-3",
        "syn-exp-3-random-order",
        "syn-exp-3-random-values",
    }
    assert len({x["run_dir"] for x in lines}) == len(lines)
    x = lines[0]
    assert x["clip_dir"] == str(tmp_path.resolve() / "clips" / x["setting_id"] / x["scene"])
    assert x["run_dir"] == str(
        tmp_path.resolve() / "runs" / "exposure-schedules" / x["scene"] / x["row"]
    )


# --------------------------------------------------------------------------------------------------
SUITE_YAML = """name: t2
description: test suite
scenes: tiny
rows:
  - {name: base, label: "Baseline", variant: world-only}
  - {name: full, label: "Ours", variant: full, overrides: {exposure.perturb_ev: 0.0}}
tables:
  - {title: "Main", columns: paper}
  - {title: "Geo", columns: [ate, depth_absrel]}
"""


def test_run_suite_resumable_and_table(tmp_path, fake_trainer):
    from eval.experiments.runner import job_list, run_suite

    suite = tmp_path / "t2.yaml"
    suite.write_text(SUITE_YAML)
    out = tmp_path / "exp"
    jl = job_list(suite, out, "tiny")
    assert len(jl) == 4
    for j in {j.clip_dir for j in jl}:  # clips exist already: the runner must not regenerate them
        make_fake_clip(Path(j), seed=len(j))
    res = run_suite(suite, out, "tiny", score_kw={"fps": False}, progress=False, log=lambda s: None)
    assert [r["steps"] for r in res] == [["train", "score"]] * 4
    assert ("full" in fake_trainer["train"][1][0]) and fake_trainer["train"][1][2] == {
        "exposure.perturb_ev": 0.0
    }
    res2 = run_suite(
        suite, out, "tiny", score_kw={"fps": False}, progress=False, log=lambda s: None
    )
    assert [r["steps"] for r in res2] == [[]] * 4 and len(fake_trainer["train"]) == 4

    # overwrite metrics with known numbers: Ours better in HDR PSNR, Baseline better in ATE
    vals = {
        ("tiny-lamp-box", "base"): (30.0, 0.2),
        ("tiny-flag-arm", "base"): (32.0, 0.4),
        ("tiny-lamp-box", "full"): (33.0, 0.5),
        ("tiny-flag-arm", "full"): (34.0, 0.5),
    }
    for j in jl:
        mp = Path(j.run_dir) / "metrics.json"
        m = json.loads(mp.read_text())
        m["hdr_psnr"], m["ate"] = vals[(j.scene, j.row)]
        mio.write_json(mp, m)
    r = CliRunner().invoke(main, ["table", "--columns", "all", str(suite), "--root", str(out)])
    assert r.exit_code == 0, r.output
    text = r.output
    base_line = next(ln for ln in text.splitlines() if ln.startswith("| Baseline"))
    ours_line = next(ln for ln in text.splitlines() if ln.startswith("| Ours"))
    # mean over scenes
    assert "**33.50**" in ours_line and "31.00" in base_line and "**31.00**" not in base_line
    geo_base = [ln for ln in text.splitlines() if ln.startswith("| Baseline")][1]
    assert "**0.3000**" in geo_base  # ATE: lower is better
    assert "HDR PSNR/SSIM: mu-law" in text and "Means over scenes" in text  # footnotes
    assert "LPIPS: n/a" in text
    figs = out / "figures" / "t2"
    for name in ("crf_tiny-lamp-box.png", "grid_tiny-lamp-box.png", "loss_tiny-flag-arm_full.png"):
        assert (figs / name).exists() and (figs / name).stat().st_size > 1000, name
    # a run without metrics.json: its row's means are n/a (never a mean over fewer scenes), and a
    # note says so
    mp = out / "runs/t2/tiny-flag-arm/base/metrics.json"
    saved = mp.read_bytes()
    mp.unlink()
    r = CliRunner().invoke(
        main, ["table", "--columns", "all", str(suite), "--root", str(out), "--no-figures"]
    )
    base_line = next(ln for ln in r.output.splitlines() if ln.startswith("| Baseline"))
    # 10 means and their 10 paired differences to the reference row (full) are n/a; n counts the one
    # scored run
    assert (
        r.exit_code == 0
        and base_line.count("n/a") == 20
        and "1 of 4 runs have no metrics.json" in r.output
    )
    assert base_line.startswith("| Baseline | 1 | n/a | n/a |")
    # ... and the scenes whose runs are all scored are named as the option that tabulates them
    assert "1 of 2 scenes have every run scored" in r.output
    assert "--scenes tiny-lamp-box" in r.output
    args = ["table", "--columns", "all", str(suite), "--root", str(out), "--no-figures"]
    r = CliRunner().invoke(main, args + ["--scenes", "tiny-lamp-box"])
    base_line = next(ln for ln in r.output.splitlines() if ln.startswith("| Baseline"))
    # HDR PSNR on that scene: Baseline 30, Ours 33
    assert r.exit_code == 0 and "| 30.00 ± n/a | -3.00 ± n/a |" in base_line, base_line
    assert "scenes have every run scored" not in r.output
    mp.write_bytes(saved)
    # latex / csv / runs-dir forms
    r = CliRunner().invoke(
        main,
        [
            "table",
            "--columns",
            "all",
            str(suite),
            "--root",
            str(out),
            "--format",
            "latex",
            "--no-figures",
        ],
    )
    assert r.exit_code == 0 and "\\textbf{33.50}" in r.output and "\\toprule" in r.output
    outf = tmp_path / "t.csv"
    r = CliRunner().invoke(
        main,
        [
            "table",
            "--columns",
            "all",
            str(out / "runs" / "t2"),
            "--format",
            "csv",
            "--out",
            str(outf),
            "--no-figures",
        ],
    )
    assert r.exit_code == 0, r.output
    rows = [ln.split(",") for ln in outf.read_text().splitlines() if ln and not ln.startswith("#")]
    assert {rw[0] for rw in rows[1:] if rw[0] != "Method"} >= {"world-only", "full"}


def test_job_command(tmp_path, fake_trainer):
    suite = tmp_path / "t2.yaml"
    suite.write_text(SUITE_YAML)
    out = tmp_path / "exp"
    make_fake_clip(out / "clips" / "tiny" / "tiny-flag-arm")
    r = CliRunner().invoke(
        main,
        [
            "job",
            str(suite),
            "--out",
            str(out),
            "--preset",
            "tiny",
            "--scene",
            "tiny-flag-arm",
            "--row",
            "full",
        ],
    )
    assert r.exit_code == 0, r.output
    res = json.loads(r.output.strip().splitlines()[-1])
    assert res["steps"] == ["train", "score"] and Path(res["metrics"]).exists()


def test_figures_direct(tmp_path):
    from eval.figures import crf_figure, loss_series, smooth

    recs = [
        {"stage": "stage1", "step": 0, "total": 1.0},
        {"stage": "stage1", "step": 50, "total": 0.5},
        {"stage": "stage2", "step": 0, "total": 0.4, "tlr": 0.0, "n_clone": 12, "static_prune": 3},
        {"stage": "stage2", "step": 20, "total": 0.3, "num_dynamic": 5},
    ]
    series, off = loss_series(recs)
    assert off == 50.0 and series["total"][0].tolist() == [0.0, 50.0, 50.0, 70.0]
    assert set(series) == {"total"}  # zero loss (log scale) and densification counters are left out
    y = np.random.default_rng(0).random(30)
    ref = np.convolve(y, np.ones(5) / 5, mode="valid")  # interior of a centred running mean
    assert np.allclose(smooth(y, 5)[2:-2], ref) and smooth(y, 5)[0] == pytest.approx(y[:3].mean())
    z = np.linspace(-4, 4, 9)
    p = crf_figure(
        [
            (
                "a",
                {
                    "log2_x": z.tolist(),
                    "learned": np.tile(z[:, None], 3).tolist(),
                    "true": z.tolist(),
                    "crf": "hdrnerf",
                },
            )
        ],
        tmp_path / "c.png",
    )
    assert p.exists() and p.stat().st_size > 1000
    assert crf_figure([("a", None)], tmp_path / "d.png") is None


def _crashing_clip(job, progress=False):
    """A clip maker that fails like a bug would (module level: the process pool pickles it)."""
    raise RuntimeError("the renderer crashed")


@pytest.mark.parametrize("jobs", [1, 2])
def test_run_suite_goes_on_after_a_failed_job_and_retries_it(tmp_path, fake_trainer, jobs):
    """A job that fails (an input error, a bug) and the jobs of a clip that cannot be made are
    reported; the other jobs finish; `m4dgs-eval run` exits 1 naming the failures; the failed run
    records its error (failure.json), which `export` turns into a "failed" row; told not to retry
    failed jobs, a run leaves that one alone; a second run retries only what failed and, when it
    scores, removes the record; --fail-fast stops at the first failure."""
    import multiprocessing as mp

    import eval.experiments.runner as runner
    from m4dgs.core.errors import InputError

    if jobs > 1 and (
        mp.get_start_method(allow_none=True) not in (None, "fork") or sys.platform != "linux"
    ):
        pytest.skip("needs the fork start method to pass the fake trainer to the workers")
    suite = tmp_path / "t2.yaml"
    suite.write_text(SUITE_YAML)
    out = tmp_path / "exp"
    jl = runner.job_list(suite, out, "tiny")
    lamp = {j.clip_dir for j in jl if j.scene == "tiny-lamp-box"}
    for c in lamp:  # tiny-flag-arm's clip is missing and fails to be made (below)
        make_fake_clip(Path(c), seed=3)
    pipeline = sys.modules["m4dgs.training.pipeline"]
    good_train = pipeline.train
    logs = []

    def bad_train(clip_dir, run_dir, *a, **k):
        if Path(run_dir).name == "base":
            Path(run_dir).mkdir(parents=True, exist_ok=True)  # as the trainer does, then fails
            raise InputError(f"{clip_dir}/clip.json: field 'exposures' is broken")
        return good_train(clip_dir, run_dir, *a, **k)

    mpatch = pytest.MonkeyPatch()
    mpatch.setattr(pipeline, "train", bad_train)
    mpatch.setattr(runner, "make_job_clip", _crashing_clip)
    try:
        kw = dict(jobs=jobs, score_kw={"fps": False, "model": False}, progress=False)
        res = runner.run_suite(suite, out, "tiny", log=logs.append, **kw)
        assert [r["id"] for r in res] == [j.id for j in jl]
        by = {(j.scene, j.row): r for j, r in zip(jl, res)}
        assert by[("tiny-lamp-box", "full")]["steps"] == ["train", "score"]
        assert by[("tiny-lamp-box", "base")]["error"] == (
            "the job: " + f"{Path(next(iter(lamp)))}/clip.json: field 'exposures' is broken"
        )
        for row in ("base", "full"):
            err = by[("tiny-flag-arm", row)]["error"]
            assert err == "making the clip: RuntimeError: the renderer crashed"
        assert len(runner.failed_jobs(res)) == 3
        text = "\n".join(logs)
        flag_key = next(j.clip_key for j in jl if j.scene == "tiny-flag-arm")
        assert f"FAILED clip {flag_key}: making the clip: RuntimeError" in text
        assert "Traceback" in text  # the unexpected error's traceback is logged
        base_run = Path(by[("tiny-lamp-box", "base")]["run"])
        assert not (base_run / "metrics.json").exists()
        want = f"training: {Path(next(iter(lamp)))}/clip.json: field 'exposures' is broken"
        assert runner.read_failure(base_run) == want
        assert runner.read_failure(by[("tiny-lamp-box", "full")]["run"]) is None
        # export: the failed run is a "failed" row with its error, the scored one "scored"
        from eval.experiments.export import export as export_runs
        from eval.records.runs_csv import read_runs_csv

        csvp = tmp_path / f"runs-{jobs}.csv"
        summary = export_runs([str(suite)], out, csvp, scenes=["tiny-lamp-box"])
        assert next(iter(summary.values())) == {"scored": 1, "failed": 1, "missing": 0}
        got = {r["row"]: (r["status"], r["error"]) for r in read_runs_csv(csvp)}
        assert got == {"full": ("scored", ""), "base": ("failed", want)}

        # not retried: the failed job keeps its record and its result says so (not a new
        # failure); the jobs of the clip that could not be made have no run folder, no record,
        # and are tried again (and fail again)
        logs.clear()
        res = runner.run_suite(suite, out, "tiny", log=logs.append, retry_failed=False, **kw)
        by = {(j.scene, j.row): r for j, r in zip(jl, res)}
        assert by[("tiny-lamp-box", "base")] == {
            "id": by[("tiny-lamp-box", "base")]["id"],
            "run": str(base_run),
            "steps": [],
            "failed_before": want,
        }
        assert sorted(r["id"] for r in runner.failed_jobs(res)) == sorted(
            j.id for j in jl if j.scene == "tiny-flag-arm"
        )
        assert "1 of 4 jobs failed at their last attempt: not retried" in "\n".join(logs)
        assert runner.read_failure(base_run) == want

        # fail fast: the first failure propagates
        with pytest.raises((InputError, RuntimeError)):
            runner.run_suite(suite, out, "tiny", log=logs.append, fail_fast=True, **kw)

        # the command: exit 1, one line naming the failed jobs
        if jobs == 1:
            r = CliRunner().invoke(
                main, ["run", str(suite), "--root", str(out), "--preset", "tiny"]
            )
            assert r.exit_code == 1, r.output
            assert (
                "3 of 4 jobs failed" in r.output and "Traceback" not in r.output.split("Error:")[-1]
            )
    finally:
        mpatch.undo()
    # fixed: a second run does only what failed (the clip is made here by hand)
    for c in {j.clip_dir for j in jl} - lamp:
        make_fake_clip(Path(c), seed=4)
    res = runner.run_suite(suite, out, "tiny", log=logs.append, **kw)
    assert not runner.failed_jobs(res)
    by = {(j.scene, j.row): r for j, r in zip(jl, res)}
    assert by[("tiny-lamp-box", "full")]["steps"] == []
    assert by[("tiny-lamp-box", "base")]["steps"] == ["train", "score"]
    assert by[("tiny-flag-arm", "full")]["steps"] == ["train", "score"]
    assert not (Path(by[("tiny-lamp-box", "base")]["run"]) / runner.FAILURE_FILE).exists()


def test_run_suite_process_pool(tmp_path, fake_trainer):
    """jobs=2: the fake trainer modules reach the workers through fork (Linux default start
    method)."""
    import multiprocessing as mp

    from eval.experiments.runner import job_list, run_suite

    if mp.get_start_method(allow_none=True) not in (None, "fork") or sys.platform != "linux":
        pytest.skip("needs the fork start method to pass the fake trainer to the workers")
    suite = tmp_path / "t2.yaml"
    suite.write_text(SUITE_YAML)
    out = tmp_path / "exp"
    jl = job_list(suite, out, "tiny")
    for j in {j.clip_dir for j in jl}:
        make_fake_clip(Path(j), seed=len(j))
    seen = []
    res = run_suite(
        suite,
        out,
        "tiny",
        jobs=2,
        score_kw={"fps": False, "model": False},
        log=lambda s: None,
        skip=lambda j: j.id == jl[1].id,  # recorded elsewhere: neither trained nor scored
        on_result=lambda j, r: seen.append((j.id, (Path(j.run_dir) / "metrics.json").exists())),
    )
    assert [r["id"] for r in res] == [j.id for j in jl]  # job order, whatever order they finish in
    assert res[1] == {"id": jl[1].id, "run": jl[1].run_dir, "steps": [], "recorded": True}
    assert not Path(jl[1].run_dir).exists()
    others = [j for i, j in enumerate(jl) if i != 1]
    assert all(r["steps"] == ["train", "score"] for i, r in enumerate(res) if i != 1)
    assert all((Path(j.run_dir) / "metrics.json").exists() for j in others)
    # on_result ran once per finished job, in this process, after its metrics were written
    assert sorted(seen) == sorted((j.id, True) for j in others)


def test_score_with_lpips_weights(tmp_path, fake_trainer):
    """Generated LPIPS weights: the per-level aggregation equals a direct per-image recomputation
    (numpy mean)."""
    from eval.experiments.score import score_run
    from eval.metrics import lpips_metric, mu_law, save_lpips_weights
    from eval.metrics.lpips import ALEX_CONVS, TAP_CHANNELS, LpipsWeights

    g = torch.Generator().manual_seed(0)
    conv_w = [
        torch.randn(cout, cin, k, k, generator=g) * 0.05 for _, cin, cout, k, _, _ in ALEX_CONVS
    ]
    conv_b = [torch.zeros(cout) for _, _, cout, _, _, _ in ALEX_CONVS]
    lin = [torch.rand(1, c, 1, 1, generator=g) for c in TAP_CHANNELS]
    wpath = tmp_path / "alex_lpips.pth"
    save_lpips_weights(LpipsWeights(conv_w, conv_b, lin), wpath)
    clip = make_fake_clip(tmp_path / "clip")
    run = tmp_path / "run"
    truth = make_fake_run(run, clip)
    m = score_run(run, lpips_weights=wpath, fps=False, model=False)
    w = LpipsWeights(conv_w, conv_b, lin)
    exp_ne = np.mean(
        [
            lpips_metric(truth["ldr"][(1.0, gg)], clip.load_gt_ldr(1.0, gg), w)
            for gg in clip.test_frames
        ]
    )
    assert m["ldr_ne_lpips"] == pytest.approx(exp_ne, rel=1e-5)
    exp_hdr = []
    for gg in clip.test_frames:
        gt = clip.load_gt_hdr(gg).astype(np.float64)
        s = gt.max()
        exp_hdr.append(lpips_metric(mu_law(np.clip(truth["hdr"][gg] / s, 0, 1)), mu_law(gt / s), w))
    assert m["hdr_lpips"] == pytest.approx(np.mean(exp_hdr), rel=1e-5)
    assert (
        m["ldr_oe_lpips"] > 0
        and "lpips" in m["conventions"]
        and m["options"]["lpips_weights"] == str(wpath)
    )


def test_score_real_clip_without_gt(tmp_path, fake_trainer):
    """A real clip (no gt/): test-frame metrics are None, training LDR is scored, HDR-TAE falls back
    to DIS flow."""
    import shutil

    from eval.experiments.score import score_run

    clip = make_fake_clip(tmp_path / "clip")
    run = tmp_path / "run"
    make_fake_run(run, clip)
    shutil.rmtree(clip.root / "gt")
    m = score_run(run, fps=False, model=False)
    assert (
        m["ldr_oe_psnr"] is None
        and m["hdr_psnr"] is None
        and m["ate"] is None
        and m["depth_absrel"] is None
    )
    assert m["ldr_train_psnr"] == 100.0  # train renders equal the input video
    assert (
        m["hdr_tae"] is not None
        and math.isfinite(m["hdr_tae"])
        and "hdr_tae_dis_flow" in m["conventions"]
    )
    assert m["run"]["has_gt"] is False


def test_run_suite_with_seeds_and_table(tmp_path, fake_trainer):
    """--seeds 2: seed 0 keeps the run folders, seed 1 trains into <row>-seed-1 with seed=1 on the
    same clips; the table pools the 2 scenes x 2 seeds with intervals and paired differences to the
    reference row."""
    from eval.experiments.runner import job_list, run_suite

    suite = tmp_path / "t2.yaml"
    suite.write_text(SUITE_YAML)
    out = tmp_path / "exp"
    for j in {j.clip_dir for j in job_list(suite, out, "tiny")}:
        make_fake_clip(Path(j), seed=len(j))
    r = CliRunner().invoke(
        main,
        ["run", str(suite), "--out", str(out), "--preset", "tiny", "--seeds", "2", "--list-jobs"],
    )
    assert r.exit_code == 0 and len(r.output.strip().splitlines()) == 8 and "--seed 1" in r.output
    res = run_suite(
        suite, out, "tiny", score_kw={"fps": False}, progress=False, log=lambda s: None, seeds=2
    )
    assert len(res) == 8 and len(fake_trainer["train"]) == 8
    by_dir = {Path(d).name: ov for d, _, ov in fake_trainer["train"]}
    assert by_dir["full"] == {"exposure.perturb_ev": 0.0} and by_dir["full-seed-1"] == {
        "exposure.perturb_ev": 0.0,
        "seed": 1,
    }
    assert by_dir["base"] is None and by_dir["base-seed-1"] == {"seed": 1}
    # known numbers: Ours = Baseline + 1 dB HDR PSNR (+- 0.1) on every (scene, seed)
    vals = {}
    for j in job_list(suite, out, "tiny", seeds=2):
        mp = Path(j.run_dir) / "metrics.json"
        m = json.loads(mp.read_text())
        b = 30.0 + 2.0 * (j.scene == "tiny-flag-arm") + 0.3 * j.seed
        m["hdr_psnr"] = b + (1.0 + 0.1 * (j.seed - 0.5) if j.row == "full" else 0.0)
        vals[(j.row, j.scene, j.seed)] = m["hdr_psnr"]
        mio.write_json(mp, m)
    r = CliRunner().invoke(
        main, ["table", "--columns", "all", str(suite), "--root", str(out), "--no-figures"]
    )
    assert r.exit_code == 0, r.output
    base_line = next(ln for ln in r.output.splitlines() if ln.startswith("| Baseline"))
    ours_line = next(ln for ln in r.output.splitlines() if ln.startswith("| Ours"))
    cells = [c.strip() for c in base_line.strip("|").split("|")]
    assert cells[1] == "4"  # 2 scenes x 2 seeds
    heads = [c.strip() for c in r.output.splitlines()[2].strip("|").split("|")]
    k = heads.index("HDR PSNR↑")
    base = [v for (row, _, _), v in vals.items() if row == "base"]
    h = 3.182446305284263 * np.std(base, ddof=1) / 2  # t_{0.975, 3} s / sqrt(4)
    assert cells[k] == f"{np.mean(base):.2f} ± {h:.2f}"
    assert (
        heads[k + 1] == "Δ HDR PSNR"
        and cells[k + 1].startswith("-1.00 ± ")
        and cells[k + 1].endswith("†")
    )
    assert "| Ours | 4 |" in ours_line and "ref" in ours_line
    # with --seeds 1 only the seed-0 runs are tabulated
    r1 = CliRunner().invoke(
        main,
        [
            "table",
            "--columns",
            "all",
            str(suite),
            "--root",
            str(out),
            "--no-figures",
            "--seeds",
            "1",
        ],
    )
    assert "| Baseline | 2 |" in r1.output
    # the runs folder form: <row>-seed-<n> folders are seeds of the same row
    r2 = CliRunner().invoke(
        main, ["table", "--columns", "all", str(out / "runs" / "t2"), "--no-figures"]
    )
    assert r2.exit_code == 0, r2.output
    assert "| world-only | 4 |" in r2.output and "| full | 4 |" in r2.output


@pytest.mark.parametrize(
    "name", ["departures", "departures-smooth", "control-video-init", "exposure-noise"]
)
def test_suite_overrides_change_what_they_name(name):
    """Each override of a row names a config field and changes it (a misspelt key fails in
    apply_overrides; a value equal to the variant's default would make the row a copy), and every
    row keeps full's iteration budget."""
    from eval.records.suite import load_eval_suite
    from m4dgs.training.config import to_dict
    from m4dgs.training.variants import variant_config

    suite = load_eval_suite(name)
    assert suite.reference in {r.name for r in suite.rows}
    full = variant_config("small", "full")
    full_total = full.stage1.iterations + full.stage2.iterations
    for r in [r for r in suite.rows if r.calibration is None]:  # 2D rows train nothing
        base = to_dict(variant_config("small", r.variant))
        resolved = variant_config("small", r.variant, r.overrides)
        assert resolved.stage1.iterations + resolved.stage2.iterations == full_total, r.name
        cfg = to_dict(resolved)
        for key, value in r.overrides.items():
            node_new, node_old = cfg, base
            for part in key.split("."):
                node_new, node_old = node_new[part], node_old[part]
            assert node_new == value and node_old != value, (r.name, key)


def test_scale_control_rows_are_the_paper_schedule_at_the_small_resolution():
    """control-video-init-scale: full gets the paper preset's iterations and densification
    schedules (its own Gaussian cap and resolution stay the small preset's), and the (a) row is
    exactly the budget transfer of that full row (stage2_only_budget), field by field."""
    import dataclasses

    from eval.records.suite import load_eval_suite
    from m4dgs.training.config import preset
    from m4dgs.training.variants import stage2_only_budget, variant_config

    suite = load_eval_suite("control-video-init-scale")
    rows = {r.variant: r for r in suite.rows}
    full = variant_config("small", "full", rows["full"].overrides)
    a = variant_config("small", "no-video-init", rows["no-video-init"].overrides)
    paper, small = preset("paper"), preset("small")
    assert (full.width, full.height) == (small.width, small.height)
    assert (full.stage1.iterations, full.stage2.iterations) == (4_000, 11_000)

    def schedule(d):
        return {k: v for k, v in dataclasses.asdict(d).items() if k != "max_gaussians"}

    assert schedule(full.stage1.densify) == schedule(paper.stage1.densify)
    for part in ("densify_static", "densify_dynamic"):
        assert schedule(getattr(full.stage2, part)) == schedule(getattr(paper.stage2, part))
        assert getattr(full.stage2, part).max_gaussians == getattr(small.stage2, part).max_gaussians
    assert full.stage2.dynamic_removal_every == paper.stage2.dynamic_removal_every
    assert full.stage2.pr_steps == 3_000  # the authors' window, as the small preset's proportion
    ref = stage2_only_budget(full)
    assert a.stage1.iterations == 0 and not a.ablation.use_video_init
    assert dataclasses.asdict(a.stage2) == dataclasses.asdict(ref.stage2)
    assert a.stage2.iterations == 15_000 and a.stage2.densify_static.stop_iter == 10_909


# -------------------------------------------------------------------------------------- campaigns
def _campaign_file(tmp_path, suite, steps):
    import yaml

    p = tmp_path / "camp.yaml"
    p.write_text(
        yaml.safe_dump(
            {
                "name": "camp",
                "preset": "tiny",
                "seeds": 1,
                "scene_sets": {"ONE": ["tiny-lamp-box"]},
                "steps": [dict(s, suite=str(suite)) for s in steps],
            }
        )
    )
    return p


def test_campaign_file_errors_name_the_field(tmp_path):
    from eval.experiments.campaign import CampaignError, load_campaign, parse_campaign

    c = load_campaign("results-small")
    four = [
        "lamp-room-orbit",
        "pendulum-lamp-handheld",
        "conveyor-occlusion-orbit",
        "robot-arm-dolly",
    ]
    appendix = [
        "paper-ablation",
        "control-points",
        "exposure-noise",
        "exposure-schedules",
        "priors",
    ]
    assert c.preset == "small" and [s.suite for s in c.steps] == [
        "crf",
        "control-video-init-priors",
        "paper-main",
        "control-video-init-scale",
        *appendix,
        "crf",
        "control-tlr",
        "control-reproj",
        "exposure-noise-draw",
        "control-video-init-prior-parts",
        "control-depth-loss",
        "control-reproj-priors",
        "control-scale",
        "paper-main",
        *appendix,
        "crf",
        "control-video-init-masks",
        "control-track-loss",
        "control-track-loss-stage",
        "control-tlr-priors",
        "control-tlr-scale",
        "control-loss-scale",
        "control-tlr",
        "control-reproj",
        "exposure-noise-draw",
        "control-depth-loss",
        "control-reproj-priors",
        "control-scale",
        "control-loss-scale",
    ]
    assert c.steps[24].scenes == ["lamp-room-orbit", "pendulum-lamp-handheld"]
    assert all(s.scenes == four for s in c.steps[25:])
    assert c.steps[2].scenes is None and c.steps[2].seeds == 1 and c.steps[17].scenes is None
    # breadth first: each appendix suite's first seed on the four scenes, then every suite's second
    assert [s.seeds for s in c.steps[4:13]] == [1] * 9
    assert c.steps[14].seeds == c.steps[15].seeds == c.steps[16].seeds == 1
    assert c.steps[29].seeds == 1  # control-loss-scale's first seed, before the second seeds
    assert all(
        s.seeds == 2
        for i, s in enumerate(c.steps)
        if not (i in (2, 14, 15, 16, 29) or 4 <= i <= 12)
    )
    assert all(
        c.steps[i].scenes == four
        for i in (4, 5, 6, 7, 8, 10, 11, 12, 14, 15, 16, 18, 19, 20, 21, 22)
    )
    assert (
        c.steps[9].scenes == c.steps[23].scenes == ["conveyor-occlusion-orbit", "robot-arm-dolly"]
    )
    good = {"preset": "tiny", "steps": [{"suite": "tiny"}]}
    assert parse_campaign(good, "f.yaml").steps[0].seeds == 1
    # a list: those trainer seeds only (a confirmatory test at seeds no earlier run used)
    assert parse_campaign({**good, "seeds": [3, 2]}, "f.yaml").steps[0].seeds == (2, 3)
    confirm = load_campaign("confirm-movers").steps
    assert [(s.suite, s.seeds) for s in confirm] == [("confirm-movers", (2, 3))]
    assert confirm[0].scenes == ["spark-crossing-lit-static", "bare-bulb-swing-lit-handheld"]
    for bad, field in [
        ({**good, "sedes": 2}, "'sedes'"),
        ({**good, "preset": "huge"}, "'preset'"),
        ({**good, "seeds": 0}, "'seeds'"),
        ({**good, "steps": []}, "'steps'"),
        ({**good, "steps": [{"suite": "nope"}]}, "'steps[0].suite'"),
        ({**good, "steps": [{"suite": "tiny", "scenes": "X"}]}, "'steps[0].scenes'"),
        (
            {**good, "steps": [{"suite": "tiny", "scenes": ["lamp-room-orbit"]}]},
            "'steps[0].scenes'",
        ),
        ({**good, "steps": [{"suite": "tiny", "seeds": -1}]}, "'steps[0]'"),
        ({**good, "seeds": [1, 1]}, "'seeds'"),
        ({**good, "steps": [{"suite": "tiny", "seeds": []}]}, "'steps[0]'"),
        ({**good, "steps": [{"suite": "tiny", "rows": ["full"]}]}, "'steps[0].rows'"),
    ]:
        with pytest.raises(CampaignError, match=field.replace("[", r"\[").replace("]", r"\]")) as e:
            parse_campaign(bad, "f.yaml")
        assert str(e.value).startswith("f.yaml: "), e.value
    r = CliRunner().invoke(main, ["campaign", "no-such-campaign"])
    assert r.exit_code != 0 and "results-small" in r.output


def _two_step_campaign(tmp_path):
    """(suite file, root, CSV path, campaign) of the fake-trainer campaign tests: suite t2 (rows
    base = world-only, full) with its clips made, step 1 on scene set ONE with one seed, step 2 on
    every scene with two."""
    from eval.experiments.campaign import load_campaign
    from eval.experiments.runner import job_list

    suite = tmp_path / "t2.yaml"
    suite.write_text(SUITE_YAML)
    out, csv_path = tmp_path / "exp", tmp_path / "runs.csv"
    for j in {j.clip_dir for j in job_list(suite, out, "tiny")}:
        make_fake_clip(Path(j), seed=len(j))
    camp = load_campaign(_campaign_file(tmp_path, suite, [{"scenes": "ONE"}, {"seeds": 2}]))
    return suite, out, csv_path, camp


def test_campaign_time_estimate_from_recorded_seconds(tmp_path, fake_trainer):
    """The dry run's estimate: the median recorded seconds per iteration of the scored runs (the
    fake runs record 120 s) times each step's iterations still to train (the rows' budgets at the
    tiny preset, counted here with m4dgs.training.variants.budget), over the workers."""
    from eval.experiments.campaign import run_campaign
    from m4dgs.core.errors import InputError
    from m4dgs.training.variants import budget

    suite, out, csv_path, camp = _two_step_campaign(tmp_path)
    code = "c0ffee" + "0" * 58
    lines = []
    kw = dict(code=code, log=lines.append, run_kw={"score_kw": {"fps": False}, "progress": False})
    plan = run_campaign(camp, out, csv_path, dry_run=True, jobs=2, **kw)
    assert all("estimate_hours" not in p for p in plan)  # nothing scored yet: no estimate
    assert any("no time estimate: none of its runs has finished yet" in ln for ln in lines)
    # step 1 trains; step 2 stops at the code guard (the fake runs record no code)
    with pytest.raises(InputError, match="mix code versions"):
        run_campaign(camp, out, csv_path, **kw)
    lines.clear()
    plan = run_campaign(camp, out, csv_path, dry_run=True, jobs=2, **kw)
    it = {v: budget("tiny", v)[2] for v in ("world-only", "full")}
    # the two scored runs of step 1 (world-only, full), 120 s each
    rate = sorted([120.0 / it["world-only"], 120.0 / it["full"]])[1]
    # step 2: 2 scenes x 2 rows x 2 seeds, of which step 1's two runs are scored
    todo = 3 * it["world-only"] + 3 * it["full"]
    assert "estimate_hours" not in plan[0]
    assert plan[1]["estimate_hours"] == pytest.approx(todo * rate / 2 / 3600)
    assert any("h of training left at --jobs 2" in ln for ln in lines)
    assert not any("no time estimate" in ln for ln in lines)
    assert [ln.split(":")[0].split()[-1] for ln in lines if "] step " in ln] == ["1/2", "2/2"]


def test_campaign_time_estimate_falls_back_on_the_roots_other_runs(tmp_path):
    """Before any run of its own has finished, the estimate takes the median seconds per iteration
    of the other suites' scored runs in the root at the campaign's preset: train_seconds over the
    config's iterations, stage 1's only when the run trained one; unscored runs and runs at another
    preset do not count."""
    import yaml

    from eval.experiments.campaign import run_campaign
    from m4dgs.core import io as mio
    from m4dgs.training.variants import budget

    suite, out, csv_path, camp = _two_step_campaign(tmp_path)

    def other_run(name, preset, seconds, stage1, iters1, iters2, scored=True):
        run = out / "runs" / "other-suite" / "some-scene" / name
        run.mkdir(parents=True)
        stages = {"stage1": 1.0, "stage2": 1.0} if stage1 else {"stage2": 1.0}
        info = {"preset": preset, "train_seconds": seconds, "stage_seconds": stages}
        mio.write_json(run / "run.json", info)
        cfg = {"stage1": {"iterations": iters1}, "stage2": {"iterations": iters2}}
        (run / "config.yaml").write_text(yaml.safe_dump(cfg))
        if scored:
            mio.write_json(run / "metrics.json", {})

    other_run("a", "tiny", 300.0, True, 100, 200)  # 1.0 s per iteration
    other_run("b", "tiny", 150.0, False, 100, 200)  # no stage 1: 0.75 (0.5 if it were counted)
    other_run("c", "tiny", 60.0, True, 100, 200)  # 0.2
    other_run("d", "small", 30000.0, True, 100, 200)  # another preset
    other_run("e", "tiny", 30000.0, True, 100, 200, scored=False)  # not finished
    lines = []
    plan = run_campaign(camp, out, csv_path, dry_run=True, jobs=2, code="0" * 64, log=lines.append)
    it = {v: budget("tiny", v)[2] for v in ("world-only", "full")}
    # step 1: one scene x (world-only, full) x one seed, nothing scored
    assert plan[0]["estimate_hours"] == pytest.approx(
        (it["world-only"] + it["full"]) * 0.75 / 2 / 3600
    )
    assert any("over 3 scored run(s) of other suites in this root" in ln for ln in lines)
    assert not any("no time estimate" in ln for ln in lines)


def test_campaign_runs_exports_resumes_and_guards_the_code(tmp_path, fake_trainer):
    import csv

    from eval.experiments.campaign import run_campaign
    from eval.experiments.runner import job_list
    from m4dgs.core.errors import InputError

    suite, out, csv_path, camp = _two_step_campaign(tmp_path)
    code = "c0ffee" + "0" * 58
    kw = dict(code=code, log=lambda s: None, run_kw={"score_kw": {"fps": False}, "progress": False})
    plan = run_campaign(camp, out, csv_path, dry_run=True, **kw)
    assert [(p["scored"], p["total"]) for p in plan] == [(0, 2), (0, 8)] and not fake_trainer[
        "train"
    ]

    # step 1 trains its 2 runs and exports them; step 2 then finds 2 of its 8 runs finished with
    # other code (the fake runs record none) and stops before training anything
    with pytest.raises(InputError, match="mix code versions"):
        run_campaign(camp, out, csv_path, **kw)
    assert len(fake_trainer["train"]) == 2
    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    assert sorted((r["scene"], r["row"], r["seed"]) for r in rows) == [
        ("tiny-lamp-box", "base", "0"),
        ("tiny-lamp-box", "full", "0"),
    ]
    # the same code: the campaign goes on where it stopped and trains only what is missing
    for j in job_list(suite, out, "tiny", seeds=2):
        rj = Path(j.run_dir) / "run.json"
        if rj.exists():
            mio.write_json(rj, dict(mio.read_json(rj), code=code))
    res = run_campaign(camp, out, csv_path, **kw)
    assert [(r["scored"], r["total"], r["ran"]) for r in res] == [(2, 2, False), (8, 8, True)]
    assert len(fake_trainer["train"]) == 8
    with open(csv_path) as f:
        assert len(list(csv.DictReader(f))) == 8
    # done: nothing is trained again; --allow-mixed-code lets a step with other code finish
    assert [r["ran"] for r in run_campaign(camp, out, csv_path, **kw)] == [False, False]
    (Path(job_list(suite, out, "tiny", seeds=2)[-1].run_dir) / "metrics.json").unlink()
    with pytest.raises(InputError, match="c0ffee"):
        run_campaign(camp, out, csv_path, **dict(kw, code="beef" + "0" * 60))
    res = run_campaign(
        camp, out, csv_path, allow_mixed_code=True, **dict(kw, code="beef" + "0" * 60)
    )
    assert res[1]["ran"] and len(fake_trainer["train"]) == 8  # rescored, not retrained


def test_a_campaign_of_listed_seeds_trains_and_exports_only_those(tmp_path, fake_trainer):
    import csv

    from eval.experiments.campaign import load_campaign, run_campaign
    from eval.experiments.runner import job_list

    suite = tmp_path / "t2.yaml"
    suite.write_text(SUITE_YAML)
    out, csv_path = tmp_path / "exp", tmp_path / "runs.csv"
    for j in {j.clip_dir for j in job_list(suite, out, "tiny")}:
        make_fake_clip(Path(j), seed=len(j))
    camp = load_campaign(_campaign_file(tmp_path, suite, [{"scenes": "ONE", "seeds": [2]}]))
    lines = []
    kw = dict(code="c0ffee" + "0" * 58, log=lines.append)
    run_kw = {"score_kw": {"fps": False}, "progress": False}
    res = run_campaign(camp, out, csv_path, run_kw=run_kw, **kw)
    assert [(r["scored"], r["total"]) for r in res] == [(2, 2)]
    assert any("seeds 2)" in ln for ln in lines), lines
    trained = sorted((Path(t[0]).name, (t[2] or {}).get("seed")) for t in fake_trainer["train"])
    assert trained == [("base-seed-2", 2), ("full-seed-2", 2)]
    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    assert sorted((r["row"], r["seed"]) for r in rows) == [("base", "2"), ("full", "2")]
    # the commands take the same lists: --seeds 2,3 lists and exports seeds 2 and 3 only
    args = ["--root", str(out), "--scenes", "tiny-lamp-box"]
    r = CliRunner().invoke(main, ["suite", "run", str(suite), *args, "--preset", "tiny"]
                           + ["--seeds", "2,3", "--list-jobs"])  # fmt: skip
    seeds = sorted(json.loads(ln)["seed"] for ln in r.output.splitlines())
    assert r.exit_code == 0 and seeds == [2, 2, 3, 3], r.output
    two = tmp_path / "two.csv"
    r = CliRunner().invoke(main, ["suite", "export", str(suite), *args, "--csv", str(two)]
                           + ["--seeds", "2,3"])  # fmt: skip
    assert r.exit_code == 0, r.output
    with open(two) as f:
        got = sorted((r["row"], r["seed"], r["status"]) for r in csv.DictReader(f))
    assert got == [
        ("base", "2", "scored"),
        ("base", "3", "missing"),
        ("full", "2", "scored"),
        ("full", "3", "missing"),
    ]
    r = CliRunner().invoke(main, ["suite", "export", str(suite), *args, "--seeds", "1,1"])
    assert r.exit_code == 2 and "distinct seeds" in r.output


def test_campaign_code_guard_ignores_the_calibration_rows(tmp_path):
    """A calibration row trains nothing and records no m4dgs code (run.json or CSV): a finished
    one must not read as "code unknown" and stop a campaign restarted on the same code, whether
    its record is a run folder or only a CSV row; a trained run of other code still counts."""
    from eval.experiments.campaign import Step, job_key, step_status
    from eval.experiments.runner import job_list

    suite = tmp_path / "t2c.yaml"
    suite.write_text(
        SUITE_YAML.replace(
            "rows:\n",
            "rows:\n  - {name: copy-nearest, label: '2D', calibration: copy-nearest}\n"
            "  - {name: flow-merge, label: '2D flow', calibration: flow-merge}\n",
        )
    )
    out = tmp_path / "exp"
    jl = job_list(suite, out, "tiny")
    by_row = {j.row: j for j in jl if j.scene == jl[0].scene}
    assert by_row["copy-nearest"].calibration == "copy-nearest"
    code = "c0ffee" + "0" * 58

    def finish(job, info):
        run = Path(job.run_dir)
        run.mkdir(parents=True)
        mio.write_json(run / "run.json", info)
        mio.write_json(run / "metrics.json", {})

    finish(by_row["copy-nearest"], {"calibration": "copy-nearest"})  # no code: trains nothing
    finish(by_row["full"], {"code": code, "train_seconds": 10.0})
    # flow-merge's record is only a CSV row (its run folder lost), without a code either
    recorded = {job_key(by_row["flow-merge"]): {"status": "scored", "code": ""}}
    step = Step(suite=str(suite), scenes=[jl[0].scene], seeds=1)
    s = step_status(step, out, "tiny", recorded)
    assert s["scored"] == 3 and s["recorded"] == 1
    assert dict(s["codes"]) == {code[:12]: 1}
    # a trained run without a code is still one of unknown code
    finish(by_row["base"], {"train_seconds": 10.0})
    s = step_status(step, out, "tiny", recorded)
    assert dict(s["codes"]) == {code[:12]: 1, "unknown": 1}


def test_campaign_runs_every_step_on_the_executor_it_is_given(tmp_path, fake_trainer):
    """run_kw["executor"] (what `suite campaign --executor ...` opens once): each step's jobs run
    on it, it stays open between steps, the driver prints a progress line per finished job, and
    every step is exported."""
    import csv
    import multiprocessing as mp

    from eval.experiments.campaign import run_campaign
    from m4dgs.core.executors import LocalExecutor

    if mp.get_start_method(allow_none=True) not in (None, "fork") or sys.platform != "linux":
        pytest.skip("needs the fork start method to pass the fake trainer to the workers")
    suite, out, csv_path, camp = _two_step_campaign(tmp_path)
    lines = []
    with LocalExecutor(jobs=2, threads=1) as ex:
        run_kw = {"score_kw": {"fps": False}, "progress": False, "executor": ex}
        res = run_campaign(
            camp,
            out,
            csv_path,
            code="0" * 64,
            log=lines.append,
            run_kw=run_kw,
            allow_mixed_code=True,  # the fake runs record no code
        )
        pool = ex._pool
        assert pool is not None  # the steps did not close it
    assert [(r["scored"], r["total"], r["ran"]) for r in res] == [(2, 2, True), (8, 8, True)]
    progress = [ln for ln in lines if " jobs: " in ln]
    # step 1: its 2 jobs; step 2: its 8 (the 2 that step 1 finished have nothing to do)
    assert len(progress) == 2 + 8 and progress[-1].startswith("[eval run] 8/8 jobs: 8 done")
    with open(csv_path) as f:
        assert len(list(csv.DictReader(f))) == 8


def test_campaign_resumes_from_the_csv_when_the_root_is_lost(tmp_path, fake_trainer, monkeypatch):
    """The runs CSV is the record that survives: each job is exported as soon as it is scored (a
    step that stops on a failure keeps its finished jobs), and a campaign restarted into an empty
    root trains only the jobs the CSV lacks; CSV rows of other code stop an unfinished step."""
    import csv
    import shutil
    import sys

    from eval.experiments.campaign import run_campaign
    from eval.experiments.runner import job_list
    from m4dgs.core.errors import InputError, M4DGSError

    suite, out, csv_path, camp = _two_step_campaign(tmp_path)
    code = "c0ffee" + "0" * 58
    kw = dict(code=code, log=lambda s: None, run_kw={"score_kw": {"fps": False}, "progress": False})
    pmod = sys.modules["m4dgs.training.pipeline"]
    fake_train = pmod.train
    diverge = {"tiny-flag-arm/full-seed-1"}  # one job of step 2 fails the first time

    def train(clip_dir, run_dir, **k):  # the fake trainer, recording the code as the real one does
        if any(str(run_dir).endswith(d) for d in diverge):
            Path(run_dir).mkdir(parents=True, exist_ok=True)  # the real trainer's folder exists
            # ... with the run.json it writes when training starts (the preset among others)
            mio.write_json(Path(run_dir) / "run.json", {"preset": "tiny", "code": code})
            raise RuntimeError("diverged")
        fake_train(clip_dir, run_dir, **k)
        rj = Path(run_dir) / "run.json"
        mio.write_json(rj, dict(mio.read_json(rj), code=code))
        return run_dir

    monkeypatch.setattr(pmod, "train", train)
    with pytest.raises(M4DGSError, match=r"jobs failed in step 2 \(.*\): 1 job"):
        run_campaign(camp, out, csv_path, **kw)
    with open(csv_path) as f:
        failed = [r for r in csv.DictReader(f) if r["status"] == "failed"]
    assert [(r["scene"], r["row"], r["seed"], r["error"]) for r in failed] == [
        ("tiny-flag-arm", "full", "1", "training: RuntimeError: diverged")
    ]
    assert [r["preset"] for r in failed] == ["tiny"]  # from run.json: the row is recognised later

    def csv_keys():
        with open(csv_path) as f:
            return sorted(
                (r["scene"], r["row"], r["seed"])
                for r in csv.DictReader(f)
                if r["status"] == "scored"
            )

    # every job but the failed one is in the CSV, and was put there by the per-job export
    assert len(csv_keys()) == 7 and len(fake_trainer["train"]) == 7
    shutil.rmtree(out)  # the root is lost (a machine restart); the CSV survives
    for j in {j.clip_dir for j in job_list(suite, out, "tiny")}:
        make_fake_clip(Path(j), seed=len(j))
    plan = run_campaign(camp, out, csv_path, dry_run=True, **kw)
    assert [(p["scored"], p["recorded"], p["total"]) for p in plan] == [(2, 2, 2), (7, 7, 8)]
    # the time estimate comes from the CSV's train_minutes (the fake runs record 120 s)
    from eval.experiments.campaign import job_iterations

    todo = job_iterations(
        next(
            j
            for j in job_list(suite, out, "tiny", seeds=2)
            if "flag" in j.id and j.id.endswith("full-seed-1")
        )
    )
    rates = sorted(p for p in plan[0]["sec_per_iteration"] + plan[1]["sec_per_iteration"])
    assert len(rates) == 9 and all(r > 0 for r in rates)
    assert plan[1]["estimate_hours"] == pytest.approx(todo * rates[4] / 3600)
    diverge.clear()
    # another checkout's code: the unfinished step would mix versions, so nothing is trained
    with pytest.raises(InputError, match="c0ffee"):
        run_campaign(camp, out, csv_path, **dict(kw, code="beef" + "0" * 60))
    assert len(fake_trainer["train"]) == 7
    res = run_campaign(camp, out, csv_path, **kw)
    assert [(r["scored"], r["total"], r["ran"]) for r in res] == [(2, 2, False), (8, 8, True)]
    assert len(fake_trainer["train"]) == 8  # only the job the CSV lacked
    assert fake_trainer["train"][-1][0].endswith("tiny-flag-arm/full-seed-1")
    assert len(csv_keys()) == 8
    with open(csv_path) as f:  # the retried run replaced its failed row
        assert {r["status"] for r in csv.DictReader(f)} == {"scored"}


def test_campaign_goes_on_after_a_step_with_a_failed_job(tmp_path, fake_trainer, monkeypatch):
    """A job that fails in step 1 does not hold up step 2: every other job trains, the failed run
    is a "failed" row of the CSV, and the campaign ends with an error naming both steps it failed
    in (step 2 retries the same job). A newer checkout cannot retry it (mixed code) but, told not
    to, goes past it with nothing to run."""
    import csv
    import sys

    from eval.experiments.campaign import run_campaign
    from m4dgs.core.errors import InputError, M4DGSError

    suite, out, csv_path, camp = _two_step_campaign(tmp_path)
    kw = dict(log=lambda s: None, run_kw={"score_kw": {"fps": False}, "progress": False})
    pmod = sys.modules["m4dgs.training.pipeline"]
    fake_train = pmod.train

    def train(clip_dir, run_dir, **k):
        if str(run_dir).endswith("tiny-lamp-box/base"):  # step 1's and step 2's seed-0 job
            Path(run_dir).mkdir(parents=True, exist_ok=True)
            raise RuntimeError("diverged")
        fake_train(clip_dir, run_dir, **k)
        rj = Path(run_dir) / "run.json"  # the code fingerprint, as the real trainer records it
        mio.write_json(rj, dict(mio.read_json(rj), code=code))
        return run_dir

    code = "c0ffee" + "0" * 58
    monkeypatch.setattr(pmod, "train", train)
    with pytest.raises(M4DGSError, match=r"step 1 \(.*\): 1 job.*; step 2 \(.*\): 1 job"):
        run_campaign(camp, out, csv_path, code=code, **kw)
    assert len(fake_trainer["train"]) == 7  # step 2's other seven jobs
    with open(csv_path) as f:
        st = sorted((r["scene"], r["row"], r["seed"], r["status"]) for r in csv.DictReader(f))
    assert len(st) == 8 and [x for x in st if x[3] != "scored"] == [
        ("tiny-lamp-box", "base", "0", "failed")
    ]
    # the dry run counts the failed job in both steps that hold it
    lines = []
    plan = run_campaign(camp, out, csv_path, dry_run=True, code=code, log=lines.append)
    assert [p["failed"] for p in plan] == [1, 1]
    assert sum("1 failed at their last attempt" in ln for ln in lines) == 2

    # a checkout with newer code: retrying the failed job would finish step 1 with other code
    # than its scored job's, so the campaign stops before it; told not to retry it, the campaign
    # has nothing left to run, trains nothing and ends without an error
    newer = "beef" + "0" * 60
    with pytest.raises(
        InputError, match=r"step 1 \(.*\): 1 finished run\(s\) with m4dgs code c0ffee"
    ):
        run_campaign(camp, out, csv_path, code=newer, **kw)
    lines = []
    res = run_campaign(
        camp, out, csv_path, code=newer, retry_failed=False, log=lines.append, run_kw=kw["run_kw"]
    )
    assert len(fake_trainer["train"]) == 7 and not any(r["ran"] for r in res)
    assert [(r["scored"], r["failed"], r["total"]) for r in res] == [(1, 1, 2), (7, 1, 8)]
    assert sum("failed at their last attempt (not retried)" in ln for ln in lines) == 2
    monkeypatch.setattr(pmod, "code_fingerprint", lambda: newer, raising=False)
    r = CliRunner().invoke(
        main,
        ["campaign", str(camp.path), "--root", str(out), "--csv", str(csv_path)]
        + ["--no-retry-failed", "--dry-run"],
    )
    assert r.exit_code == 0, r.output
    assert "2 of 2 steps complete" in r.output
    # the root is lost (a new machine): the CSV's "failed" row is the record of that attempt, so
    # the job still counts as failed, not as one to train (which would mix code versions)
    import shutil

    from eval.experiments.runner import job_list

    shutil.rmtree(out)
    for j in {j.clip_dir for j in job_list(suite, out, "tiny")}:
        make_fake_clip(Path(j), seed=len(j))
    lines = []
    res = run_campaign(
        camp, out, csv_path, code=newer, retry_failed=False, log=lines.append, run_kw=kw["run_kw"]
    )
    assert len(fake_trainer["train"]) == 7 and not any(r["ran"] for r in res)
    assert [(r["scored"], r["recorded"], r["failed"]) for r in res] == [(1, 1, 1), (7, 7, 1)]
    assert sum("failed at their last attempt (not retried)" in ln for ln in lines) == 2
    with pytest.raises(InputError, match=r"step 1 \(.*\): 1 finished run\(s\) with m4dgs code"):
        run_campaign(camp, out, csv_path, code=newer, **kw)  # retried: mixed code, as before
    with open(csv_path) as f:
        st = sorted((r["scene"], r["row"], r["seed"], r["status"]) for r in csv.DictReader(f))
    assert [x for x in st if x[3] != "scored"] == [("tiny-lamp-box", "base", "0", "failed")]


SHARE_SUITE_YAML = """name: t3
description: rows that differ after stage 1, one that does not
scenes: tiny
rows:
  - {name: full, label: "Ours", variant: full}
  - {name: no-occlusion, label: "(b)", variant: no-occlusion}
  - {name: no-reproj, label: "(d)", variant: no-reproj}
  - {name: no-tlr, label: "(e)", variant: no-tlr}
  - {name: base, label: "Baseline", variant: world-only}
tables:
  - {title: "Main", columns: paper}
"""


def test_campaign_estimate_counts_a_run_repeated_in_another_suite_once(tmp_path):
    """A control's row that repeats another suite's run (same clip, variant, overrides, seed) has
    that run's training key: it costs nothing when the run is finished under ROOT (the share folder
    holds its model), is counted once when neither has run, and a finished run known only from the
    CSV (no run folder, so nothing in the share folder) does not count as shared. Counted from the
    budgets (m4dgs.training.variants.budget)."""
    from eval.experiments.campaign import (
        Step,
        job_cost,
        job_training_key,
        step_status,
        todo_iterations,
    )
    from eval.experiments.runner import job_list
    from m4dgs.training.variants import budget

    a, b = tmp_path / "t3.yaml", tmp_path / "t4.yaml"
    a.write_text(SHARE_SUITE_YAML)
    b.write_text(
        SHARE_SUITE_YAML.replace("name: t3", "name: t4").split("rows:")[0]
        + "rows:\n  - {name: full-again, label: Ours, variant: full}\n"
        + "  - {name: tlr, label: w, variant: full, overrides: {stage2.loss.lambda_tlr: 0.5}}\n"
        + 'tables:\n  - {title: "Main", columns: paper}\n'
    )
    out = tmp_path / "exp"
    ja, jb = job_list(a, out, "tiny"), job_list(b, out, "tiny")
    ka = {(j.scene, j.row): job_training_key(j) for j in ja}
    kb = {(j.scene, j.row): job_training_key(j) for j in jb}
    lamp, flag = "tiny-lamp-box", "tiny-flag-arm"
    assert kb[(lamp, "full-again")] == ka[(lamp, "full")]  # the same training
    assert kb[(lamp, "tlr")] not in ka.values()  # a stage-2 weight: another training ...
    assert job_cost(jb[1])[0] == job_cost(ja[0])[0]  # ... on full's stage 1
    assert ka[(lamp, "no-reproj")] != ka[(lamp, "full")]  # shares stage 1 only
    assert kb[(flag, "full-again")] != kb[(lamp, "full-again")]
    s1, s2, _ = budget("tiny", "full")

    def status(path):
        return step_status(Step(suite=str(path), scenes=None, seeds=1), out, "tiny")

    # nothing finished: t4 after t3 trains only its two tlr rows' stage 2 (full-again is t3's full)
    assert todo_iterations([status(a), status(b)])[1] == 2 * s2
    # t4 first: every row of it trains, the tlr rows on their full-again's stage 1
    assert todo_iterations([status(b), status(a)])[0] == 2 * (s1 + s2) + 2 * s2
    # lamp's full finished under ROOT: t4's lamp full-again costs nothing, even before t3 runs
    assert (ja[0].scene, ja[0].row) == (lamp, "full")
    Path(ja[0].run_dir).mkdir(parents=True)
    (Path(ja[0].run_dir) / "metrics.json").write_text("{}")
    assert todo_iterations([status(b), status(a)])[0] == (s1 + s2) + 2 * s2
    # t3's fulls known only from the CSV: no model in the share folder, so full-again trains
    # (its stage 1 counts as shared, as for any finished job: todo_iterations' docstring)
    costs = [(j.row == "full", *job_cost(j), job_training_key(j), False) for j in ja]
    assert todo_iterations([dict(status(a), job_costs=costs), status(b)])[1] == 4 * s2


def test_campaign_estimate_counts_a_shared_stage_1_once(tmp_path):
    """job_cost: rows that change only V2W or stage 2 ((b), (d)) share full's stage-1 key, a row
    that changes stage 1 ((e) w/o TLR), another trainer seed or another clip does not, a row
    without stage 1 has none. todo_iterations counts each key's stage 1 once, and not at all when
    a finished job has it; counted here from the budgets (m4dgs.training.variants.budget)."""
    from eval.experiments.campaign import Step, job_cost, step_status, todo_iterations
    from eval.experiments.runner import job_list
    from m4dgs.training.variants import budget

    suite = tmp_path / "t3.yaml"
    suite.write_text(SHARE_SUITE_YAML)
    out = tmp_path / "exp"
    jobs = job_list(suite, out, "tiny", seeds=2)
    key = {(j.scene, j.row, j.seed): job_cost(j)[0] for j in jobs}
    lamp = "tiny-lamp-box"
    assert key[(lamp, "full", 0)] == key[(lamp, "no-occlusion", 0)] == key[(lamp, "no-reproj", 0)]
    assert key[(lamp, "no-tlr", 0)] not in (None, key[(lamp, "full", 0)])
    assert key[(lamp, "full", 1)] != key[(lamp, "full", 0)]  # trainer seeds are never shared
    assert key[("tiny-flag-arm", "full", 0)] != key[(lamp, "full", 0)]
    assert key[(lamp, "base", 0)] is None
    s1 = {v: budget("tiny", v)[0] for v in ("full", "no-tlr", "world-only")}
    s2 = {
        v: budget("tiny", v)[1]
        for v in ("full", "no-occlusion", "no-reproj", "no-tlr", "world-only")
    }
    assert s1["world-only"] == 0 and s1["full"] > 0
    st = step_status(Step(suite=str(suite), scenes=None, seeds=2), out, "tiny")
    rows = ("full", "no-occlusion", "no-reproj", "no-tlr", "base")
    variants = ("full", "no-occlusion", "no-reproj", "no-tlr", "world-only")
    per_clip_seed = sum(s2[v] for v in variants) + s1["full"] + s1["no-tlr"]
    assert todo_iterations([st]) == [4 * per_clip_seed]  # 2 clips x 2 seeds, nothing finished
    assert st["todo_iterations"] == 4 * (per_clip_seed + 2 * s1["full"])  # every job in full
    # lamp's seed-0 full is finished: (b) and (d) there find its stage 1 in the share folder
    costs = [(j.scene == lamp and j.row == "full" and j.seed == 0, *job_cost(j)) for j in jobs]
    assert len(costs) == 4 * len(rows)
    done_st = dict(st, job_costs=costs)
    assert todo_iterations([done_st]) == [4 * per_clip_seed - s2["full"] - s1["full"]]
