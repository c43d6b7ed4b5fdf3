"""Training configuration: dataclasses carrying the paper's defaults, presets, YAML round trip and
overrides.

Sections (each group cites the paper section its defaults come from; "authors' code" marks choices
the paper leaves open, filled from the authors' released code, LiuJF1226/Mono4DGS-HDR):

    TrainConfig
      model        ModelConfig        Gaussian representation (N_s, features, scale activations,
                                      rotation init)
      stage1       Stage1Config       video Gaussians: iterations, densification, learning rates,
                                      init; stage1.loss (LossConfig) its loss weights and details
      v2w          V2WConfig          video-to-world transform
      stage2       Stage2Config       world Gaussians + cameras; stage2.loss (LossConfig) and the
                                      stage-2 terms (HDR / LDR reprojection, dynamic removal)
      tonemap      ToneMapConfig      tone mapper / colour MLP sizes and pre-training
      exposure     ExposureConfig     clip-derived values (unit-exposure target) and the
                                      exposure-perturbation study
      ablation     AblationConfig     the paper's ablation switches
      camera_init, epipolar, masks    priors-side configs owned by m4dgs.priors.camera_init /
                                      m4dgs.priors.epipolar / m4dgs.priors.rigidity

Presets: `tiny` (unit tests: tens of iterations, tiny images), `small` (CPU, 216x120), `paper`
(864x480, 4K + 11K iterations). `to_dict` / `from_dict` round-trip through YAML (`from_dict` names
an unknown key with its full dotted path); `apply_overrides(cfg, {"stage1.loss.lambda_tlr": 0,
"model.control_every": 8})` builds a variant.

String options with a fixed set of values are typed `Literal[...]`: a value outside the set is
rejected with the key and the allowed values when a config is built, loaded or overridden
(`validate`). Keys of older configs (the loss weights directly under stage1 / stage2, e.g.
`stage1.lambda_dep`) are mapped to their new place (`stage1.loss.lambda_dep`) with a one-line
FutureWarning; keys that were removed because nothing read them are ignored with a warning; a
key renamed because its value's meaning changed gets the converted value (`LEGACY_KEYS`,
`REMOVED_KEYS`, `RENAMED_VALUE_KEYS`, `upgrade_dict`)."""

from __future__ import annotations

import copy
import dataclasses
import math
import typing
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Literal, Mapping, Optional, Tuple

import yaml

from m4dgs.core.errors import InputError
from m4dgs.core.io import parse_yaml, write_text_atomic
from m4dgs.model.gaussians import ModelConfig, VideoInitConfig
from m4dgs.priors.camera_init import CameraInitConfig
from m4dgs.priors.epipolar import EpipolarConfig
from m4dgs.priors.rigidity import DynamicMaskConfig
from m4dgs.training.densify import DensifyConfig


class ConfigError(InputError):
    """A config value outside its allowed values (a ValueError; the tools report it in one line)."""


class ConfigKeyError(ConfigError, KeyError):
    """An unknown config key (also a KeyError, as before it was a project error)."""

    def __str__(self) -> str:  # KeyError's own str() quotes the message
        return str(self.args[0]) if self.args else ""


class ConfigTypeError(ConfigError, TypeError):
    """A config value of the wrong type (also a TypeError, as before it was a project error)."""


def _unknown_key(path: str, section: Any, key: str, override: str = "") -> ConfigKeyError:
    """The error for an unknown key `key` of the dataclass `section` (None: not a section), at
    dotted path `path` (of the override `override`, when longer): the valid keys there and the
    closest one when one is near."""
    import difflib

    names = sorted(f.name for f in dataclasses.fields(section)) if section is not None else []
    near = difflib.get_close_matches(key, names, n=1)
    hint = f"; did you mean '{near[0]}'?" if near else ""
    valid = f" (valid keys there: {', '.join(names)})" if names else ""
    within = f" in override '{override}'" if override and override != path else ""
    return ConfigKeyError(f"unknown config key '{path}'{within}{hint}{valid}")


# typed choices of the string options (validated by `validate`, `from_dict`, `apply_overrides`)
PresetName = Literal["tiny", "small", "paper"]
# "mono4dgs" (the method) or an adapted baseline of the paper's comparisons
# (m4dgs.training.variants)
Method = Literal["mono4dgs", "static-hdr", "world-only", "ldr-reproj"]
RasterBackend = Literal["auto", "gsplat", "cpu", "torch"]  # m4dgs.raster.BACKENDS
PrQuery = Literal["stage1", "render"]
LdrReprojPairs = Literal["same-exposure", "consecutive"]
DynamicRemovalScope = Literal["new", "densified", "all"]
CloneSplitExtent = Literal["cameras", "absolute"]
V2WResample = Literal["lstsq", "sample"]
V2WWorldFit = Literal["world", "pixel"]
ColorDirection = Literal["view", "reflected"]  # m4dgs.model.color.DIRECTIONS

PRESETS: Tuple[str, ...] = typing.get_args(PresetName)
LDR_REPROJ_PAIRS: Tuple[str, ...] = typing.get_args(LdrReprojPairs)


