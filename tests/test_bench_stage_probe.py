"""bench/stage_probe.py's --emitter figures against Gaussians placed here on known pixels, its
--movers quotient against renders scaled here by known factors, and the probe from a run's V2W
output on a short tiny-preset run."""

from __future__ import annotations

import math

import numpy as np
import torch

from m4dgs.core import spline
from m4dgs.model.gaussians import WorldGaussians
from m4dgs.training.stage2 import CameraRig


def _state(ctrl: np.ndarray, opacity_logits, knots):
    n = ctrl.shape[0]
    rot = torch.zeros(n, 4, 4)
    rot[:, 0, 0] = 1.0
    g = WorldGaussians(
        {
            "means": torch.tensor([[0.0, 0.0, 5.0]]),  # a static one right on the emitter's ray
            "quats": torch.tensor([[1.0, 0, 0, 0]]),
            "scales": torch.zeros(1, 3),
            "opacities": torch.tensor([5.0]),
            "features": torch.zeros(1, 4),
        },
        {
            "ctrl": torch.tensor(ctrl, dtype=torch.float32),
            "rot": rot,
            "scales": torch.zeros(n, 3),
            "opacities": torch.tensor(opacity_logits, dtype=torch.float32),
            "features": torch.zeros(n, 4),
        },
        knots,
        int(knots[-1].item()) + 1,
    )
    return g.to_state()


def test_emitter_figures_on_known_pixels(load_bench):
    sp = load_bench("stage_probe")
    T, f, c = 5, 100.0, 50.0
    K = torch.tensor([[f, 0, c], [0, f, c], [0, 0, 1.0]])
    c2w = torch.eye(4).repeat(T, 1, 1)
    c2w[:, 0, 3] = torch.arange(T) * 0.1  # the camera slides along x
    rig = CameraRig(K, c2w).state_dict()
    emit = np.stack([np.full(T, 60.0), np.full(T, 50.0)], -1)  # the emitter at pixel (60, 50)
    knots = spline.make_knots(T, 1)
    x_on = (60.0 - c) / f * 2.0 + c2w[:, 0, 3].numpy()  # on the emitter's ray at depth 2
    on = np.stack([x_on, np.zeros(T), np.full(T, 2.0)], -1)
    off = on + [0.03, 0.0, 0.0]  # 1.5 px to the right at depth 2
    far = on + [1.0, 0.0, 0.0]  # 50 px away
    # opaque on the emitter, opaque 1.5 px off, transparent on it (ignored), opaque far
    st = _state(np.stack([on, off, on, far]), [5.0, 5.0, -5.0, 5.0], knots)
    px, near = sp.emitter_figures(st, rig, emit)
    assert px < 1e-3 and near == 2.0, (px, near)
    st = _state(np.stack([off, far]), [5.0, 5.0], knots)
    px, near = sp.emitter_figures(st, rig, emit)
    assert math.isclose(px, 1.5, rel_tol=1e-3) and near == 1.0, (px, near)
    st = _state(np.stack([on]), [-5.0], knots)  # no opaque dynamic Gaussian (the static one is)
    assert sp.emitter_figures(st, rig, emit) == (float("inf"), 0.0)


class _ScaledStage:
    """A stand-in for a stage-2 stage whose render at time i is the truth of frame i with the moving
    pixels times a and the still ones times b."""

    def __init__(self, truth, a, b):
        self.renders = {i: np.where(m[..., None], a * h, b * h) for i, h, m in truth}

    def cameras(self):
        return [None] * (max(self.renders) + 1)

    def render_at(self, t, c2w):
        from types import SimpleNamespace

        return SimpleNamespace(hdr=torch.from_numpy(self.renders[int(t)]))


def test_movers_quotient_against_known_scales(load_bench):
    sp = load_bench("stage_probe")
    rng = np.random.default_rng(0)
    truth = []
    for i in (0, 5, 10):
        m = np.zeros((8, 12), bool)
        m[2:4, 3 + i // 5 : 6 + i // 5] = True
        truth.append((i, rng.uniform(0.1, 20.0, (8, 12, 3)), m))
    assert math.isclose(sp.movers_quotient(_ScaledStage(truth, 0.25, 0.5), truth), 0.5)
    assert math.isclose(sp.movers_quotient(_ScaledStage(truth, 3.0, 3.0), truth), 1.0)
    assert math.isnan(sp.movers_quotient(_ScaledStage(truth, 1.0, 1.0), []))


def test_probe_from_v2w_on_a_short_run(
    tiny_clip_realistic, short_run_realistic, short_training, load_bench
):
    from m4dgs.clip import Clip

    sp = load_bench("stage_probe")
    run = short_run_realistic
    emit = sp.emitters(Clip.open(tiny_clip_realistic))
    recs = sp.run_arm(
        str(tiny_clip_realistic),
        run,
        dict(short_training),
        0,
        4,
        0,
        preset="tiny",
        from_v2w=True,
        window=2,
        emit=emit,
        movers=sp.mover_truth(Clip.open(tiny_clip_realistic), stride=1),
    )
    assert len(recs) == 4 and all("rgb" in r for r in recs)
    q = [recs[0]["movers_start"]] + [r["movers"] for r in recs if "movers" in r]
    assert len(q) == 3 and all(v > 0 and math.isfinite(v) for v in q), q
    marked = [r for r in recs if "emitter_px" in r]
    assert len(marked) == 2 and all(r["emitter_px"] >= 0 and r["emitter_near"] >= 0 for r in marked)
