"""Named variants: the full method, the paper's ablations and the adapted baselines, as config
overrides.

Every variant is a dict of dotted config overrides applied on top of a preset
(m4dgs.training.config.apply_overrides). The baselines are the paper's comparison methods
re-implemented inside this code base with the same priors, cameras, tone mapper and rasterizer, so
they are "adapted" (named after the style they follow), not the original programs.

Iteration budget: the paper trains every experiment, ablations and baselines included, for the same
15K iterations (4K stage 1 + 11K stage 2). A variant without stage 1 (`ablation.use_video_init:
False`: ablation (a) and the baselines) therefore spends stage 1's iterations in stage 2
(`variant_config`, `stage2_only_budget`), so that every variant's stage-1 + stage-2 total equals
full's within a preset (`budget`; `m4dgs variants --preset P` prints it). The budget counts
optimisation iterations of the two stages; the tone-mapper pre-training and the V2W scale refit are
not counted (full does both as well)."""

from __future__ import annotations

import copy
from typing import Any, Dict, Mapping, Optional, Tuple

# beyond the paper: N_s = 2 with the highlight chains carrying the motion in stage 1
# (stage1.init.highlight_motion), for small fast bright movers; the variants ns-2-chains,
# ns-2-chains-free, ns-2-chains-held and ns-2-chains-held-rel (lab/notes/hard-lit.md, "Stage 2's
# smoothness terms and the fast movers")
_NS2_CHAINS: Dict[str, Any] = {"model.control_every": 2, "stage1.init.highlight_motion": True}
_NS2_CHAINS_FREE: Dict[str, Any] = {
    **_NS2_CHAINS,
    "stage2.loss.lambda_vel": 0.0,
    "stage2.loss.lambda_acc": 0.0,
}