# --------------------------------------------------------------------------------------------------
# sections
# --------------------------------------------------------------------------------------------------
@dataclass
class LRConfig:
    """Learning rates (appendix "Implementation Details": static attributes as 3DGS, dynamic ones
    and cameras as MoSca, MLPs 5e-4; values from the authors' code)."""

    position_init: float = 1.6e-4  # exponential decay from init to final over the stage (3DGS)
    position_final: float = 1.6e-6
    position_delay_mult: float = 1.0  # 3DGS warm-up multiplier (1.0 = none)
    rotation: float = 1e-3
    scale: float = 5e-3
    opacity: float = 5e-2
    features: float = 2.5e-3
    mlp: float = 5e-4  # tone-mapper and colour MLPs (paper)
    adam_eps: float = 1e-15
    # stage 2 (authors' code); the focal length stays fixed in stage 2 (authors' code: its learning
    # rate is 0), so it has none
    camera_rotation: float = 3e-5
    camera_translation: float = 3e-5
    # dynamic Gaussians of stage 2 (appendix "Implementation Details": "the learning rates of
    # dynamic Gaussian attributes ... are following MoSca"): spline control points (same 3DGS
    # decay shape, x scene extent) and rotation polynomial coefficients. The paper gives no
    # numbers; these are the authors' code's, which equal the static ones
    dynamic_position_init: float = 1.6e-4
    dynamic_position_final: float = 1.6e-6
    dynamic_rotation: float = 1e-3
    # beyond the paper: the knot values of the per-Gaussian log2 gain over time
    # (model.appearance_knots > 0; unused otherwise). This project's choice: 1e-2 stops a step, a
    # 0.7 % change of brightness, so that one step stays below what an 8-bit frame tells apart,
    # while a knot, which the steps on frames within a knot interval or two of it move (at 8
    # knots over 50 training frames over a quarter of the small preset's 3,000 stage-1 steps),
    # can still travel the 3-3.5 stops of the relit scenes. The 300 + 300 steps of the tiny preset
    # follow a 2-stop ramp to within 0.3 stops with it (tests/training/test_relit_plane.py; 3e-2:
    # 0.1 stops)
    gain: float = 1e-2
    # beyond the paper, stage 2 only (stage 1's video Gaussians are one set): the rate of the
    # dynamic set's gain knots; None = `gain`. A glint on a moving object needs its gain to travel
    # 4-8 stops on the one or two frames that show each flare, further than `gain` lets it in the
    # small preset's steps, while raising every Gaussian's rate makes the static ones flicker
    # (lab/notes/hard-lit.md, "What holds the glints' peak")
    dynamic_gain: Optional[float] = None

    def position_lr(self, step: int, max_steps: int, dynamic: bool = False) -> float:
        """3DGS exponential decay: log-linear from position_init (step 0) to position_final (step
        max_steps), with the optional warm-up multiplier position_delay_mult ramping up over the
        first 1% of the steps; `dynamic`: from dynamic_position_init to dynamic_position_final."""
        init, final = (
            (self.dynamic_position_init, self.dynamic_position_final)
            if dynamic
            else (self.position_init, self.position_final)
        )
        if max_steps <= 0:
            return init
        u = min(max(step / max_steps, 0.0), 1.0)
        lr = math.exp((1.0 - u) * math.log(init) + u * math.log(final))
        if self.position_delay_mult < 1.0:
            delay = max(int(0.01 * max_steps), 1)
            lr *= self.position_delay_mult + (1.0 - self.position_delay_mult) * math.sin(
                0.5 * math.pi * min(step / delay, 1.0)
            )
        return lr


@dataclass
class LossConfig:
    """Weights and details of the loss terms both stages share (paper sec. 3.3.3 "Overall Loss";
    weights from appendix "Implementation Details", lambda_d from appendix "LDR RGB Loss"). A term
    with weight 0 is not computed. The objective itself: m4dgs.training.objective."""

    lambda_rgb: float = 1.0
    lambda_dssim: float = 0.2  # lambda_d: L_rgb = lambda_d DSSIM + (1 - lambda_d) L1
    lambda_ue: float = 10.0
    lambda_dep: float = 1.0
    lambda_track: float = 0.01
    lambda_arap: float = 0.01
    lambda_vel: float = 10.0
    lambda_acc: float = 10.0
    lambda_tlr: float = 0.1
    # extra terms of the authors' code, off by default (paper does not list them): opacity -> 1
    # (authors 1.0), scale standard deviation (authors 10.0)
    lambda_opacity: float = 0.0
    lambda_scale_std: float = 0.0
    # beyond the paper (0 = off): the mean over Gaussians of smallest scale / largest scale, which
    # flattens each Gaussian into a disc so that its smallest-scale axis is a surface normal
    # (the direction tonemap.color_direction = "reflected" mirrors about); no source for a weight
    lambda_flat: float = 0.0
    arap_k: int = 5  # k nearest neighbours of the ARAP loss (appendix "Rigidity Constraint")
    # per-iteration probability of flow (vs track) supervision (appendix "Flow/Track Loss")
    flow_prob: float = 0.5
    # velocity / acceleration window (appendix "Gaussian Motion Regularization"): frames i - w ..
    # i + w (w = smooth_half_width) around query frame i, cut at the clip's ends; -1 = every frame
    # of the clip (the paper's sum over t). Default +-2 (5 frames), the authors' code; a window
    # costs 5 spline evaluations of the subset per iteration instead of T
    smooth_half_width: int = 2
    # beyond the paper (off = the paper): the velocity and acceleration terms charge each Gaussian's
    # motion relative to the mean of its arap_k nearest neighbours' (the ARAP sets at the query
    # frame) instead of its own, so that a group that moves as one (a small fast mover's Gaussians)
    # is free and its members' jitter against one another is not (m4dgs.losses.motion)
    smooth_relative: bool = False
    # the motion regularisers (ARAP, velocity, acceleration) look at a random subset of this many
    # moving Gaussians per iteration (0 = all; not in the paper, which averages over every
    # Gaussian; the subset is an unbiased estimate of that mean at a fixed cost per iteration)
    motion_subset: int = 4096
    # first step of the TLR loss; None = after densification (sec. 3.3.3; the stage config's
    # tlr_start_step says which densification)
    tlr_start: Optional[int] = None
    tlr_occlusion_ratio: float = 1.1  # authors' code: depth-order occlusion test at 1.1x depth
    # TLR's gradient reaches the neighbour frame's render too (sec. 3.3.3 stops the gradient of the
    # rendered flow only; off: the neighbour render carries no gradient, as this code always did;
    # docs/method.md, departure 8)
    tlr_neighbour_grad: bool = False
    # beyond the paper: a floor added to TLR's denominator, as a fraction of the query render's
    # median HDR value (detached). 0 = the paper's normalisation (H_w + H_t). The normalised L1
    # gives every pixel a push of the same size in log HDR, so near-black pixels, whose values
    # 8-bit frames barely constrain, take most of the gradient in linear HDR; a floor of ~1 % of
    # the median weights them down (docs/method.md, "Options beyond the paper")
    tlr_den_floor: float = 0.0
    # beyond the paper: TLR leaves out the pixels whose tone-mapped render at the query frame's
    # own exposure is at or above this LDR value in any channel (detached); None = every pixel (the
    # paper's). Past the tone curve's shoulder the photometric term's gradient vanishes while TLR's,
    # normalised in log HDR, does not, so TLR alone moves those values, and on a bright mover it
    # can drive them up without bound (lab/notes/hard-lit.md). 250 / 255 leaves TLR on every pixel
    # that the frame can still check (docs/method.md, "Options beyond the paper")
    tlr_shoulder: Optional[float] = None
    # beyond the paper, only with a gain over time (model.appearance_knots > 0; no term without
    # one): the mean over Gaussians of the squared second differences of each Gaussian's log2-gain
    # knot values, in stops^2. It leaves a constant and a straight ramp in stops free and charges
    # curvature, so that a Gaussian does not flicker its brightness to fake what motion, another
    # Gaussian or a frame's exposure should explain. This project's choice: at 0.1 a curvature of
    # one stop at every knot costs about what the RGB loss of a fitted frame does (0.05-0.1). On
    # the tiny ramp clip (tests/training/test_relit_plane.py) without it the rendered brightness
    # flickered by up to a third with the alternating exposures and missed the ramp by 0.46 stops;
    # with it, it rises smoothly, 0.27 stops short (docs/method.md, "Options beyond the paper")
    lambda_gain_smooth: float = 0.1


