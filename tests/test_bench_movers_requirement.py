"""bench/movers_requirement.py on a campaign root made here: the disc clip of
bench/small_mover_bench.py as the movers' scene, with test renders made from the truth (the disc's
pixels scaled to set the movers / still quotient) and metrics.json files that set the peak ratio."""

from __future__ import annotations

import json
import shutil

import numpy as np

from m4dgs.core.io import write_exr


def _run(run, clip, masks, movers_scale, peak):
    """A scored run: test renders = truth with the movers' pixels times movers_scale."""
    from m4dgs.clip import Clip

    c = Clip.open(clip)
    (run / "renders" / "test" / "hdr").mkdir(parents=True)
    for g in c.test_frames:
        img = c.load_gt_hdr(g) * np.where(masks[g], movers_scale, 1.0)[..., None]
        write_exr(run / "renders" / "test" / "hdr" / f"{g:05d}.exr", img.astype(np.float32))
    (run / "run.json").write_text(json.dumps({"clip": str(clip)}))
    (run / "metrics.json").write_text(json.dumps({"highlight_peak_ratio": peak}))


def _campaign(tmp_path, load_bench):
    """(the requirement module, the disc clip, its masks, the root, the suite's folder)."""
    smb = load_bench("small_mover_bench")
    clip = smb.make_disc_clip(tmp_path / "disc")
    masks = smb.write_dynamic_masks(tmp_path / "disc")
    root = tmp_path / "root"
    return load_bench("movers_requirement"), clip, masks, root, root / "runs" / "s"


def test_requirement_met_not_met_and_undecided(tmp_path, load_bench, capsys):
    mr, clip, masks, root, suite = _campaign(tmp_path, load_bench)
    # the movers' scene: both seeds keep the disc (quotient 1 and 0.6), peaks in the band
    _run(suite / "disc" / "v", clip, masks, 1.0, 1.1)
    _run(suite / "disc" / "v-seed-1", clip, masks, 0.6, 0.6)
    # another scene: no highlight pixels at seed 0 (NaN), in the band at seed 1
    _run(suite / "other" / "v", clip, masks, 1.0, float("nan"))
    _run(suite / "other" / "v-seed-1", clip, masks, 1.0, 1.9)
    rep = mr.check(root, ["s"], "v", seeds=2, movers=("disc",))
    assert rep["verdict"] == "met", rep
    disc = [r for r in rep["runs"] if r["scene"] == "disc"]
    np.testing.assert_allclose([r["quotient_median"] for r in disc], [1.0, 0.6], rtol=1e-3)
    assert [r["peak_in_band"] for r in rep["runs"] if r["scene"] == "other"] == [None, True]
    assert mr.main([str(root), "s", "--row", "v", "--movers", "disc"]) == 0
    assert "requirement for v: met" in capsys.readouterr().out

    # a seed that keeps 0.4 of the disc's radiance loses the mover; a peak at 2.5 is out of band
    shutil.rmtree(suite / "disc" / "v-seed-1")
    _run(suite / "disc" / "v-seed-1", clip, masks, 0.4, 1.0)
    (suite / "other" / "v-seed-1" / "metrics.json").write_text(
        json.dumps({"highlight_peak_ratio": 2.5})
    )
    rep = mr.check(root, ["s"], "v", seeds=2, movers=("disc",))
    assert rep["verdict"] == "not met" and rep["movers_kept"] == {"disc": False}
    assert rep["out_of_band"] == ["s/other seed 1"]
    assert mr.main([str(root), "s", "--row", "v", "--movers", "disc"]) == 1

    # an unscored run leaves it undecided, as does a movers' scene with no run
    (suite / "other" / "v-seed-1" / "metrics.json").unlink()
    assert mr.check(root, ["s"], "v", seeds=2, movers=("disc",))["verdict"] == "undecided"
    assert mr.main([str(root), "s", "--row", "v", "--movers", "disc,bulb"]) == 2


def test_later_seeds_and_the_resolved_peak(tmp_path, load_bench, capsys):
    """--first-seed 2 reads the folders <row>-seed-2 and -3 only; --peak reads the named ratio."""
    mr, clip, masks, root, suite = _campaign(tmp_path, load_bench)
    _run(suite / "disc" / "v", clip, masks, 0.1, 1.0)  # seed 0 loses the disc: not counted
    for seed in (2, 3):
        run = suite / "disc" / f"v-seed-{seed}"
        _run(run, clip, masks, 0.9, 1.0)
        # the plain peak out of the band, the resolved one in it
        m = {"highlight_peak_ratio": 4.0, "highlight_peak_ratio_resolved": 1.3}
        (run / "metrics.json").write_text(json.dumps(m))
    rep = mr.check(root, ["s"], "v", seeds=2, movers=("disc",), first_seed=2)
    assert [r["seed"] for r in rep["runs"]] == [2, 3] and rep["verdict"] == "not met"
    assert rep["out_of_band"] == ["s/disc seed 2", "s/disc seed 3"]
    rep = mr.check(
        root, ["s"], "v", 2, ("disc",), first_seed=2, peak_key="highlight_peak_ratio_resolved"
    )
    assert rep["verdict"] == "met" and rep["movers_kept"] == {"disc": True}
    args = [str(root), "s", "--row", "v", "--movers", "disc", "--first-seed", "2"]
    assert mr.main(args + ["--peak", "highlight_peak_ratio_resolved"]) == 0
    assert "requirement for v: met" in capsys.readouterr().out
    assert mr.main(args) == 1
    assert mr.main(args[:-2]) == 2  # seeds 0-1: seed 1 has no run, nothing is decided