VARIANTS: Dict[str, Dict[str, Any]] = {
    "full": {},
    # paper Table "ablation" rows (a)-(e); N_s in its own table
    # (a) world Gaussians from lifted tracks/depth
    "no-video-init": {"ablation.use_video_init": False},
    "no-occlusion": {"ablation.occlusion_handling": False},  # (b) V2W without occlusion handling
    "no-cov-invariance": {"ablation.cov_invariance": False},  # (c) inherit video scales
    # (d) without the HDR photometric reprojection loss
    "no-reproj": {"ablation.reproj_loss": False},
    "no-tlr": {"ablation.tlr": False},  # (e) without temporal luminance regularisation
    "ns-1": {"model.control_every": 1},
    "ns-2": {"model.control_every": 2},
    "ns-4": {"model.control_every": 4},
    "ns-8": {"model.control_every": 8},
    "ns-16": {"model.control_every": 16},
    "no-depth-loss": {"ablation.depth_loss": False},
    "no-track-loss": {"ablation.track_loss": False},
    # dynamic masks from the paper's epipolar test alone (the tiny/small presets OR in the rigidity
    # test, m4dgs.priors.rigidity)
    "epipolar-masks": {"masks.method": "epipolar"},
    # beyond the paper: the full method plus tracks of the video's bright blobs at the
    # initialisation (m4dgs.priors.highlight_tracks), for small bright movers
    "full-highlights": {"stage1.init.highlight_tracks": True},
    # beyond the paper: the full method plus a grey brightness gain over time on every Gaussian
    # (model.appearance_knots), for scenes whose light moves (lab/notes/relighting.md). 8 knots
    # over the training frames: the relit scenes' clips have 100 frames (50 training frames), so a
    # knot every 7 training frames, 14 clip frames. The fastest relighting among them is the bulb
    # swinging at 0.55 Hz (scenes/bare-bulb-swing-handheld.yaml: a 55-frame period at 30 fps, a
    # point under its arc lit twice per period), about two knots per rise or fall; denser knots
    # would come closer to the 3-frame exposure cycle, which a gain must not follow
    "full-relight": {"model.appearance_knots": 8},
    # beyond the paper: the full method with V2W fitting each dynamic Gaussian's world spline to its
    # stage-1 pixel path (errors across the camera ray in pixels, along it as a depth tolerance)
    # instead of to its lifted world path (m4dgs.training.v2w.pixel_weights), for small fast movers
    # whose jittery lifted depth throws the world fit off them (lab/notes/hard-lit.md)
    "full-pixel-fit": {"v2w.world_fit": "pixel"},
    # beyond the paper: the full method with TLR left off the pixels whose render is past the tone
    # curve's shoulder at their frame's exposure (loss.tlr_shoulder, 250 / 255), in both stages,
    # so that TLR cannot drive a bright highlight that no frame can check (lab/notes/hard-lit.md)
    "full-tlr-shoulder": {
        "stage1.loss.tlr_shoulder": 250 / 255,
        "stage2.loss.tlr_shoulder": 250 / 255,
    },
    # beyond the paper (_NS2_CHAINS above); the same without the velocity and acceleration terms in
    # stage 2, which charge a mover's own speed and curvature; and that with the depth prior held at
    # each chain's median around the chain, where a mover's prior depth jumps with its background
    "ns-2-chains": dict(_NS2_CHAINS),
    "ns-2-chains-free": dict(_NS2_CHAINS_FREE),
    "ns-2-chains-held": {**_NS2_CHAINS_FREE, "stage1.init.highlight_depth": True},
    # beyond the paper: ns-2-chains with the held depth, stage 2's velocity and acceleration terms
    # kept at the paper's weights but on each Gaussian's motion relative to its ARAP neighbours'
    # (loss.smooth_relative), which a group moving as one does not pay
    "ns-2-chains-held-rel": {
        **_NS2_CHAINS,
        "stage1.init.highlight_depth": True,
        "stage2.loss.smooth_relative": True,
    },
    # adapted baselines (paper sec. 4.2)
    "static-hdr": {
        "method": "static-hdr",
        "ablation.use_video_init": False,
        "ablation.reproj_loss": False,
        "ablation.tlr": False,
        "ablation.track_loss": False,
        "stage2.optimize_cameras": False,
    },
    # ablation (a) without TLR (method "world-only" changes nothing else: no stage 1 means no HDR
    # reprojection loss)
    "world-only": {
        "method": "world-only",
        "ablation.use_video_init": False,
        "ablation.reproj_loss": False,
        "ablation.tlr": False,
    },
    # world-only + an LDR photometric reprojection loss on the cameras, between frames of the SAME
    # exposure (i +- N_e)
    "ldr-reproj": {
        "method": "ldr-reproj",
        "ablation.use_video_init": False,
        "ablation.reproj_loss": False,
        "ablation.tlr": False,
        "stage2.ldr_reproj_pairs": "same-exposure",
    },
    # the same between CONSECUTIVE, differently exposed frames (i +- 1): the paper's SplineGS-HDR
    # failure mode
    "ldr-reproj-consecutive": {
        "method": "ldr-reproj",
        "ablation.use_video_init": False,
        "ablation.reproj_loss": False,
        "ablation.tlr": False,
        "stage2.ldr_reproj_pairs": "consecutive",
    },
}