def _stage1_loss() -> LossConfig:
    # appendix "Implementation Details": lambda_rgb 1, lambda_ue 10, lambda_dep 1 (authors' base
    # config: 0.01, used by the small preset), lambda_track 0.01, lambda_arap 0.01, lambda_vel 10,
    # lambda_acc 10, lambda_tlr 0.1 (authors' synthetic configs: 0.01); TLR after the end of the
    # stage-1 densification (sec. 3.3.3)
    return LossConfig()


def _stage1_densify() -> DensifyConfig:
    # appendix "Implementation Details": 3K densification iterations, every 200 steps, opacity reset
    # every 1K
    return DensifyConfig(start_iter=500, stop_iter=3_000, every=200, reset_every=1_000)


@dataclass
class Stage1Config:
    """Video Gaussians (sec. 3.3.1, 3.3.3; weights and schedule from appendix "Implementation
    Details")."""

    iterations: int = 4_000
    densify: DensifyConfig = field(default_factory=_stage1_densify)
    lr: LRConfig = field(default_factory=LRConfig)
    init: VideoInitConfig = field(default_factory=VideoInitConfig)
    loss: LossConfig = field(default_factory=_stage1_loss)

    def tlr_start_step(self) -> int:
        """First step with the TLR loss: loss.tlr_start, or the end of densification."""
        return self.densify.stop_iter if self.loss.tlr_start is None else self.loss.tlr_start


@dataclass
class V2WConfig:
    """Video-to-world transform (sec. 3.3.2; details from the authors' code)."""

    dynamic_ratio: float = 0.1  # N_d / N_f above this: dynamic in world space (paper)
    # Relative depth tolerance of the occlusion test (V2W and the stage-2 removal): occluded iff
    # z > (1 + tol) x rendered depth. Not in the paper (it says only "occluded"); the rendered depth
    # is an alpha-weighted mean over the Gaussians of the visible surface, so a Gaussian ON that
    # surface sits within a few percent of it: 0.05 keeps those visible, while an occluded
    # background is clearly behind. The authors' TLR occlusion test uses 1.1x depth (0.1).
    occlusion_tol: float = 0.05
    static_std_fallback: float = (
        0.02  # authors' fallback without masks: world position std < 0.02 -> static
    )
    scale_refit_steps: int = (
        1_000  # 2D-covariance invariance refit (paper: "within 1000 iterations")
    )
    scale_refit_lr: float = 0.1  # authors' code
    rotation_refit_lr: float = 1e-3  # authors' code
    # (the EWA tan-fov clamp of the refit, authors' 1.3, is the rasterizer's own: not an option)
    resample: V2WResample = "lstsq"  # control points from the world trajectory
    # What the least-squares fit of the dynamic control points minimises (beyond the paper; resample
    # "lstsq" only): "world" = the distance to the lifted world path, equal in every direction (the
    # paper's and the authors'); "pixel" = errors across each camera ray in pixels
    # (f / pixel_sigma / z per unit) and along it as a relative depth error (1 / depth_sigma / z per
    # unit), so that a jittery lifted depth cannot pull the fit off the stage-1 pixel path
    # (docs/v2w.md, "Fitting the world spline in pixels"). The two tolerances are set by argument
    # (half a pixel; a tenth of the depth), not tuned on any clip.
    world_fit: V2WWorldFit = "world"
    pixel_sigma: float = 0.5  # px: the world_fit "pixel" tolerance across the ray
    depth_sigma: float = 0.1  # relative: its tolerance along the ray
    # 1 - |<q, q*>| refinement after the least-squares polynomial refit
    rotation_refine_steps: int = 200
    seed: int = 0

    def validate(self) -> None:
        if self.world_fit == "pixel" and self.resample != "lstsq":
            raise ValueError(
                "config key 'v2w.world_fit' 'pixel' needs v2w.resample 'lstsq' (a least-squares "
                f"fit); got resample {self.resample!r}"
            )


def _stage2_static_densify() -> DensifyConfig:
    # appendix "Implementation Details": 8K densification iterations; static every 400, reset every
    # 2K
    return DensifyConfig(start_iter=500, stop_iter=8_000, every=400, reset_every=2_000)


def _stage2_dynamic_densify() -> DensifyConfig:
    # dynamic every 200, reset every 2K
    return DensifyConfig(start_iter=500, stop_iter=8_000, every=200, reset_every=2_000)


def _stage2_loss() -> LossConfig:
    # appendix "Implementation Details": the same weights as stage 1 (one list for both stages,
    # lambda_pr apart: Stage2Config.lambda_pr); TLR after the end of both stage-2 densifications
    # (sec. 3.3.3)
    return LossConfig()


