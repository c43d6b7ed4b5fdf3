"""m4dgs.core.temporal: HDR-TAE pieces shared by benchgen and eval, against direct formulas."""

from __future__ import annotations

import numpy as np

import eval.metrics.temporal as et
from m4dgs.core import temporal as ct


def test_hdr_tae_with_zero_flow_is_the_relative_difference():
    rng = np.random.default_rng(0)
    a = rng.uniform(0.1, 2.0, (6, 5, 3))
    b = rng.uniform(0.1, 2.0, (6, 5, 3))
    zero = np.zeros((1, 6, 5, 2))
    want = (np.abs(a - b) / (a + b + 1e-10)).sum(-1).mean()  # channel sum, mean over pixels
    vis = np.ones((1, 6, 5), bool)
    got = ct.hdr_tae_pairs(np.stack([a, b]), zero, zero, vis, vis)
    assert len(got) == 1 and abs(got[0] - want) < 1e-12
    vis_half = vis.copy()
    vis_half[0, :3] = False  # only the visible pixels count, and only in that direction
    both = ct.hdr_tae_pairs(np.stack([a, b]), zero, zero, vis_half, vis)[0]
    rel = (np.abs(a - b) / (a + b + 1e-10)).sum(-1)
    assert abs(both - (rel[3:].mean() + rel.mean()) / 2) < 1e-12
    assert np.isnan(ct.hdr_tae(np.stack([a, b]), zero, zero, ~vis, ~vis))


def test_eval_reexports_the_core_functions():
    for name in (
        "hdr_tae",
        "hdr_tae_pairs",
        "hdr_tce",
        "hdr_tce_pairs",
        "depth_edges",
        "interior_visibility",
    ):
        assert getattr(et, name) is getattr(ct, name)
