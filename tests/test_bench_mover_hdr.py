"""bench/mover_hdr.py on the disc clip of bench/small_mover_bench.py, with renders made here from
the truth: the movers' pixels at 0.05 of their radiance and the rest at 0.5 give a quotient of 0.1
in every frame; renders equal to the truth give 1."""

from __future__ import annotations

import numpy as np

from m4dgs.core.io import write_exr


def _setup(tmp_path, smb):
    clip = smb.make_disc_clip(tmp_path / "disc")  # 160x96, 24 frames, radius 9, 4 px a frame
    return clip, smb.write_dynamic_masks(tmp_path / "disc")


def test_quotient_of_a_dimmed_mover(tmp_path, load_bench, capsys):
    from m4dgs.clip import Clip

    smb = load_bench("small_mover_bench")
    mh = load_bench("mover_hdr")
    clip, masks = _setup(tmp_path, smb)
    c = Clip.open(clip)
    run = tmp_path / "run"
    for sub, frames, scale in (
        ("train", c.train_frames, lambda m: np.where(m, 0.05, 0.5)),
        ("test", c.test_frames, lambda m: np.ones(m.shape)),
    ):
        (run / "renders" / sub / "hdr").mkdir(parents=True)
        for g in frames:
            img = c.load_gt_hdr(g) * scale(masks[g])[..., None]
            write_exr(run / "renders" / sub / "hdr" / f"{g:05d}.exr", img.astype(np.float32))
    rep = mh.mover_report(run, clip)
    assert set(rep["renders"]) == {"train/hdr", "test/hdr"}
    tr, te = rep["renders"]["train/hdr"], rep["renders"]["test/hdr"]
    assert tr["frames"] == len(c.train_frames) and te["frames"] == len(c.test_frames)
    np.testing.assert_allclose(tr["quotient_q"], 0.1, rtol=1e-3)
    np.testing.assert_allclose(tr["movers_q"], 0.05, rtol=1e-3)
    np.testing.assert_allclose(te["quotient_q"], 1.0, rtol=1e-3)
    assert mh.main([str(run), str(clip)]) == 0
    assert "train/hdr: movers / still 0.100/0.100/0.100" in capsys.readouterr().out