@dataclass
class Stage2Config:
    """World Gaussians + cameras (sec. 3.3.3, appendix "Implementation Details" and "Gaussian
    Densification")."""

    iterations: int = 11_000
    densify_static: DensifyConfig = field(default_factory=_stage2_static_densify)
    densify_dynamic: DensifyConfig = field(default_factory=_stage2_dynamic_densify)
    dynamic_removal_every: int = 2_000  # remove mistakenly densified dynamic Gaussians (appendix)
    # Which dynamic Gaussians the removal tests (appendix "Gaussian Densification": project their
    # trajectories and apply the V2W dynamic/static identification to "those densified
    # mistakenly"): "new" = those densified (cloned / split) since the previous removal, each tested
    # once (paper, default); "densified" = every Gaussian densified so far, re-tested at every pass;
    # "all" = the whole dynamic set, initial V2W Gaussians included (the previous behaviour: on
    # lamp-room-orbit it removed 11,778 of world-only's 11,796 dynamic Gaussians)
    dynamic_removal_scope: DynamicRemovalScope = "new"
    # clone/split boundary of both stage-2 sets (appendix "Gaussian Densification": "the same
    # densification strategy as 3DGS"): "cameras" = densify.clone_split_scale (percent_dense 0.01)
    # x the 3DGS scene extent, 1.1 x the largest distance of a camera centre from their mean
    # (the median world depth when the cameras do not move); "absolute" = clone_split_scale as is
    # (the authors' code: 0.01 world units, whatever the depth prior's scale)
    clone_split_extent: CloneSplitExtent = "cameras"
    # Guard (not in the paper): one pass never removes more than this fraction of the dynamic set;
    # above it the most static-looking candidates (fewest N_d) go, with a warning. 1.0 = no guard
    # (the last dynamic Gaussian is always kept)
    dynamic_removal_max_fraction: float = 0.5
    # Not in the paper (0 = off; tiny/small presets 0.1): at every removal step and after the last
    # iteration, remove the dynamic Gaussians that pass in view closer to the camera than this
    # fraction of the median scene depth at any training or in-between time (near_camera_samples per
    # frame interval). Between training frames nothing constrains them, and one such floater ruins a
    # test frame (m4dgs.training.stage2.near_camera_gaussians).
    near_camera_fraction: float = 0.0
    near_camera_samples: int = 2
    lr: LRConfig = field(default_factory=LRConfig)
    loss: LossConfig = field(default_factory=_stage2_loss)
    lambda_pr: float = 1.0  # HDR photometric reprojection (stage 2 only; appendix)
    # t' in {t +- 1, t +- 2} (appendix "HDR Photometric Reprojection Loss")
    pr_offsets: Tuple[int, ...] = (1, 2)
    pr_steps: Optional[int] = None  # paper: whole stage; authors' code: first 3,000 steps only
    # HDR image at the query time t of L_pr: "stage1" = the stage-1 HDR frame (detached, like the
    # one at t'), so the loss moves only cameras and rendered depth (appendix: "we use the recovered
    # HDR training frames in the first stage for the computation of L_pr"; the authors' code
    # detaches both); "render" = the stage-2 render at t, which also pulls the stage-2 colours
    # towards the (less accurate) stage-1 frames
    pr_query: PrQuery = "stage1"
    # frame pairs of the LDR reprojection baselines (method "ldr-reproj";
    # m4dgs.training.stage2.ldr_reprojection_refs): "same-exposure" = i +- N_e (same level in an
    # alternating schedule), "consecutive" = i +- 1 (a different exposure: the SplineGS-HDR form the
    # paper compares with)
    ldr_reproj_pairs: LdrReprojPairs = "same-exposure"
    optimize_cameras: bool = True

    def tlr_start_step(self) -> int:
        """First step with the TLR loss: loss.tlr_start, or the end of both densifications."""
        if self.loss.tlr_start is not None:
            return self.loss.tlr_start
        return max(self.densify_static.stop_iter, self.densify_dynamic.stop_iter)


@dataclass
class ToneMapConfig:
    """Tone mapper and colour MLP (appendix "Implementation Details"; pre-training from the authors'
    code)."""

    tonemap_hidden: int = 128
    color_hidden: int = 36
    # the colour MLP's second input, the unit view direction (camera centre -> Gaussian) of the
    # pinhole renders (stage 2 and the trained model): the authors' code feeds it (39 -> 36 -> 3);
    # the paper only says "a color MLP instead of spherical harmonics". Off by default: every
    # measured result so far was without it. Stage 1's orthographic video camera has no direction
    # (zeros), so stage-2 Gaussians inherit the same weights either way
    color_view_dependent: bool = False
    # which direction that input is (beyond the paper; read only with color_view_dependent): "view"
    # (the authors') or "reflected", the view direction mirrored about each Gaussian's normal (the
    # axis of its smallest scale, turning with it), so that a mirror-like surface can show a fixed
    # light where that direction meets it (m4dgs.model.color.color_directions)
    color_direction: ColorDirection = "view"
    # a lobe per Gaussian over that direction, read from its feature (beyond the paper; needs
    # color_view_dependent): e += a exp(kappa (d . mu - 1)), so that a colour can flare as a
    # surface turns through the mirror angle (m4dgs.model.color.ColorMLP.specular_lobe)
    color_specular: bool = False
    pretrain_steps: int = 1_000
    pretrain_monotonic_weight: float = 10.0  # ReLU of the negative slope over ln x in [-10, 10]
    lambda_monotonic: float = (
        0.0  # authors' code adds it during stage 1 with weight 10; paper does not
    )
    # pre-training target (paper silent; authors: "an equal-RGB CRF"). "log-logistic" (default): the
    # generic curve C_0 x^0.5 / (C_0 x^0.5 + 1 - C_0), a logistic in the tone mapper's input log2 x
    # anchored only at f(1) = C_0 (the unit-exposure target); it is none of the benchmark's clip
    # responses (m4dgs.core.crf.CLIP_CRFS) and differs from each by >= 0.09 somewhere in log2 x in
    # [-10, 10], so the tone mapper does not start at the answer. "reinhard-c0" (alias "auto", the
    # former default): (x / (x + k))^(1/2.2) with f(1) = C_0, which for C_0 = 0.73 IS the HDR-NeRF
    # clip curve. Any registered m4dgs.core.crf name is accepted too (an oracle when it is the
    # clip's).
    pretrain_crf: str = "log-logistic"
    # tone mapper evaluated through a piecewise-linear table of this many nodes (0 = exact MLP)
    lut_size: int = 512
    # learnable constant HDR background behind the Gaussians (paper silent)
    learn_background: bool = True