DESCRIPTIONS: Dict[str, str] = {
    "full": "Mono4DGS-HDR: video Gaussians, V2W transform, world Gaussians with camera "
    "refinement, TLR, HDR reprojection",
    "no-video-init": "ablation (a): no video-Gaussian stage; world Gaussians initialised from "
    "lifted tracks and depth "
    "(no stage-1 HDR frames, hence no HDR reprojection loss either)",
    "no-occlusion": "ablation (b): V2W dynamic/static identification without occlusion handling",
    "no-cov-invariance": "ablation (c): V2W inherits the video scales instead of the "
    "2D-covariance refit",
    "no-reproj": "ablation (d): no HDR photometric reprojection loss in stage 2",
    "no-tlr": "ablation (e): no temporal luminance regularisation",
    "no-depth-loss": "prior ablation: no depth loss",
    "no-track-loss": "prior ablation: no flow/track loss",
    "epipolar-masks": "dynamic masks from the epipolar test alone (sec. 3.2 as written), no "
    "rigidity test",
    "full-highlights": "BEYOND THE PAPER: full plus Gaussians lifted from tracks of the video's "
    "bright blobs (small bright movers that point tracks lose; docs/method.md)",
    "full-relight": "BEYOND THE PAPER: full plus a grey brightness gain over time on every "
    "Gaussian (a smooth curve through 8 knots, its curvature penalised), for scenes whose moving "
    "light relights static surfaces (docs/method.md)",
    "full-pixel-fit": "BEYOND THE PAPER: full with V2W fitting each moving Gaussian's world "
    "spline to the pixels stage 1 left it at rather than to its lifted world path, so that small "
    "fast movers keep their place at the hand-over (docs/v2w.md)",
    "full-tlr-shoulder": "BEYOND THE PAPER: full with the temporal luminance regularisation left "
    "off the pixels whose render is past the tone curve's shoulder (LDR >= 250/255 at the frame's "
    "exposure), where it alone would set their brightness, for bright highlights that run away "
    "(docs/method.md)",
    "ns-2-chains": "BEYOND THE PAPER: N_s = 2, with the tracks of the video's bright blobs in "
    "place of the point tracks and flow that follow them in stage 1, for small fast bright movers "
    '(docs/method.md, "Small bright movers")',
    "ns-2-chains-free": "BEYOND THE PAPER: ns-2-chains with stage 2's velocity and acceleration "
    "terms off (lambda_vel = lambda_acc = 0), which charge a fast mover's own motion "
    '(docs/method.md, "Small bright movers")',
    "ns-2-chains-held": "BEYOND THE PAPER: ns-2-chains-free with the depth prior held at each "
    "bright blob's median around it, in stage 1 and stage 2's depth term, where a small mover's "
    "prior depth jumps with what lies behind it; the option for footage with small fast bright "
    'movers, with a flicker cost (docs/method.md, "Small bright movers")',
    "ns-2-chains-held-rel": "BEYOND THE PAPER: ns-2-chains-held with stage 2's velocity and "
    "acceleration terms back at the paper's weights, on each Gaussian's motion relative to its 5 "
    "ARAP neighbours' (loss.smooth_relative), so that a mover's own speed is not charged "
    '(docs/method.md, "Small bright movers")',
    "static-hdr": "baseline (GaussHDR-style): static HDR Gaussians with the bundle-adjustment "
    "cameras (fixed)",
    "world-only": "ablation (a) without TLR: world Gaussians from lifted tracks/depth (no stage "
    "1, hence no HDR "
    "reprojection loss), no temporal luminance regularisation; cameras refined by the "
    "RGB/depth/flow "
    "losses",
    "ldr-reproj": "world-only plus an LDR photometric reprojection loss between SAME-exposure "
    "frames i +- N_e (this "
    "sidesteps the exposure change that the paper blames for SplineGS-HDR's failure)",
    "ldr-reproj-consecutive": "baseline (SplineGS-HDR-style, the paper's form): world-only plus "
    "an LDR photometric "
    "reprojection loss between CONSECUTIVE, differently exposed frames i +- 1",
}
for _n in (1, 2, 4, 8, 16):
    DESCRIPTIONS[f"ns-{_n}"] = f"control-point interval N_s = {_n} frames" + (
        " (the paper's default)" if _n == 4 else ""
    )


def describe(name: str) -> str:
    if name not in VARIANTS:
        raise KeyError(f"unknown variant {name!r} (known: {', '.join(VARIANTS)})")
    return DESCRIPTIONS.get(name, name)


def overrides_for(name: str) -> Dict[str, Any]:
    if name not in VARIANTS:
        raise KeyError(f"unknown variant {name!r} (known: {', '.join(VARIANTS)})")
    return dict(VARIANTS[name])


# --------------------------------------------------------------------------------------------------
# iteration budgets
# --------------------------------------------------------------------------------------------------
def _scaled(step: int, factor: float) -> int:
    return int(round(step * factor))


