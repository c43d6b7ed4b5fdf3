"""Regression test for small bright movers (docs/method.md, "Small bright movers"): a disc 50 times
brighter than a textured plane crosses a still camera's view (bench/small_mover_bench.py draws it
with numpy; benchgen from-hdr makes the clip, with DIS-chained tracks that lose the disc). The
paper's method drops it (rendered at 0.04-0.09 of its true HDR over its pixels at the tiny preset,
three seeds, lab/notes/small-movers.md); `full-highlights`, `ns-2-chains-held` and
`ns-2-chains-held-rel` must render it within a factor 2 of the truth, in the training and the test
frames."""

from __future__ import annotations

import pytest


def _train_disc(
    tmp_path, load_bench, radius, overrides=None, contrast=50.0, variant="full-highlights"
):
    """Make the disc clip (radius px, 4 px a frame, `contrast` times the plane) and train
    `variant` on it at the tiny preset; returns (run folder, bench module)."""
    from m4dgs.core.threads import threads_for
    from m4dgs.training.pipeline import train

    smb = load_bench("small_mover_bench")
    smb.make_disc_clip(
        tmp_path, frames=24, width=160, height=96, radius=radius, speed=4.0, contrast=contrast
    )
    run = tmp_path / "run"
    with threads_for(device="cpu"):
        train(
            tmp_path / "clip", run, preset="tiny", variant=variant, overrides=overrides,
            device="cpu", progress=False,
        )  # fmt: skip
    return run, smb


# about 60-80 s each on 2 cores; the tracker itself is checked on these frames in
# tests/priors/test_highlight_tracks.py within the default run
@pytest.mark.slow
@pytest.mark.parametrize("variant", ["full-highlights", "ns-2-chains-held", "ns-2-chains-held-rel"])
def test_variant_renders_the_disc(tmp_path, load_bench, variant):
    """The highlight tracks (`full-highlights`), and the chains carrying the motion with the depth
    prior held along them and stage 2's velocity and acceleration terms off or relative to the
    neighbours (docs/method.md, "Small bright movers"). Measured at seed 0 for the last two: 0.94
    and 0.97 of the disc's HDR at the test frames, 0.96 and 0.99 at the training frames, the plane
    at 0.91 and 0.79."""
    run, smb = _train_disc(tmp_path, load_bench, radius=9.0, variant=variant)
    s = smb.score_run(run)
    for split in ("train", "test"):
        assert 0.5 <= s[f"{split}_disc_ratio"] <= 2.0, s
        # and the plane is not traded for it
        assert 0.5 <= s[f"{split}_bg_ratio"] <= 2.0, s


# about 75 s on 2 cores
@pytest.mark.slow
def test_highlight_masks_keep_a_small_disc_dynamic(tmp_path, load_bench):
    """A disc of 2.5 px radius: the flow-based dynamic masks barely cover it, so `full-highlights`
    alone classifies its Gaussians static at the hand-over and renders 0.02 of it (one seed,
    lab/notes/small-movers.md); with `masks.highlight_blobs` they stay dynamic (0.26 measured)."""
    import torch

    run, smb = _train_disc(tmp_path, load_bench, 2.5, {"masks.highlight_blobs": True})
    diag = torch.load(run / "model" / "camera_init.pt", weights_only=False)["diagnostics"]["masks"]
    assert diag["fraction_highlight"] > 0 and diag["fraction"] > diag["fraction_before_highlight"]
    s = smb.score_run(run)
    assert s["test_disc_ratio"] >= 0.1, s  # ~10x the variant without the masks
    assert 0.5 <= s["test_bg_ratio"] <= 2.0, s


# about 2 minutes on 2 cores
@pytest.mark.slow
def test_tlr_shoulder_keeps_a_bright_disc_from_running_away(tmp_path, load_bench):
    """A disc 350 times the plane reads code ~240 at the shortest exposure and clips at the two
    longer ones. With four times the tiny preset's stage-1 steps, `full-highlights` renders it
    4.5e17 times too bright after stage 1 (seed 0; seeds 1 and 2 overflow float32 and stop): past
    the tone curve's shoulder only TLR moves it, and TLR off in stage 1 keeps it at 0.98-1.04 (three
    seeds, lab/notes/hard-lit.md). With TLR left off the pixels past the shoulder
    (`loss.tlr_shoulder`, the variant `full-tlr-shoulder`) it stays within a factor 2."""
    shoulder = 250 / 255
    run, smb = _train_disc(
        tmp_path, load_bench, 9.0,
        {
            "stage1.iterations": 1200,
            "stage1.loss.tlr_shoulder": shoulder,
            "stage2.loss.tlr_shoulder": shoulder,
        },
        contrast=350.0,
    )  # fmt: skip
    s = smb.score_run(run)
    for split in ("stage1", "test"):
        assert 0.5 <= s[f"{split}_disc_ratio"] <= 2.0, s
        assert 0.5 <= s[f"{split}_bg_ratio"] <= 2.0, s