@dataclass
class ExposureConfig:
    """Exposure-related values. None means "from the clip" (clip.json)."""

    # C_0: 0.73 synthetic, 0.5 real (appendix "Unit Exposure Loss"); the number of exposure levels
    # N_e always comes from the clip (clip.json)
    unit_exposure_value: Optional[float] = None
    # exposure-perturbation study: uniform noise in [-r, r] EV on the input exposures
    perturb_ev: float = 0.0
    perturb_seed: int = 0


@dataclass
class AblationConfig:
    """Switches of the paper's ablations (sec. 4.4 and appendix "More Ablation Results"); all True =
    full model. The control-point interval N_s is `model.control_every`."""

    # (a) stage 1 + V2W; False: world Gaussians initialised from track/depth priors
    use_video_init: bool = True
    occlusion_handling: bool = True  # (b) occlusion test in the V2W dynamic/static identification
    # the occlusion test in the stage-2 removal of mistakenly densified dynamic Gaussians; the
    # paper's ablation (b) removes it from V2W only, so `no-occlusion` keeps it here. False: (b)
    # extended to the removal too (the previous `no-occlusion`)
    occlusion_handling_removal: bool = True
    cov_invariance: bool = True  # (c) 2D covariance scale refit; False: inherit video scales
    reproj_loss: bool = True  # (d) HDR photometric reprojection loss in stage 2
    tlr: bool = True  # (e) temporal luminance regularisation
    depth_loss: bool = True  # prior ablation: depth loss
    track_loss: bool = True  # prior ablation: flow/track loss


def _paper_epipolar() -> EpipolarConfig:
    # appendix "Implementation Details": "We threshold the epipolar error maps by 0.00001", in the
    # authors' normalised [-1, 1] coordinates (m4dgs.priors.epipolar: units "ndc")
    return EpipolarConfig(units="ndc", threshold=1e-5)


@dataclass
class TrainConfig:
    preset: PresetName = "paper"
    # "mono4dgs" (the method) or an adapted baseline of the paper's comparisons
    # (m4dgs.training.variants): "static-hdr" (static HDR Gaussians with the BA cameras),
    # "world-only" (world Gaussians from lifted priors), "ldr-reproj" (world-only + an LDR
    # photometric reprojection loss on the cameras, pairs: stage2.ldr_reproj_pairs)
    method: Method = "mono4dgs"
    seed: int = 0
    checkpoint_every: int = 500  # iterations between resumable checkpoints (model/ckpt.pt)
    width: int = 864  # processing resolution (paper: original 864x480)
    height: int = 480
    device: str = "auto"
    raster_backend: RasterBackend = "auto"
    model: ModelConfig = field(default_factory=ModelConfig)
    stage1: Stage1Config = field(default_factory=Stage1Config)
    v2w: V2WConfig = field(default_factory=V2WConfig)
    stage2: Stage2Config = field(default_factory=Stage2Config)
    tonemap: ToneMapConfig = field(default_factory=ToneMapConfig)
    exposure: ExposureConfig = field(default_factory=ExposureConfig)
    ablation: AblationConfig = field(default_factory=AblationConfig)
    camera_init: CameraInitConfig = field(default_factory=CameraInitConfig)
    epipolar: EpipolarConfig = field(default_factory=_paper_epipolar)
    # which dynamic-mask test (sec. 3.2 uses the epipolar one; m4dgs.priors.rigidity adds a rigidity
    # test)
    masks: DynamicMaskConfig = field(default_factory=DynamicMaskConfig)

    def __post_init__(self) -> None:
        validate(self)

    def to_dict(self) -> Dict[str, Any]:
        return to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "TrainConfig":
        return from_dict(cls, data)


