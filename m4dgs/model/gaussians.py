"""Gaussian parameter containers of both stages and the video-Gaussian initialisation from priors.

Stage 1 (paper sec. 3.3.1, appendix "Video Gaussian Representation"): fully dynamic *video*
Gaussians in orthographic camera space, x, y in [-1, 1] (x = u / W * 2 - 1 for the continuous pixel
coordinate u, pixel centres at +0.5) and z = depth. Each Gaussian has a cubic Hermite spline
position trajectory (`m4dgs.core.spline`), a cubic quaternion polynomial rotation
(`m4dgs.core.rotation`), and time-invariant scale, opacity and 36-d colour features (sec. 3.1).

Stage 2 (sec. 3.3.2): *world* Gaussians, the union of a static set (position + quaternion) and a
dynamic set (spline + rotation polynomial), sharing the kinds of scale / opacity / feature
attributes.

Parameters live in `nn.ParameterDict`s whose tensors all have the number of Gaussians as first
dimension, so the densification strategy (`m4dgs.training.densify`) can grow / prune them;
`layout()` (a `m4dgs.model.layout.GaussianLayout`) tells it which keys are which. Time is the
training-frame index (0..T-1, fractional for in-between test frames); the rotation polynomial is
evaluated at the normalised time t / (T - 1).

Scale activations: "exp" (3DGS log-scales) or "sigmoid" (scale = scale_max * sigmoid(raw), the
authors' video-space choice with scale_max = 0.05).

Beyond the paper (`ModelConfig.appearance_knots` = K > 0; off by default): every Gaussian of either
stage also holds "log2_gain" [N, K], a grey brightness gain over time in stops. Its HDR colour at
time t is the colour MLP's output times 2 ** g(t), g the cubic Hermite curve of `m4dgs.core.spline`
through its K values at K knots spread evenly over the training frames (`log2_gain(t)`). Without it
the containers hold exactly the paper's parameters."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Dict, Literal, Mapping, Optional, Tuple, Union

import torch
import torch.nn.functional as F
from torch import nn

from m4dgs.core import rotation as rot
from m4dgs.core import spline
from m4dgs.core.knn import knn
from m4dgs.model.layout import GaussianLayout

Tensor = torch.Tensor
TimeLike = Union[Tensor, float, int]

SCALE_ACTIVATIONS = ("exp", "sigmoid")


# --------------------------------------------------------------------------------------------------
# configuration of the Gaussian models (collected into the training config by m4dgs.training.config)
# --------------------------------------------------------------------------------------------------
@dataclass
class ModelConfig:
    """Gaussian representation shared by both stages (paper sec. 3.1 and appendix "Implementation
    Details")."""

    control_every: int = (
        4  # N_s: spline control point every 4 frames (paper; the authors' code uses 2)
    )
    feature_dim: int = 36  # 36-d colour features decoded by the colour MLP (paper)
    rotation_degree: int = 3  # cubic quaternion polynomial (sec. 3.1)
    rotation_init: Literal["paper", "constant"] = (
        "paper"  # "paper": all coefficients [1,0,0,0]; "constant": only a_0 (authors' code)
    )
    video_scale_activation: Literal["exp", "sigmoid"] = (
        "sigmoid"  # authors: sigmoid bounded scale in video space
    )
    video_scale_max: float = 0.05  # authors: maximum video-space scale
    world_scale_activation: Literal["exp", "sigmoid"] = "exp"  # 3DGS log-scales in world space
    world_scale_max: float = 1.0  # only used with a "sigmoid" world activation
    # Beyond the paper. 0 = the paper's time-invariant colour (sec. 3.1). K > 0: every Gaussian
    # (stage-1 video Gaussians, stage-2 static and dynamic world Gaussians) carries a grey gain
    # "log2_gain" [N, K] (zero at the start), and its HDR colour at time t is colour(features,
    # direction) * 2 ** g(t), g the cubic Hermite curve through its K values at K knots spread
    # evenly over the training frames: a light that moves changes how brightly a surface is lit,
    # which a time-invariant colour cannot follow (docs/method.md, "Options beyond the paper")
    appearance_knots: int = 0


@dataclass
class VideoInitConfig:
    """Video-Gaussian initialisation from tracks + depth (appendix "Video Gaussian Representation";
    authors' code)."""

    # cap on tracks lifted to Gaussians (authors: 16,384 uniform + 16,384 dynamic)
    max_gaussians: int = 32_768
    min_visible: int = 1  # tracks visible (and inside the image) on fewer frames are dropped
    knn_k: int = 3  # scale = sqrt(mean squared distance to the k nearest neighbours) (3DGS)
    init_opacity: float = 0.5  # authors' code
    feature_std: float = 1.0  # features ~ N(0, std^2) (authors: randn, i.e. std 1)
    # second-difference weight of the control-point fit (fills invisible spans)
    fit_smooth: float = 1e-3
    seed: int = 0
    # beyond the paper (off = the paper): also lift tracks of the video's bright blobs, so that
    # small bright movers that point tracks lose get Gaussians that follow them
    # (m4dgs.priors.highlight_tracks; docs/method.md, "Small bright movers")
    highlight_tracks: bool = False
    highlight_points: int = 16  # tracks per linked blob chain
    # smallest blob the tracker keeps, in pixels (m4dgs.priors.highlight_tracks, step 1; beyond the
    # paper): 3 leaves out one-pixel sparkles; a glint on a moving object is 1-3 px
    highlight_min_area: int = 3
    # beyond the paper (off = the paper): the chains carry the motion where they are: their tracks
    # replace the prior tracks that follow them, and the flow prior is off around them, in stage 1's
    # initialisation and its track and flow losses (m4dgs.priors.highlight_tracks, step 5). Implies
    # the chains' tracks at the initialisation, whatever highlight_tracks says
    highlight_motion: bool = False
    # beyond the paper (off = the paper): the depth prior held at each chain's median within 3 px of
    # the chain's centre (m4dgs.priors.highlight_tracks, step 6), where a mover's prior depth jumps
    # with what lies behind it; read by stage 1 (initialisation, depth loss) and stage 2 (depth)
    highlight_depth: bool = False


# --------------------------------------------------------------------------------------------------
# activations
# --------------------------------------------------------------------------------------------------
def scale_activation(raw: Tensor, kind: str = "exp", scale_max: float = 0.05) -> Tensor:
    """Raw scale parameter -> positive scales ("exp": exp(raw); "sigmoid": scale_max *
    sigmoid(raw))."""
    if kind == "exp":
        return torch.exp(raw)
    if kind == "sigmoid":
        return scale_max * torch.sigmoid(raw)
    raise ValueError(f"unknown scale activation {kind!r}; expected one of {SCALE_ACTIVATIONS}")


def scale_inverse(scale: Tensor, kind: str = "exp", scale_max: float = 0.05) -> Tensor:
    """Inverse of `scale_activation` (sigmoid: the ratio is clamped into (0, 1))."""
    if kind == "exp":
        return torch.log(scale.clamp_min(1e-12))
    if kind == "sigmoid":
        r = (scale / scale_max).clamp(1e-6, 1.0 - 1e-6)
        return torch.log(r) - torch.log1p(-r)
    raise ValueError(f"unknown scale activation {kind!r}; expected one of {SCALE_ACTIVATIONS}")


# --------------------------------------------------------------------------------------------------
# brightness gain over time (beyond the paper: ModelConfig.appearance_knots)
# --------------------------------------------------------------------------------------------------
GAIN_KEY = "log2_gain"  # per-Gaussian knot values [N, K] of the log2 brightness gain


def gain_knots(num_frames: int, count: int, *, dtype=torch.float32, device=None) -> Tensor:
    """[K] knot times of the gain curve: K knots spread evenly over the training frames 0..T-1
    (`m4dgs.core.spline.uniform_knots`)."""
    return spline.uniform_knots(num_frames, count, dtype=dtype, device=device)


def evaluate_log2_gain(
    values: Tensor, knots: Tensor, t: TimeLike, memo: Optional[spline.BasisMemo] = None
) -> Tensor:
    """The log2 gain of each Gaussian at time t: the cubic Hermite spline (Catmull-Rom tangents,
    times clamped to the knots) of its knot values, as `m4dgs.core.spline.evaluate` computes the
    positions, with one channel.

    Args:
        values: [N, K] knot values (stops). knots: [K] knot times. t: a scalar time or [T] times.
        memo: the model's basis memo (the same values bit for bit).
    Returns:
        [N, 1] for a scalar t, else [N, T, 1].
    """
    return spline.evaluate(values[..., None], knots, t, memo)


def gain_second_differences(values: Tensor) -> Tensor:
    """[N, K - 2] second differences g_{k+1} - 2 g_k + g_{k-1} of the knot values [N, K] (zero
    along a straight line in time; the knots are evenly spaced)."""
    return values[:, 2:] - 2.0 * values[:, 1:-1] + values[:, :-2]


def _check_gain(gain: Tensor, n: int, label: str) -> None:
    if gain.dim() != 2 or gain.shape[0] != n or gain.shape[1] < 1:
        raise ValueError(
            f"{label}: '{GAIN_KEY}' must be [N, K] with N = {n} and K >= 1, got {tuple(gain.shape)}"
        )


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


def spline_layout(kind: str, smax: float) -> GaussianLayout:
    """Densification layout of spline Gaussians ("ctrl" [N, K, 3] control points move together when
    split; splits are oriented by the rotation polynomial at mid-sequence), shared by video and
    dynamic world Gaussians."""
    return GaussianLayout(
        position_keys=("ctrl",),
        scale_key="scales",
        opacity_key="opacities",
        rotation_key="rot",
        scale_fn=lambda r: scale_activation(r, kind, smax),
        scale_inv_fn=lambda s: scale_inverse(s, kind, smax),
        rotation_fn=lambda p: rot.poly_evaluate(p["rot"], 0.5),
    )


# --------------------------------------------------------------------------------------------------
# containers
# --------------------------------------------------------------------------------------------------
class VideoGaussians(nn.Module):
    """Fully dynamic video Gaussians (stage 1).

    Parameters (`self.params`): "ctrl" [N, K, 3] spline control points in video space, "rot" [N, J,
    4] quaternion polynomial coefficients, "scales" [N, 3] raw scales, "opacities" [N] logits,
    "features" [N, C], and with a gain over time (beyond the paper) "log2_gain" [N, K_g]. Buffer
    "knots" [K] (frame times of the control points); `num_frames` T sets the normalised rotation
    time."""

    def __init__(
        self,
        ctrl: Tensor,
        rot_coeffs: Tensor,
        scales_raw: Tensor,
        opacity_logits: Tensor,
        features: Tensor,
        knots: Tensor,
        num_frames: int,
        scale_kind: str = "sigmoid",
        scale_max: float = 0.05,
        log2_gain: Optional[Tensor] = None,
    ):
        super().__init__()
        n = ctrl.shape[0]
        for name, v in (
            ("rot", rot_coeffs),
            ("scales", scales_raw),
            ("opacities", opacity_logits),
            ("features", features),
        ):
            if v.shape[0] != n:
                raise ValueError(f"VideoGaussians: '{name}' has {v.shape[0]} rows, ctrl has {n}")
        if ctrl.shape[1] != knots.numel():
            raise ValueError(
                f"VideoGaussians: ctrl has {ctrl.shape[1]} control points but {knots.numel()} knots"
            )
        if scale_kind not in SCALE_ACTIVATIONS:
            raise ValueError(f"unknown scale activation {scale_kind!r}")
        self.params = nn.ParameterDict(
            {
                "ctrl": nn.Parameter(ctrl),
                "rot": nn.Parameter(rot_coeffs),
                "scales": nn.Parameter(scales_raw),
                "opacities": nn.Parameter(opacity_logits.reshape(n)),
                "features": nn.Parameter(features),
            }
        )
        self.register_buffer("knots", knots.to(device=ctrl.device, dtype=ctrl.dtype))
        self.spline_memo = spline.BasisMemo()  # the basis of frame times, built once
        self.num_frames = int(num_frames)
        self.scale_kind = scale_kind
        self.scale_max = float(scale_max)
        if log2_gain is not None:
            _check_gain(log2_gain, n, "VideoGaussians")
            self.params[GAIN_KEY] = nn.Parameter(log2_gain)
            self._register_gain_knots(log2_gain.shape[1], ctrl)

    def _register_gain_knots(self, count: int, like: Tensor) -> None:
        # not saved with the state (it follows from num_frames and K); moves with .to()
        knots = gain_knots(self.num_frames, count, dtype=like.dtype, device=like.device)
        self.register_buffer("gain_knots", knots, persistent=False)

    @property
    def num_gaussians(self) -> int:
        return self.params["ctrl"].shape[0]

    def __len__(self) -> int:
        return self.num_gaussians

    def positions(self, t: TimeLike) -> Tensor:
        """Video-space means at frame time t: [N, 3] (scalar t) or [N, T, 3]."""
        return spline.evaluate(self.params["ctrl"], self.knots, t, self.spline_memo)

    def quats(self, t: TimeLike, normalize: bool = True) -> Tensor:
        """Rotation quaternions (wxyz) at frame time t: [N, 4] or [N, T, 4] (unit unless
        normalize=False)."""
        tn = rot.normalize_time(
            torch.as_tensor(t, dtype=self.knots.dtype, device=self.knots.device), self.num_frames
        )
        return rot.poly_evaluate(self.params["rot"], tn, normalize=normalize)

    def scales(self) -> Tensor:
        """[N, 3] activated scales."""
        return scale_activation(self.params["scales"], self.scale_kind, self.scale_max)

    def opacities(self) -> Tensor:
        """[N] opacities in (0, 1)."""
        return torch.sigmoid(self.params["opacities"])

    def features(self) -> Tensor:
        """[N, C] colour features."""
        return self.params["features"]

    @property
    def appearance_knots(self) -> int:
        """K of the gain over time (0: none, the paper's time-invariant colour)."""
        return self.params[GAIN_KEY].shape[1] if GAIN_KEY in self.params else 0

    def gain_values(self) -> Optional[Tensor]:
        """[N, K] knot values of the log2 gain, or None without a gain."""
        return self.params[GAIN_KEY] if GAIN_KEY in self.params else None

    def log2_gain(self, t: TimeLike) -> Optional[Tensor]:
        """log2 brightness gain at frame time t: [N, 1] (scalar t) or [N, T, 1]; None without a
        gain (the paper's model)."""
        if GAIN_KEY not in self.params:
            return None
        return evaluate_log2_gain(self.params[GAIN_KEY], self.gain_knots, t, self.spline_memo)

    def layout(self) -> GaussianLayout:
        """Densification layout: control points move together; splits are oriented by the
        mid-sequence rotation."""
        return spline_layout(self.scale_kind, self.scale_max)

    def to_state(self) -> Dict[str, Any]:
        """Plain dict (tensors + metadata) for torch.save; the inverse is `from_state` (works for
        any N)."""
        return {
            "type": "VideoGaussians",
            "params": {k: v.detach().clone() for k, v in self.params.items()},
            "knots": self.knots.detach().clone(),
            "num_frames": self.num_frames,
            "scale_kind": self.scale_kind,
            "scale_max": self.scale_max,
        }

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "VideoGaussians":
        p = state["params"]
        return cls(
            p["ctrl"],
            p["rot"],
            p["scales"],
            p["opacities"],
            p["features"],
            state["knots"],
            state["num_frames"],
            state["scale_kind"],
            state["scale_max"],
            log2_gain=p.get(GAIN_KEY),
        )


class WorldGaussians(nn.Module):
    """Static + dynamic world Gaussians (stage 2); accessors return the union, static first.

    `static` params: "means" [Ns, 3], "quats" [Ns, 4], "scales" [Ns, 3], "opacities" [Ns],
    "features" [Ns, C]. `dynamic` params: "ctrl" [Nd, K, 3], "rot" [Nd, J, 4], "scales",
    "opacities", "features". With a gain over time (beyond the paper) both sets also hold
    "log2_gain" [Ns / Nd, K_g] (both or neither, one K_g)."""

    def __init__(
        self,
        static: Mapping[str, Tensor],
        dynamic: Mapping[str, Tensor],
        knots: Tensor,
        num_frames: int,
        scale_kind: str = "exp",
        scale_max: float = 1.0,
    ):
        super().__init__()
        need_s = ("means", "quats", "scales", "opacities", "features")
        need_d = ("ctrl", "rot", "scales", "opacities", "features")
        for keys, part, label in ((need_s, static, "static"), (need_d, dynamic, "dynamic")):
            missing = [k for k in keys if k not in part]
            if missing:
                raise ValueError(f"WorldGaussians: {label} set lacks {missing}")
            sizes = {k: part[k].shape[0] for k in keys}
            if len(set(sizes.values())) > 1:
                raise ValueError(
                    f"WorldGaussians: {label} attributes disagree on the count: {sizes}"
                )
        if scale_kind not in SCALE_ACTIVATIONS:
            raise ValueError(f"unknown scale activation {scale_kind!r}")
        self.static = nn.ParameterDict({k: nn.Parameter(static[k]) for k in need_s})
        self.dynamic = nn.ParameterDict({k: nn.Parameter(dynamic[k]) for k in need_d})
        self.static["opacities"] = nn.Parameter(self.static["opacities"].detach().reshape(-1))
        self.dynamic["opacities"] = nn.Parameter(self.dynamic["opacities"].detach().reshape(-1))
        ref = self.dynamic["ctrl"]
        self.register_buffer("knots", knots.to(device=ref.device, dtype=ref.dtype))
        self.spline_memo = spline.BasisMemo()  # the basis of frame times, built once
        self.num_frames = int(num_frames)
        self.scale_kind = scale_kind
        self.scale_max = float(scale_max)
        has_gain = (GAIN_KEY in static, GAIN_KEY in dynamic)
        if any(has_gain):
            if not all(has_gain):
                raise ValueError(
                    f"WorldGaussians: '{GAIN_KEY}' in the {'static' if has_gain[0] else 'dynamic'}"
                    " set only (both sets or neither)"
                )
            gs, gd = static[GAIN_KEY], dynamic[GAIN_KEY]
            _check_gain(gs, self.static["means"].shape[0], "WorldGaussians static set")
            _check_gain(gd, ref.shape[0], "WorldGaussians dynamic set")
            if gs.shape[1] != gd.shape[1]:
                raise ValueError(
                    f"WorldGaussians: the static gain has {gs.shape[1]} knots, the dynamic one "
                    f"{gd.shape[1]}"
                )
            self.static[GAIN_KEY] = nn.Parameter(gs)
            self.dynamic[GAIN_KEY] = nn.Parameter(gd)
            knots_g = gain_knots(self.num_frames, gs.shape[1], dtype=ref.dtype, device=ref.device)
            # not saved with the state (it follows from num_frames and K); moves with .to()
            self.register_buffer("gain_knots", knots_g, persistent=False)

    @property
    def num_static(self) -> int:
        return self.static["means"].shape[0]

    @property
    def num_dynamic(self) -> int:
        return self.dynamic["ctrl"].shape[0]

    @property
    def num_gaussians(self) -> int:
        return self.num_static + self.num_dynamic

    def __len__(self) -> int:
        return self.num_gaussians

    @property
    def is_dynamic(self) -> Tensor:
        """[N] bool, False for the static rows (first), True for the dynamic ones."""
        dev = self.static["means"].device
        return torch.cat(
            [
                torch.zeros(self.num_static, dtype=torch.bool, device=dev),
                torch.ones(self.num_dynamic, dtype=torch.bool, device=dev),
            ]
        )

    def positions(self, t: TimeLike) -> Tensor:
        """World means of the union at time t: [N, 3] (scalar t) or [N, T, 3]."""
        dyn = spline.evaluate(self.dynamic["ctrl"], self.knots, t, self.spline_memo)
        stat = self.static["means"]
        if dyn.dim() == 3:
            stat = stat[:, None].expand(-1, dyn.shape[1], -1)
        return torch.cat([stat, dyn])

    def quats(self, t: TimeLike, normalize: bool = True) -> Tensor:
        """World rotations (wxyz) of the union at time t: [N, 4] or [N, T, 4]."""
        tn = rot.normalize_time(
            torch.as_tensor(t, dtype=self.knots.dtype, device=self.knots.device), self.num_frames
        )
        dyn = rot.poly_evaluate(self.dynamic["rot"], tn, normalize=normalize)
        stat = self.static["quats"]
        if normalize:
            stat = rot.quat_normalize(stat)
        if dyn.dim() == 3:
            stat = stat[:, None].expand(-1, dyn.shape[1], -1)
        return torch.cat([stat, dyn])

    def scales(self) -> Tensor:
        raw = torch.cat([self.static["scales"], self.dynamic["scales"]])
        return scale_activation(raw, self.scale_kind, self.scale_max)

    def opacities(self) -> Tensor:
        return torch.sigmoid(torch.cat([self.static["opacities"], self.dynamic["opacities"]]))

    def features(self) -> Tensor:
        return torch.cat([self.static["features"], self.dynamic["features"]])

    @property
    def appearance_knots(self) -> int:
        """K of the gain over time (0: none, the paper's time-invariant colour)."""
        return self.static[GAIN_KEY].shape[1] if GAIN_KEY in self.static else 0

    def gain_values(self) -> Optional[Tensor]:
        """[N, K] knot values of the log2 gain of the union (static first), or None."""
        if GAIN_KEY not in self.static:
            return None
        return torch.cat([self.static[GAIN_KEY], self.dynamic[GAIN_KEY]])

    def log2_gain(self, t: TimeLike) -> Optional[Tensor]:
        """log2 brightness gain of the union at time t: [N, 1] (scalar t) or [N, T, 1]; None
        without a gain (the paper's model)."""
        values = self.gain_values()
        if values is None:
            return None
        return evaluate_log2_gain(values, self.gain_knots, t, self.spline_memo)

    def static_layout(self) -> GaussianLayout:
        kind, smax = self.scale_kind, self.scale_max
        return GaussianLayout(
            position_keys=("means",),
            scale_key="scales",
            opacity_key="opacities",
            rotation_key="quats",
            scale_fn=lambda r: scale_activation(r, kind, smax),
            scale_inv_fn=lambda s: scale_inverse(s, kind, smax),
        )

    def dynamic_layout(self) -> GaussianLayout:
        return spline_layout(self.scale_kind, self.scale_max)

    def split_render_info(self, info: Mapping[str, Any]) -> Tuple[Dict[str, Any], Dict[str, Any]]:
        """Per-set views of a render info dict for the two densification strategies (after
        backward).

        Returns (static_info, dynamic_info), each with "means2d_grad", "radii" sliced along the
        Gaussian axis and the other entries (e.g. "width", "height") copied."""
        ns = self.num_static
        grad = info.get("means2d_grad")
        if grad is None:
            grad = info["means2d"].grad
            if grad is None:
                raise ValueError(
                    "split_render_info: info['means2d'] has no gradient (call it after backward)"
                )
        radii = info["radii"]
        per_axis = radii.numel() == grad.numel()
        n_axis_r = -2 if per_axis else -1
        g_s, g_d = grad.narrow(-2, 0, ns), grad.narrow(-2, ns, grad.shape[-2] - ns)
        r_s = radii.narrow(n_axis_r, 0, ns)
        r_d = radii.narrow(n_axis_r, ns, radii.shape[n_axis_r] - ns)
        base = {k: v for k, v in info.items() if k not in ("means2d", "means2d_grad", "radii")}
        return {**base, "means2d_grad": g_s, "radii": r_s}, {
            **base,
            "means2d_grad": g_d,
            "radii": r_d,
        }

    def to_state(self) -> Dict[str, Any]:
        return {
            "type": "WorldGaussians",
            "static": {k: v.detach().clone() for k, v in self.static.items()},
            "dynamic": {k: v.detach().clone() for k, v in self.dynamic.items()},
            "knots": self.knots.detach().clone(),
            "num_frames": self.num_frames,
            "scale_kind": self.scale_kind,
            "scale_max": self.scale_max,
        }

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "WorldGaussians":
        return cls(
            state["static"],
            state["dynamic"],
            state["knots"],
            state["num_frames"],
            state["scale_kind"],
            state["scale_max"],
        )


# --------------------------------------------------------------------------------------------------
# initialisation from priors
# --------------------------------------------------------------------------------------------------
def pixel_to_video_xy(uv: Tensor, width: int, height: int) -> Tensor:
    """Continuous pixel coordinates [..., 2] (centres at +0.5) -> video-space (x, y) = (u / W * 2 -
    1, v / H * 2 - 1)."""
    scale = torch.tensor([2.0 / width, 2.0 / height], dtype=uv.dtype, device=uv.device)
    return uv * scale - 1.0


def sample_depth(depth: Tensor, tracks: Tensor, width: int, height: int) -> Tensor:
    """Bilinear depth at track pixels, per frame.

    Args:
        depth: [T, H, W] depth maps. tracks: [N, T, 2] continuous pixel coordinates (centres at
        +0.5).
    Returns:
        [N, T] depth (border-clamped outside the image). grid_sample with align_corners=False maps
        the continuous coordinate u to the normalised u / W * 2 - 1, so pixel centres sample exactly
        their own value.
    """
    t_count = depth.shape[0]
    # [T, N, 1, 2]
    grid = pixel_to_video_xy(tracks.to(depth.dtype), width, height).permute(1, 0, 2)[:, :, None, :]
    z = F.grid_sample(
        depth[:, None], grid, mode="bilinear", padding_mode="border", align_corners=False
    )  # [T,1,N,1]
    return z[:, 0, :, 0].T.reshape(tracks.shape[0], t_count)


def knn_mean_sq_distance(points: Tensor, k: int = 3, backend: str = "auto") -> Tensor:
    """Mean squared distance of each point to its k nearest other points (k clipped to N - 1),
    [N, D] -> [N] (1 for a single point)."""
    n = points.shape[0]
    if n <= 1:
        return torch.ones(n, dtype=points.dtype, device=points.device)
    _, dist = knn(points, min(k, n - 1), backend=backend)
    return (dist**2).to(points.dtype).mean(dim=1)


def init_video_gaussians(
    tracks: Tensor,
    visible: Tensor,
    depth: Tensor,
    width: int,
    height: int,
    cfg: Optional[VideoInitConfig] = None,
    model: Optional[ModelConfig] = None,
    always: Optional[Tensor] = None,
) -> VideoGaussians:
    """Lift 2D tracks with the depth prior to video Gaussians (appendix "Video Gaussian
    Representation").

    Each track becomes one Gaussian: on its visible frames the video-space trajectory is (u / W * 2
    - 1, v / H * 2 - 1, D_t(u, v)) with the depth bilinearly sampled at the track pixel; spline
    control points (every N_s frames over the T training frames) are fitted to it by least squares,
    the spline itself filling the invisible spans. Opacity 0.5, scale sqrt(mean squared distance to
    the k = 3 nearest neighbours) at the frame where most tracks are visible, features ~ N(0,
    std^2), identity rotation polynomial; with `model.appearance_knots` > 0 (beyond the paper) a
    zero log2 gain.

    Args:
        tracks: [N, T, 2] continuous pixel coordinates over the training frames. visible: [N, T]
        bool. depth: [T, H, W] depth prior. cfg: initialisation settings (cap on the number of
        tracks, random subsample with cfg.seed); model: the
            representation (N_s, feature size, scale activation, rotation init).
        always: [N] bool, tracks kept whatever the cap (the highlight tracks); the cap's random
            subsample is drawn from the others. None: none.
    Returns:
        VideoGaussians on the device / dtype of `depth`.
    """
    cfg = cfg or VideoInitConfig()
    model = model or ModelConfig()
    device, dtype = depth.device, depth.dtype
    tracks = tracks.to(device=device, dtype=dtype)
    visible = visible.to(device=device, dtype=torch.bool)
    n_all, t_count, _ = tracks.shape
    if depth.shape[0] != t_count:
        raise ValueError(
            f"init_video_gaussians: tracks cover {t_count} frames but depth has {depth.shape[0]}"
        )
    inside = (
        (tracks[..., 0] >= 0)
        & (tracks[..., 0] <= width)
        & (tracks[..., 1] >= 0)
        & (tracks[..., 1] <= height)
    )
    valid = visible & inside & torch.isfinite(tracks).all(-1)
    keep = torch.where(valid.sum(1) >= max(cfg.min_visible, 1))[0]
    gen = torch.Generator(device=device)
    gen.manual_seed(cfg.seed)
    # the cap: the `always` tracks, and a seeded random subset of the others in the room left
    a = torch.zeros_like(keep, dtype=torch.bool) if always is None else always.to(device)[keep]
    fixed, rest = keep[a], keep[~a]
    room = max(cfg.max_gaussians - fixed.numel(), 0)
    if rest.numel() > room:
        pick = torch.randperm(rest.numel(), generator=gen, device=device)[:room]
        rest = rest[pick.sort().values]
    keep = torch.cat([rest, fixed]).sort().values
    tracks, valid = tracks[keep], valid[keep]
    n = keep.numel()

    z = sample_depth(depth, torch.nan_to_num(tracks), width, height)  # [n, T]
    valid = valid & torch.isfinite(z) & (z > 0)
    traj = torch.cat([pixel_to_video_xy(tracks, width, height), z[..., None]], dim=-1)  # [n, T, 3]
    knots = spline.make_knots(t_count, model.control_every, dtype=dtype, device=device)
    times = torch.arange(t_count, dtype=dtype, device=device)
    ctrl = spline.fit_control_points(traj, valid, times, knots, smooth=cfg.fit_smooth)

    # scale from the kNN distance at the frame where most tracks are visible
    t_ref = int(valid.sum(0).argmax()) if n else 0
    pos_ref = spline.evaluate(ctrl, knots, float(t_ref))
    dist2 = knn_mean_sq_distance(pos_ref, cfg.knn_k).clamp_min(1e-7)
    s = dist2.sqrt()
    if model.video_scale_activation == "sigmoid":
        s = s.clamp_max(model.video_scale_max * (1.0 - 1e-3))
    scales_raw = scale_inverse(s, model.video_scale_activation, model.video_scale_max)[
        :, None
    ].repeat(1, 3)

    rot_coeffs = rot.init_rotation_coeffs(
        n, model.rotation_degree, model.rotation_init, dtype=dtype, device=device
    )
    opacity = torch.full((n,), _logit(cfg.init_opacity), dtype=dtype, device=device)
    features = (
        torch.randn(n, model.feature_dim, generator=gen, dtype=dtype, device=device)
        * cfg.feature_std
    )
    # beyond the paper: a gain over time starts at 1 (2 ** 0) at every knot
    gain = (
        torch.zeros(n, model.appearance_knots, dtype=dtype, device=device)
        if model.appearance_knots > 0
        else None
    )
    return VideoGaussians(
        ctrl,
        rot_coeffs,
        scales_raw,
        opacity,
        features,
        knots,
        t_count,
        model.video_scale_activation,
        model.video_scale_max,
        log2_gain=gain,
    )
