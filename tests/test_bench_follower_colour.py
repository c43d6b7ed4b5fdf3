"""bench/follower_colour.py on a short tiny-preset run: the brightest opaque Gaussian recomputed
here from the checkpoint's colour-MLP weights by hand (2 ** (W2 relu(W1 [f, 0] + b1) + b2)) and
the run's still-pixel scale from its renders, against the report."""

from __future__ import annotations

import numpy as np
import torch

from m4dgs.clip import Clip
from m4dgs.core.io import read_exr
from m4dgs.run import load_torch


def test_report_on_a_short_run(tiny_clip_realistic, short_run_realistic, load_bench, capsys):
    fc = load_bench("follower_colour")
    run = short_run_realistic
    rep = fc.colour_report(run, tiny_clip_realistic)
    assert rep["hdr_scale"] > 0 and rep["truth_peak"] > 0
    if "followers_q" in rep:
        q = rep["followers_q"]
        assert q == sorted(q) and q[-1] <= rep["brightest_opaque"] * (1 + 1e-6)

    s1 = load_torch(run / "model" / "stage1.pt", map_location="cpu")
    p, c = s1["gaussians"]["params"], s1["color"]
    feats = p["features"].double()
    x = torch.cat([feats, torch.zeros(len(feats), 3, dtype=torch.float64)], -1)
    hid = torch.relu(x @ c["fc1.weight"].double().T + c["fc1.bias"].double())
    colour = (2.0 ** (hid @ c["fc2.weight"].double().T + c["fc2.bias"].double())).mean(-1)
    opaque = torch.sigmoid(p["opacities"].double().reshape(-1)) > 0.3
    clip = Clip.open(tiny_clip_realistic)
    ratios, truths = [], []
    for g in clip.train_frames:
        m = clip.load_gt_dynamic_mask(g)
        if m.any() and not m.all():
            t = clip.load_gt_hdr(g)[..., :3].mean(-1)
            r = read_exr(run / "renders" / "stage1" / "hdr" / f"{g:05d}.exr")[..., :3].mean(-1)
            ratios.append(np.median(r[~m]) / np.median(t[~m]))
            truths.append(np.median(t[~m]))
    unit = np.median(ratios) * np.median(truths)
    want = float(colour[opaque].max()) / unit
    assert abs(rep["brightest_opaque"] - want) <= 1e-4 * want, (rep["brightest_opaque"], want)
    assert fc.main([str(run), str(tiny_clip_realistic)]) == 0
    assert "x the still background" in capsys.readouterr().out