# --------------------------------------------------------------------------------------------------
# presets
# --------------------------------------------------------------------------------------------------
def preset(name: str) -> TrainConfig:
    """`tiny` (tests), `small` (CPU, 216x120) or `paper` (864x480, 4K + 11K iterations)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; expected one of {PRESETS}")
    cfg = TrainConfig(preset=name)
    if name == "paper":
        return cfg
    # Short schedules keep the paper's proportions where they matter: stage 1 must fit the training
    # frames well (stage 2's HDR reprojection loss is measured against the stage-1 renders),
    # densification stops before the end, and an opacity reset leaves enough iterations to recover
    # (none at all in the tiny preset).
    if name == "small":
        # ~0.5 per pixel (paper: 150k at 864x480 = 0.36)
        width, height, cap, tracks, tm_steps, v2w_steps = 216, 120, 12_000, 8_192, 300, 300
        # Stage 1 gets 3K iterations: with 1.5K it fitted the training frames to only 19.7 dB and
        # the HDR reprojection loss then held stage 2 back (full lost ~3.5 dB LDR PSNR to world-only
        # on lamp-room-orbit; with 3K it won).
        it1, it2 = 3_000, 2_500
        d1 = DensifyConfig(
            start_iter=150, stop_iter=1_100, every=50, reset_every=500, max_gaussians=cap
        )
        d2s = DensifyConfig(
            start_iter=200, stop_iter=1_800, every=100, reset_every=900, max_gaussians=cap
        )
        d2d = DensifyConfig(
            start_iter=200, stop_iter=1_800, every=50, reset_every=900, max_gaussians=cap
        )
        removal = 600
    else:  # tiny: tests and the README demo (72x40 clips, about a minute per run on 2 cores)
        width, height, cap, tracks, tm_steps, v2w_steps = 64, 36, 4_000, 1_024, 200, 60
        it1, it2 = 300, 300
        d1 = DensifyConfig(
            start_iter=30, stop_iter=200, every=20, reset_every=10**9, max_gaussians=cap
        )
        d2s = DensifyConfig(
            start_iter=30, stop_iter=200, every=40, reset_every=10**9, max_gaussians=cap
        )
        d2d = DensifyConfig(
            start_iter=30, stop_iter=200, every=20, reset_every=10**9, max_gaussians=cap
        )
        removal = 100
    cfg.width, cfg.height = width, height
    s1, s2 = cfg.stage1, cfg.stage2
    s1.iterations, s2.iterations = it1, it2
    if name == "small":
        # reprojection loss in the first 28 % of stage 2, the proportion of the authors' 3K of 11K
        s2.pr_steps = 700
        # TLR weight of the authors' synthetic configs (their released code); the
        # paper's 0.1 cost 1.1 dB test LDR PSNR on pendulum-lamp-handheld (stage 2 with 0.1: 25.87
        # dB, without TLR: 26.98 dB)
        s1.loss.lambda_tlr = s2.loss.lambda_tlr = 0.01
        # stage-1 depth weight of the authors' base config: with the paper's 1.0 the (biased, noisy)
        # depth prior held the stage-1 fit of the training frames to 20.8 dB on
        # conveyor-occlusion-orbit / 23.5 dB on pendulum-lamp-handheld; with 0.01: 24.2 / 25.1 dB,
        # and the final depth AbsRel improved (0.067 -> 0.059)
        s1.loss.lambda_dep = 0.01
    # dynamic masks (tiny and small): the paper's epipolar test OR'd with the rigidity test
    # (m4dgs.priors.rigidity). Epipolar masks alone miss motion along the epipolar lines: IoU
    # against the gt masks 0.07 (conveyor-occlusion-orbit), 0.13 (lamp-room-orbit), 0.61
    # (pendulum-lamp-handheld), 0.38 (robot-arm-dolly); the union with the second BA pass: 0.55,
    # 0.61, 0.79, 0.62 (small clips, realistic priors; docs/cameras.md)
    cfg.masks.method = "union"
    # epipolar threshold (tiny and small): 1 px^2 (squared Sampson distance in pixels), which is
    # the paper's 1e-5 NDC^2 at its 864x480 (1e-5 x 432 x 240 = 1.04 px^2). At 216x120 the NDC
    # threshold would be 0.065 px^2, below the flow noise of these clips; the mask IoUs above were
    # measured with 1 px^2 (paper's exact form: epipolar.units=ndc, epipolar.threshold=1e-5)
    cfg.epipolar.units, cfg.epipolar.threshold = "px", 1.0
    s1.densify, s2.densify_static, s2.densify_dynamic = d1, d2s, d2d
    s2.dynamic_removal_every = removal
    # conveyor-occlusion-orbit, small: 299 dynamic Gaussians of the full method passed within 10 %
    # of the median depth of an in-between camera; two test frames lost 18.6 and 10.8 dB to them
    # (docs/method.md)
    s2.near_camera_fraction = 0.1
    s1.init.max_gaussians = tracks
    cfg.tonemap.pretrain_steps = tm_steps
    cfg.v2w.scale_refit_steps = v2w_steps
    cfg.v2w.rotation_refine_steps = max(v2w_steps // 5, 5)
    cfg.checkpoint_every = 100 if name == "tiny" else 250
    cfg.camera_init = CameraInitConfig.for_preset(name)
    return cfg


# --------------------------------------------------------------------------------------------------
# dict / YAML round trip and overrides
# --------------------------------------------------------------------------------------------------
def to_dict(cfg: Any) -> Dict[str, Any]:
    """Nested plain dict (tuples as lists) of a config dataclass, ready for yaml.safe_dump."""

    def conv(v):
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        return v

    return conv(cfg)


def _strip_optional(tp):
    origin = typing.get_origin(tp)
    if origin is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0], True
    return tp, False


def _coerce(value: Any, tp: Any, key: str) -> Any:
    """Convert a YAML / CLI value to the annotated field type, with an error naming the key."""
    base, optional = _strip_optional(tp)
    if typing.get_origin(base) is Literal:
        if value is None and optional:
            return None
        _check_choice(value, base, key)
        return value
    if isinstance(value, str) and base is not str:
        text = value.strip()
        try:
            value = yaml.safe_load(value) if text else value
        except yaml.YAMLError:
            raise ConfigTypeError(
                f"config key '{key}': {value!r} is not a value (a number, true/false, a word, "
                "or a YAML list such as [1, 2])"
            ) from None
        if base in (float, int) and isinstance(value, str):
            # YAML 1.1 reads 2e-5 (no dot) and nan / inf as words; Python's float() reads them as
            # numbers, as a user typing --set ...=2e-5 means (the range check names the key)
            try:
                value = float(text)
            except ValueError:
                pass
    if value is None:
        if optional or base is Any:
            return None
        raise ConfigTypeError(f"config key '{key}' may not be null")
    if dataclasses.is_dataclass(base):
        if not isinstance(value, Mapping):
            raise ConfigTypeError(
                f"config key '{key}' expects a mapping, got {type(value).__name__}"
            )
        return _from_dict(base, value, key + ".")
    origin = typing.get_origin(base)
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            value = [value]
        args = typing.get_args(base)
        elem = args[0] if args else Any
        items = [_coerce(v, elem, f"{key}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if base is bool:
        if isinstance(value, bool):
            return value
        raise ConfigTypeError(f"config key '{key}' expects true/false, got {value!r}")
    if base is int:
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or float(value) != int(value)
        ):
            raise ConfigTypeError(f"config key '{key}' expects an integer, got {value!r}")
        return int(value)
    if base is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigTypeError(f"config key '{key}' expects a number, got {value!r}")
        return float(value)
    if base is str:
        if not isinstance(value, str):
            raise ConfigTypeError(f"config key '{key}' expects a string, got {value!r}")
        return value
    return value


def _from_dict(cls, data: Mapping[str, Any], prefix: str = ""):
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in names]
    if unknown:
        raise ConfigKeyError(
            f"unknown config key '{prefix}{unknown[0]}' (valid keys under '{prefix or '<root>'}': "
            f"{sorted(names)})"
        )
    kwargs = {k: _coerce(v, hints[k], prefix + k) for k, v in data.items()}
    return cls(**kwargs)


def from_dict(cls, data: Mapping[str, Any]):
    """Build a config dataclass from a (partial) nested dict; missing keys keep their defaults.

    Raises KeyError naming the full dotted path of an unknown key, TypeError for a value of the
    wrong type, ValueError for a value outside a typed choice. For TrainConfig, a "preset" key
    selects the defaults the other keys are applied to, and keys of older configs are upgraded
    (`upgrade_dict`, with a warning each)."""
    if cls is TrainConfig:
        data = upgrade_dict(data)
        if "preset" in data:
            base = preset(_check_choice(data["preset"], PresetName, "preset"))
            rest = {k: v for k, v in data.items() if k != "preset"}
            return apply_overrides(base, _flatten(rest))
    return _from_dict(cls, data)


def _flatten(d: Mapping[str, Any], prefix: str = "") -> Dict[str, Any]:
    out: Dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def _unflatten(flat: Mapping[str, Any]) -> Dict[str, Any]:
    out: Dict[str, Any] = {}
    for path, v in flat.items():
        *parents, last = path.split(".")
        node = out
        for part in parents:
            node = node.setdefault(part, {})
        node[last] = v
    return out


# --------------------------------------------------------------------------------------------------
# keys of older configs
# --------------------------------------------------------------------------------------------------
# the loss weights and details moved from stage1 / stage2 into their `loss` section (LossConfig)
LEGACY_KEYS: Dict[str, str] = {
    f"{stage}.{name}": f"{stage}.loss.{name}"
    for stage in ("stage1", "stage2")
    for name in [f.name for f in dataclasses.fields(LossConfig)] + ["smooth_window"]
}
# keys renamed with a new meaning of their value: old path -> (new path, value map, why). The old
# `smooth_window` w selected frames i - w - 1 .. i + w + 1 (its comment said i - w .. i + w); the
# new `smooth_half_width` says what the code does, so w becomes w + 1 (same frames)
RENAMED_VALUE_KEYS: Dict[str, Tuple[str, Any, str]] = {
    f"{stage}.loss.smooth_window": (
        f"{stage}.loss.smooth_half_width",
        lambda w: int(w) + 1,
        "the same frames as before (half width = old value + 1)",
    )
    for stage in ("stage1", "stage2")
}
# keys that nothing ever read, removed; an old config or command naming them still loads
REMOVED_KEYS: Dict[str, str] = {
    "stage1.track_clamp_px": "the track loss is the paper's L1 without a clamp",
    "stage2.track_clamp_px": "the track loss is the paper's L1 without a clamp",
    "stage1.lr.camera_focal": "stage 1 has no camera",
    "stage2.lr.camera_focal": "the focal length stays fixed in stage 2",
    "v2w.fov_clamp": "the V2W refit uses the rasterizer's fixed 1.3 tan-fov clamp",
    "exposure.num_exposures": "N_e always comes from the clip",
}


def _warn_key(message: str) -> None:
    """One line on stderr (no source line): the key is the user's, not a line of this module."""
    warnings.warn_explicit(message, FutureWarning, "m4dgs config", 0, module=__name__)


