"""The scoring conventions printed under the tables (eval.experiments.score applies them): the PSNR
cap, the CRF sampling, the track sample count and one line per convention. Free of torch, so that
tables and the results page can name them without loading the scorer."""

from __future__ import annotations

from typing import Dict

PSNR_CAP_DB = 100.0
TRACK_SAMPLES = 256
CRF_LOG2_RANGE = (
    -10.0,
    10.0,
)  # the tone mapper's input axis range used by the authors' monotonicity penalty
CRF_SAMPLES = 81

SCORE_CONVENTIONS = {
    "psnr_cap": f"PSNR capped at {PSNR_CAP_DB:g} dB per image (identical images) before averaging",
    "depth_absrel_clip": "Depth AbsRel: rendered test z-depth vs GT, one median scale over all "
    "test frames, mean "
    "|s d - gt| / gt over gt > 0",
    "crf_rmse": f"CRF RMSE: learned tone curve vs the true CRF, RMSE over RGB and {CRF_SAMPLES} "
    "log2 exposures in "
    f"[{CRF_LOG2_RANGE[0]:g}, {CRF_LOG2_RANGE[1]:g}]",
    "track_first_frame": f"Tracks: up to {TRACK_SAMPLES} GT tracks visible at the first frame "
    "(seed 0), induced by "
    "the dynamic Gaussians' motion (model.track_2d)",
    "cameras_all_frames": "Cameras: Sim(3) alignment over every frame present in both trajectories",
    "hdr_tae_train": "HDR-TAE on the rendered training frames",
    "hdr_tae_interior": "HDR-TAE on the rendered training frames without occlusion-edge pixels "
    "(gt depth)",
    "dyn_masks": "Dynamic masks: the run's dynamic masks (config masks.method) vs GT dynamic "
    "masks on the training "
    "frames, pixel counts pooled over frames (precision, recall, IoU)",
    "nv_views": "Held-out views (nv_*): rendered at each test frame's time from the clip's view "
    "cameras, carried into the run's frame by the Umeyama similarity of its training-camera "
    "centres onto the true ones; LDR-OE / LDR-NE / HDR (mu-law, GT-max) per frame, means over "
    "frames, then levels, then views",
    "nv_masked": "Held-out views, mPSNR / mSSIM: MSE and the SSIM map averaged over the co-visible "
    "pixels only (surface seen by at least two training frames, gt/views/<view>/covis); "
    "covisible: their mean fraction of the view's surface pixels",
    "nv_dynamic": "Held-out views, dyn mPSNR: LDR-OE and mu-law HDR PSNR over the co-visible "
    "pixels of moving objects (covis and gt/views/<view>/masks/dynamic); frames without such "
    "pixels left out",
    "camera_motion": "Camera motion (clip.json gt.camera_motion): camera_deg_s, the camera's "
    "angular speed about its look-at point; scene_deg_s, the moving points' speed seen from the "
    "median look-at distance; emf, their ratio",
}


def all_conventions() -> Dict[str, str]:
    """eval.metrics.CONVENTIONS plus the scoring conventions of this module."""
    from eval.metrics import CONVENTIONS  # deferred: the metrics load torch

    return {**CONVENTIONS, **SCORE_CONVENTIONS}


# metrics that a clip where nothing moves has no value for (no dynamic pixels to score over or to
# recall, no moving points to measure the speed of): their absence from every run of such a scene
# says nothing about when the runs were scored
MOVING_CONTENT_KEYS = (
    "dyn_ldr_psnr",
    "dyn_hdr_psnr",
    "nv_ldr_oe_dyn_mpsnr",
    "nv_hdr_dyn_mpsnr",
    "mask_precision",
    "mask_recall",
    "mask_iou",
    "scene_deg_s",
    "emf",
)
