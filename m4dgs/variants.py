"""Named variants: the full method, the paper's ablations and the adapted baselines, as config overrides.

Every variant is a dict of dotted config overrides applied on top of a preset (m4dgs.config.apply_overrides).
The baselines are the paper's comparison methods re-implemented inside this code base with the same priors, cameras,
tone mapper and rasterizer, so they are "adapted" (named after the style they follow), not the original programs.
"""
from __future__ import annotations

from typing import Any, Dict

VARIANTS: Dict[str, Dict[str, Any]] = {
    "full": {},
    # paper Table "ablation" rows (a)-(e); N_s in its own table
    "no-video-init": {"ablation.use_video_init": False},  # (a) world Gaussians from lifted tracks/depth
    "no-occlusion": {"ablation.occlusion_handling": False},  # (b) V2W without occlusion handling
    "no-cov-invariance": {"ablation.cov_invariance": False},  # (c) inherit video scales
    "no-reproj": {"ablation.reproj_loss": False},  # (d) without the HDR photometric reprojection loss
    "no-tlr": {"ablation.tlr": False},  # (e) without temporal luminance regularisation
    "ns-1": {"model.control_every": 1},
    "ns-2": {"model.control_every": 2},
    "ns-4": {"model.control_every": 4},
    "ns-8": {"model.control_every": 8},
    "ns-16": {"model.control_every": 16},
    "no-depth-loss": {"ablation.depth_loss": False},
    "no-track-loss": {"ablation.track_loss": False},
    # dynamic masks from the paper's epipolar test alone (the tiny/small presets OR in the rigidity test, m4dgs.rigidity)
    "epipolar-masks": {"masks.method": "epipolar"},
    # adapted baselines (paper sec. 4.2)
    "static-hdr": {"method": "static-hdr", "ablation.use_video_init": False, "ablation.reproj_loss": False,
                   "ablation.tlr": False, "ablation.track_loss": False, "stage2.optimize_cameras": False},
    "world-only": {"method": "world-only", "ablation.use_video_init": False, "ablation.reproj_loss": False,
                   "ablation.tlr": False},
    "ldr-reproj": {"method": "ldr-reproj", "ablation.use_video_init": False, "ablation.reproj_loss": False,
                   "ablation.tlr": False},
}

DESCRIPTIONS: Dict[str, str] = {
    "full": "Mono4DGS-HDR: video Gaussians, V2W transform, world Gaussians with camera refinement, TLR, HDR reprojection",
    "no-video-init": "ablation (a): no video-Gaussian stage; world Gaussians initialised from lifted tracks and depth",
    "no-occlusion": "ablation (b): V2W dynamic/static identification without occlusion handling",
    "no-cov-invariance": "ablation (c): V2W inherits the video scales instead of the 2D-covariance refit",
    "no-reproj": "ablation (d): no HDR photometric reprojection loss in stage 2",
    "no-tlr": "ablation (e): no temporal luminance regularisation",
    "no-depth-loss": "prior ablation: no depth loss",
    "no-track-loss": "prior ablation: no flow/track loss",
    "epipolar-masks": "dynamic masks from the epipolar test alone (sec. 3.2 as written), no rigidity test",
    "static-hdr": "baseline (GaussHDR-style): static HDR Gaussians with the bundle-adjustment cameras (fixed)",
    "world-only": "baseline (MoSca-HDR-style): dynamic world Gaussians from lifted priors, camera refinement by RGB/flow only",
    "ldr-reproj": "baseline (SplineGS-HDR-style): world-only plus an LDR photometric reprojection loss on the cameras",
}
for _n in (1, 2, 4, 8, 16):
    DESCRIPTIONS[f"ns-{_n}"] = f"control-point interval N_s = {_n} frames" + (" (the paper's default)" if _n == 4 else "")


def describe(name: str) -> str:
    if name not in VARIANTS:
        raise KeyError(f"unknown variant {name!r} (known: {', '.join(VARIANTS)})")
    return DESCRIPTIONS.get(name, name)


def overrides_for(name: str) -> Dict[str, Any]:
    if name not in VARIANTS:
        raise KeyError(f"unknown variant {name!r} (known: {', '.join(VARIANTS)})")
    return dict(VARIANTS[name])