def _upgrade_item(path: str, value: Any, warn: bool) -> Optional[Tuple[str, Any]]:
    """(current dotted key, value) of an older config's item, or None for a removed key."""
    new = _upgrade_key(path, warn)
    if new in RENAMED_VALUE_KEYS:
        newer, fn, why = RENAMED_VALUE_KEYS[new]
        if warn:
            _warn_key(f"config key '{path}' is now '{newer}' = {fn(value)} ({why})")
        return newer, fn(value)
    return None if new is None else (new, value)


def _upgrade_key(path: str, warn: bool) -> Optional[str]:
    """The current dotted key of `path` (itself when current), or None for a removed key."""
    if path in LEGACY_KEYS:
        new = LEGACY_KEYS[path]
        if new in RENAMED_VALUE_KEYS:  # reported with its value by _upgrade_item
            return new
        if warn:
            _warn_key(f"config key '{path}' is deprecated, use '{new}'")
        return new
    if path in REMOVED_KEYS:
        if warn:
            _warn_key(f"config key '{path}' was removed ({REMOVED_KEYS[path]}); ignored")
        return None
    return path


def upgrade_overrides(overrides: Mapping[str, Any], warn: bool = True) -> Dict[str, Any]:
    """Dotted overrides (mapping values flattened) with the keys of older configs renamed and
    removed keys dropped, warning once per such key when `warn` (see `apply_overrides`)."""
    out = {}
    for path, v in _flatten(overrides).items():
        item = _upgrade_item(path, v, warn)
        if item is not None:
            out[item[0]] = item[1]
    return out


def upgrade_dict(data: Mapping[str, Any], warn: bool = True) -> Dict[str, Any]:
    """A nested TrainConfig dict (e.g. an older run's config.yaml) with the keys of older configs
    moved to their current place (LEGACY_KEYS) and removed keys dropped (REMOVED_KEYS), warning
    once per such key when `warn`. A current dict comes back equal."""
    flat = _flatten(data)
    out = {}
    for path, v in flat.items():
        item = _upgrade_item(path, v, warn)
        if item is not None:
            out[item[0]] = item[1]
    # a mapping value for a section that held only removed keys disappears; keep empty sections
    return _unflatten(out) if out != flat else dict(data)


def apply_overrides(cfg: Any, overrides: Mapping[str, Any]) -> Any:
    """A copy of `cfg` with dotted-path overrides applied, e.g. {"stage1.loss.lambda_tlr": 0,
    "ablation.tlr": False}.

    Values are coerced to the field type (strings are parsed as YAML scalars, so CLI values work); a
    mapping value overrides the nested fields it names. Unknown paths raise KeyError naming the
    path, a value outside a typed choice ValueError. On a TrainConfig, the key of an older config
    (e.g. "stage1.lambda_dep") is applied to its current place ("stage1.loss.lambda_dep") with a
    FutureWarning, and a removed key is ignored with one; the result is validated (`validate`)."""
    out = copy.deepcopy(cfg)
    root = isinstance(cfg, TrainConfig)
    for path, value in overrides.items():
        if root:
            item = _upgrade_item(path, value, warn=True)
            if item is None:
                continue
            path, value = item
        parts = path.split(".")
        obj = out
        for i, part in enumerate(parts[:-1]):
            if not dataclasses.is_dataclass(obj) or part not in {
                f.name for f in dataclasses.fields(obj)
            }:
                raise _unknown_key(
                    ".".join(parts[: i + 1]),
                    obj if dataclasses.is_dataclass(obj) else None,
                    part,
                    path,
                )
            obj = getattr(obj, part)
        last = parts[-1]
        if not dataclasses.is_dataclass(obj) or last not in {
            f.name for f in dataclasses.fields(obj)
        }:
            raise _unknown_key(path, obj if dataclasses.is_dataclass(obj) else None, last)
        tp = typing.get_type_hints(type(obj))[last]
        base, _ = _strip_optional(tp)
        if dataclasses.is_dataclass(base) and isinstance(value, Mapping):
            if root:  # through the root, so that older nested keys are upgraded too
                flat = {f"{path}.{k}": v for k, v in _flatten(value).items()}
                out = apply_overrides(out, flat)
            else:
                setattr(obj, last, apply_overrides(getattr(obj, last), _flatten(value)))
        else:
            setattr(obj, last, _coerce(value, tp, path))
    if root:
        validate(out)
    return out