def stage2_only_budget(cfg):
    """A copy of `cfg` (m4dgs.training.config.TrainConfig) for a run without stage 1: stage 2 gets
    the stage-1 + stage-2 iterations and stage1.iterations becomes 0 (nothing is trained there). A
    config whose stage 1 is already 0 is returned unchanged (idempotent).

    Stage 2's schedules scale with its longer length so that the phases keep the proportions of
    full's stage 2:
      - phase ends scale by f = new / old stage-2 length: densification stop (static and dynamic),
        an explicit loss.tlr_start (the default, the densification stop, follows by itself) and
        pr_steps (the reprojection-loss window, also used by the LDR reprojection baselines).
        Paper: densify until 8K of 11K -> 10 909 of 15K, TLR over the last 4 091 iterations (full:
        the last 3K of stage 2 plus the last 1K of stage 1).
      - the position learning rate decays log-linearly over stage2.iterations (3DGS), so it spans
        the whole budget.
      - cadences stay in iterations: densification warm-up (start_iter), interval (every), opacity
        reset interval (reset_every) and the removal of misplaced dynamic Gaussians
        (dynamic_removal_every). Gradient statistics are accumulated over `every` steps and an
        opacity reset needs the same number of steps to recover whatever the stage length; the
        longer window then holds proportionally more densification events, as full gets its extra
        events in stage 1.
    """
    s1, s2 = cfg.stage1, cfg.stage2
    if s1.iterations <= 0 or s2.iterations <= 0:
        return cfg
    out = copy.deepcopy(cfg)
    o1, o2 = out.stage1, out.stage2
    total = s1.iterations + s2.iterations
    f = total / s2.iterations
    o2.iterations, o1.iterations = total, 0
    for d in (o2.densify_static, o2.densify_dynamic):
        d.stop_iter = min(_scaled(d.stop_iter, f), total)
    if o2.loss.tlr_start is not None:
        o2.loss.tlr_start = _scaled(o2.loss.tlr_start, f)
    if o2.pr_steps is not None:
        o2.pr_steps = _scaled(o2.pr_steps, f)
    return out


def variant_config(
    preset: str, variant: str = "full", overrides: Optional[Mapping[str, Any]] = None
):
    """The resolved TrainConfig of a variant: preset defaults, the variant's overrides, the budget
    transfer of a run without stage 1 (`stage2_only_budget`), then the user's overrides (which win:
    an explicit --set stage2.iterations=N is kept). The budget transfer also applies when the user's
    overrides switch stage 1 off."""
    from m4dgs.training.config import apply_overrides, upgrade_overrides
    from m4dgs.training.config import preset as make_preset

    cfg = apply_overrides(make_preset(preset), overrides_for(variant))
    user = upgrade_overrides(overrides or {})  # older keys: one warning each, here
    if not apply_overrides(cfg, user).ablation.use_video_init:
        cfg = stage2_only_budget(cfg)
    return apply_overrides(cfg, user) if user else cfg


def budget(preset: str, variant: str = "full") -> Tuple[int, int, int]:
    """(stage-1, stage-2, total) optimisation iterations of a variant under a preset (stage 1 = 0
    when skipped)."""
    cfg = variant_config(preset, variant)
    s1 = cfg.stage1.iterations if cfg.ablation.use_video_init else 0
    return s1, cfg.stage2.iterations, s1 + cfg.stage2.iterations


def stage1_plan(
    preset: str, variant: str, overrides: Optional[Mapping[str, Any]] = None, clip: str = ""
) -> Tuple[Optional[str], int, int]:
    """(stage-1 share key, stage-1 iterations, stage-2 iterations) of a run: runs with one key
    compute one stage 1 (with camera initialisation) through a share folder
    (m4dgs.training.phases.phase_keys over the resolved configuration; `clip` stands for the
    clip, the rest of the real key's context being the same for the runs of one experiment
    root). The key is None for a variant without stage 1."""
    return run_plan(preset, variant, overrides, clip)[:3]


def training_key(
    preset: str, variant: str, overrides: Optional[Mapping[str, Any]] = None, clip: str = ""
) -> str:
    """The share key of a run's whole training (its stage-2 phase key: every field of every phase
    up to stage 2, and the variant): two runs with one key train once, the second finding the
    first's model in the share folder (`clip` stands for the clip, as in stage1_plan)."""
    return run_plan(preset, variant, overrides, clip)[3]


def run_plan(
    preset: str, variant: str, overrides: Optional[Mapping[str, Any]] = None, clip: str = ""
) -> Tuple[Optional[str], int, int, str]:
    """stage1_plan's (stage-1 key, stage-1 iterations, stage-2 iterations) and training_key,
    from one resolution of the configuration."""
    from m4dgs.training.config import to_dict
    from m4dgs.training.phases import phase_keys

    cfg = variant_config(preset, variant, overrides)
    keys = phase_keys(to_dict(cfg), {"clip": str(clip)}, variant)
    if not cfg.ablation.use_video_init:
        return None, 0, int(cfg.stage2.iterations), keys["stage2"]
    return keys["stage1"], int(cfg.stage1.iterations), int(cfg.stage2.iterations), keys["stage2"]