# --------------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------------
def _check_choice(value: Any, tp: Any, key: str) -> Any:
    """`value` if it is one of the Literal type's values, else ValueError naming key and values."""
    allowed = typing.get_args(tp)
    if not isinstance(value, str) or value not in allowed:
        raise ConfigError(
            f"config key '{key}' must be one of {', '.join(map(repr, allowed))}; got {value!r}"
        )
    return value


def _range_error(key: str, v: Any, want: str) -> ConfigError:
    return ConfigError(f"config key '{key}' must be {want}; got {v!r}")


def _check_range(section: Any, name: str, v: Any, key: str) -> None:
    """Numeric ranges that hold for every config field of their kind: every float finite, loss
    weights (lambda_*) >= 0, learning rates (LRConfig) > 0, iteration / step counts >= 0,
    probabilities (*_prob) in [0, 1]."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return
    if isinstance(v, float) and not math.isfinite(v):
        raise _range_error(key, v, "a finite number")
    if name.startswith("lambda_") and v < 0:
        raise _range_error(key, v, ">= 0 (a loss weight; 0 turns the term off)")
    if isinstance(section, LRConfig) and not v > 0:
        raise _range_error(key, v, "> 0 (a learning rate)")
    if (name.endswith("iterations") or name.endswith("_steps")) and v < 0:
        raise _range_error(key, v, ">= 0 (a number of iterations)")
    if name.endswith("_prob") and not 0 <= v <= 1:
        raise _range_error(key, v, "a probability in [0, 1]")
    if name == "tlr_shoulder" and not 0 < v <= 1:
        raise _range_error(key, v, "an LDR value in (0, 1] (None = TLR on every pixel)")
    if name == "tlr_den_floor" and v < 0:
        raise _range_error(key, v, ">= 0 (a fraction of the render's median HDR value)")
    if name == "appearance_knots" and v < 0:
        raise _range_error(key, v, ">= 0 (0 = no gain over time, the paper's colour)")
    if name == "highlight_min_area" and v < 1:
        raise _range_error(key, v, ">= 1 (pixels)")
    if name.endswith("_sigma") and isinstance(section, V2WConfig) and not v > 0:
        raise _range_error(key, v, "> 0 (a tolerance)")


def _check_budget(cfg: "TrainConfig") -> None:
    """Whole-config ranges: an image size, a stage 2, a stage 1 when the variant trains one, a
    checkpoint interval."""
    for key, v in (("width", cfg.width), ("height", cfg.height)):
        if v < 1:
            raise _range_error(key, v, ">= 1 (pixels)")
    if cfg.stage2.iterations < 1:
        raise _range_error("stage2.iterations", cfg.stage2.iterations, ">= 1")
    if cfg.ablation.use_video_init and cfg.stage1.iterations < 1:
        raise _range_error(
            "stage1.iterations", cfg.stage1.iterations, ">= 1 (0 only without stage 1)"
        )
    if cfg.checkpoint_every < 1:
        raise _range_error("checkpoint_every", cfg.checkpoint_every, ">= 1")


def validate(cfg: Any, prefix: str = "") -> None:
    """Raise ConfigError (naming the dotted key and the allowed values) for a typed-choice field
    outside its values or a number outside its range (`_check_range`, `_check_budget`), anywhere in
    the config tree; nested configs with their own `validate()`
    (e.g. masks: m4dgs.priors.rigidity.DynamicMaskConfig) are asked too, and the tone mapper's
    pre-training curve must be a known one."""
    hints = typing.get_type_hints(type(cfg))
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        base, optional = _strip_optional(hints[f.name])
        if typing.get_origin(base) is Literal and not (v is None and optional):
            _check_choice(v, base, prefix + f.name)
        elif dataclasses.is_dataclass(v):
            validate(v, f"{prefix}{f.name}.")
        else:
            _check_range(cfg, f.name, v, prefix + f.name)
    if isinstance(cfg, TrainConfig):
        _check_budget(cfg)
    if callable(getattr(cfg, "validate", None)):
        try:
            cfg.validate()
        except ValueError as e:
            raise ConfigError(str(e)) from e
    if isinstance(cfg, ToneMapConfig):
        from m4dgs.core.crf import available_crfs

        for key, on in (
            ("color_direction", cfg.color_direction != "view"),
            ("color_specular", cfg.color_specular),
        ):
            if on and not cfg.color_view_dependent:
                raise ConfigError(
                    f"config key '{prefix}{key}' = {getattr(cfg, key)!r} needs "
                    f"'{prefix}color_view_dependent' = true (without it the colour MLP sees no "
                    "direction)"
                )

        known = ("log-logistic", "reinhard-c0", "auto", *available_crfs())
        if cfg.pretrain_crf not in known:
            raise ConfigError(
                f"config key '{prefix}pretrain_crf' must be one of {', '.join(map(repr, known))}; "
                f"got {cfg.pretrain_crf!r}"
            )


def to_yaml(cfg: Any) -> str:
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)


def from_yaml(text: str, cls=TrainConfig, name: str = "<config>"):
    data = parse_yaml(text, name) or {}
    return from_dict(cls, data)


def save_yaml(cfg: Any, path) -> None:
    """Write the config as YAML atomically (m4dgs.core.io.write_text_atomic)."""
    write_text_atomic(path, to_yaml(cfg))


def load_yaml(path, cls=TrainConfig):
    return from_yaml(Path(path).read_text(), cls, str(path))
