"""The training objective both stages optimise (paper sec. 3.3.3 "Overall Loss"):

    L = l_rgb L_rgb + l_ue L_ue + l_dep L_dep + l_track L_track + l_arap L_arap + l_vel L_vel
        + l_acc L_acc + l_tlr L_tlr (+ l_pr L_pr, stage 2)

(and, beyond the paper, with a brightness gain over time on the Gaussians, the smoothness of its
curves: `gain_smooth_term`, weight loss.lambda_gain_smooth)

with the weights of a stage's `LossConfig` (m4dgs.training.config; appendix "Implementation
Details"). Each term is a small pure function of tensors returning ``(name, value)``; `assemble`
samples one iteration's frames (`sample_frames`), renders them through the stage and adds the terms
the config and the ablation switches enable, in a fixed order (the order of the float additions of
`total_loss`). A stage supplies only what differs (m4dgs.training.stage.Stage): its camera model
(`CameraModel`: the orthographic video camera of stage 1, the refined pinhole cameras of stage 2),
its Gaussians (the set whose motion is regularised: `Trajectories`) and its own terms (stage 2: the
HDR / LDR photometric reprojection losses).

Space conventions: in stage 1 (video space) positions, depths and the depth prior are in the prior's
units; in stage 2 (world space) the depth prior is scaled per frame by the bundle-adjustment depth
scales, and depth / motion terms are divided by the scene extent (median world depth) so that their
weights keep the meaning they have in video space."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np
import torch

from m4dgs.core import camera as cam
from m4dgs.core import rotation as rot
from m4dgs.core import spline
from m4dgs.core.knn import knn
from m4dgs.core.tensors import gather_rows
from m4dgs.losses.geometry import depth_loss, flow_from_destination_map, flow_loss, track_loss
from m4dgs.losses.motion import relative_to_neighbours
from m4dgs.losses.motion import smoothness_terms as motion_smoothness
from m4dgs.losses.photometric import rgb_loss, unit_exposure_loss
from m4dgs.losses.temporal import tlr_den_floor, tlr_loss, tlr_valid_mask
from m4dgs.model.gaussians import gain_second_differences
from m4dgs.model.tonemap import monotonicity_penalty
from m4dgs.training.config import AblationConfig, LossConfig, ToneMapConfig
from m4dgs.training.data import TrainingData

Tensor = torch.Tensor
Term = Tuple[str, Tensor]

# the ARAP neighbour sets are recomputed every this many iterations (and when the set changes)
KNN_REFRESH_EVERY = 100


# --------------------------------------------------------------------------------------------------
# camera model and per-iteration sample
# --------------------------------------------------------------------------------------------------
@dataclass
class CameraModel:
    """How a stage's renders relate to pixels and to the depth prior.

    K None: the orthographic video camera of stage 1 (destination maps hold video positions, whose z
    is the depth). Otherwise pinhole intrinsics K [3, 3] with per-frame poses c2w / w2c [T, 4, 4]
    (stage 2; gradients reach the cameras through them), the per-frame depth-prior scales
    depth_scale [T] and the scene extent dividing the depth and motion terms."""

    K: Optional[Tensor] = None
    c2w: Optional[Tensor] = None
    w2c: Optional[Tensor] = None
    depth_scale: Optional[Tensor] = None
    extent: float = 1.0

    def destination(self, j: int, detach: bool = False) -> Dict[str, Tensor]:
        """Keyword arguments of the flow / track functions for destination frame j."""
        if self.K is None:
            return {}
        w2c = self.w2c[j]
        return {"K": self.K, "w2c_dst": w2c.detach() if detach else w2c}

    def flow(
        self, dest: Tensor, alpha: Tensor, j: int, detach: bool = False
    ) -> Tuple[Tensor, Tensor]:
        """Rendered flow F~_{t->j} [H, W, 2] and its validity [H, W] from a destination map."""
        return flow_from_destination_map(dest, alpha=alpha, **self.destination(j, detach))

    def depth_at(self, points: Tensor, j: int) -> Tensor:
        """Depth of positions [..., 3] (at time j) in frame j's camera (cameras detached)."""
        if self.K is None:
            return points[..., 2]
        return cam.transform_points(self.w2c[j].detach(), points)[..., 2]

    def depth_prior(self, prior: Tensor, i: int) -> Tensor:
        """The depth prior of frame i in the units of the rendered depth."""
        return prior if self.depth_scale is None else prior * self.depth_scale[i]


@dataclass
class FrameSample:
    """The frames of one iteration: query frame i, flow / track target j (i when none), whether
    the flow (else the track) prior supervises, whether that term is on, and the TLR neighbours."""

    i: int
    j: int
    use_flow: bool
    track: bool
    tlr_neighbours: List[int] = field(default_factory=list)

    def dest_times(self, always_target: bool = False) -> List[float]:
        """Destination times rendered with frame i: j when the flow / track term is on (or
        `always_target`), then the TLR neighbours."""
        with_j = self.track or always_target
        return ([float(self.j)] if with_j else []) + [float(k) for k in self.tlr_neighbours]


def sample_frames(
    rng: np.random.Generator,
    data: TrainingData,
    loss: LossConfig,
    ablation: AblationConfig,
    tlr_on: bool,
    motion: bool = True,
) -> FrameSample:
    """Draw one iteration's frames (appendix "Flow/Track Loss"): i uniform; with probability
    flow_prob (when frame i has prior flows) a flow target t +- N_e, else a random other frame for
    the track loss; the TLR neighbours i +- 1 when `tlr_on`. `motion` False (static Gaussians only)
    switches the flow / track term off."""
    T = data.num_frames
    i = int(rng.integers(T))
    flow_targets = data.flow_targets(i) if data.flow is not None else []
    use_flow = bool(flow_targets) and rng.random() < loss.flow_prob
    if use_flow:
        j = int(rng.choice(flow_targets))
    else:
        j = int(rng.choice([k for k in range(T) if k != i])) if T > 1 else i
    nbrs = [k for k in (i - 1, i + 1) if 0 <= k < T] if tlr_on else []
    track = motion and ablation.track_loss and loss.lambda_track > 0 and j != i
    return FrameSample(i, j, use_flow, track, nbrs)


@dataclass
class Trajectories:
    """The Gaussians whose motion is regularised: spline control points ctrl [N, K, 3] on `knots`,
    rotation polynomial coefficients rot [N, J, 4] over `num_frames` frames (stage 1: every video
    Gaussian; stage 2: the dynamic world Gaussians)."""

    ctrl: Tensor
    rot: Tensor
    knots: Tensor
    num_frames: int
    memo: Optional[spline.BasisMemo] = None  # the model's (its Gaussians' spline_memo)

    @property
    def count(self) -> int:
        return self.ctrl.shape[0]

    def positions(self, t) -> Tensor:
        return spline.evaluate(self.ctrl, self.knots, t, self.memo)


class KnnCache:
    """The ARAP neighbour sets (k nearest neighbours at the query time), recomputed when the number
    of Gaussians changes, every KNN_REFRESH_EVERY iterations, or after `invalidate()` (the stages
    call it when densification or a removal pass ran)."""

    def __init__(self, refresh_every: int = KNN_REFRESH_EVERY):
        self.refresh_every = refresh_every
        self._entry: Optional[Tuple[int, int, Tensor]] = None

    def neighbours(self, points: Tensor, k: int, it: int) -> Tensor:
        """[N, k] neighbour indices of points [N, 3] (cached)."""
        n = points.shape[0]
        e = self._entry
        if e is None or e[0] != n or it - e[1] >= self.refresh_every:
            self._entry = (n, it, knn(points.detach(), k)[0])
        return self._entry[2]

    def invalidate(self) -> None:
        self._entry = None

    def state_dict(self) -> Dict[str, object]:
        """The cached neighbour sets (for checkpoints: a resumed run reuses the same neighbours as
        an uninterrupted one until the next refresh)."""
        return {"entry": self._entry}

    def load_state_dict(self, sd: Dict[str, object]) -> None:
        self._entry = sd.get("entry")


class LossOutput(NamedTuple):
    """The terms of one iteration (insertion order = addition order) and the render metadata of the
    query frame (its means2d / radii drive densification)."""

    terms: Dict[str, Tensor]
    meta: object


# --------------------------------------------------------------------------------------------------
# terms: pure functions of tensors -> (name, value)
# --------------------------------------------------------------------------------------------------
def rgb_term(ldr: Tensor, target: Tensor, lambda_d: float) -> Term:
    """L_rgb = lambda_d DSSIM + (1 - lambda_d) L1 between the tone-mapped render and the input."""
    return "rgb", rgb_loss(ldr, target, lambda_d=lambda_d)


def unit_exposure_term(tm, c0: float) -> Term:
    """L_ue = ||phi(0) - C_0||^2 (appendix "Unit Exposure Loss")."""
    return "ue", unit_exposure_loss(tm.unit_exposure_value(), c0)


def depth_term(depth: Tensor, prior: Tensor, alpha: Tensor, extent: float = 1.0) -> Term:
    """L1 to the depth prior where the render is opaque (alpha > 0.5), over the scene extent."""
    return "dep", depth_loss(depth, prior, valid=alpha.detach() > 0.5) / extent


def flow_term(
    dest: Tensor,
    alpha: Tensor,
    prior_flow: Tensor,
    prior_valid: Tensor,
    camera: CameraModel,
    j: int,
) -> Term:
    """L1 between the rendered flow F~_{t->j} (from the destination map) and the prior flow."""
    pred, valid = camera.flow(dest, alpha, j)
    return "track", flow_loss(pred, prior_flow, prior_valid & valid, norm="l1")


def track_term(
    dest: Tensor, alpha: Tensor, src_uv: Tensor, dst_uv: Tensor, camera: CameraModel, j: int
) -> Term:
    """L1 between where the destination map sends the prior tracks' points of t and their
    positions at j."""
    return "track", track_loss(
        dest, src_uv, dst_uv, alpha=alpha, norm="l1", **camera.destination(j)
    )


def arap_term(pos_t: Tensor, pos_t2: Tensor, nbr: Tensor, sub: Tensor, extent: float = 1.0) -> Term:
    """ARAP on the subset `sub` of Gaussians: squared change of the distances to their k nearest
    neighbours (indices `nbr` [N, k] into the full set) between t and t2, over extent^2."""
    idx = nbr[sub]  # [n, k]
    # gathers whose gradient does not depend on the thread count (repeated neighbour indices)
    d_t = (gather_rows(pos_t, sub)[:, None] - gather_rows(pos_t, idx)).norm(dim=-1)
    d_t2 = (gather_rows(pos_t2, sub)[:, None] - gather_rows(pos_t2, idx)).norm(dim=-1)
    return "arap", ((d_t - d_t2) ** 2).mean() / extent**2


def smooth_window(i: int, num_frames: int, half_width: int) -> Tuple[int, int]:
    """Frames [lo, hi) of the velocity / acceleration window around query frame i: i - half_width
    .. i + half_width cut at the clip's ends; half_width < 0: every frame (the paper's sum)."""
    if half_width < 0:
        return 0, num_frames
    return max(0, i - half_width), min(num_frames, i + half_width + 1)


def smoothness_terms(positions: Tensor, quats: Tensor) -> List[Term]:
    """Velocity and acceleration losses on a window: positions [W, n, 3], quats [W, n, 4] (the
    four parts computed once: m4dgs.losses.motion.smoothness_terms)."""
    parts = motion_smoothness(positions, quats)
    return [
        ("vel", parts["pos_vel"] + parts["rot_vel"]),
        ("acc", parts["pos_acc"] + parts["rot_acc"]),
    ]


def tlr_term(
    hdr: Tensor,
    neighbours: Sequence[Tuple[Tensor, Tensor, Tensor, Tensor, Tensor]],
    occlusion_ratio: float,
    neighbour_grad: bool = False,
    den_floor: float = 0.0,
    keep: Optional[Tensor] = None,
) -> Term:
    """Temporal luminance regularisation of the HDR render at t, averaged over its neighbours, each
    (hdr_nb [H, W, 3], depth_nb [H, W], flow [H, W, 2], flow_valid [H, W], depth_ref [H, W]): the
    neighbour's render and depth, the rendered flow to it and the depth of each pixel's point at the
    neighbour's time (depth-order occlusion test at occlusion_ratio). neighbour_grad: the gradient
    also reaches the neighbour's render (`loss.tlr_neighbour_grad`); den_floor: the fraction of
    hdr's median added to the denominator (`loss.tlr_den_floor`, 0 = the paper's); keep: optional
    [H, W] bool, the pixels of t that TLR may move (`shoulder_keep`; None = every pixel)."""
    terms = []
    floor = tlr_den_floor(hdr, den_floor)
    for hdr_nb, depth_nb, flow, fvalid, zref in neighbours:
        valid = fvalid & tlr_valid_mask(flow, depth_nb, zref, ratio=occlusion_ratio)
        if keep is not None:
            valid = valid & keep
        terms.append(
            tlr_loss(hdr, hdr_nb, flow, valid, detach_neighbour=not neighbour_grad, den_floor=floor)
        )
    return "tlr", torch.stack(terms).mean()


def shoulder_keep(ldr: Tensor, shoulder: Optional[float]) -> Optional[Tensor]:
    """The pixels below the tone curve's shoulder: [H, W, 3] tone-mapped render (at the frame's own
    exposure) -> [H, W] bool, true where every channel is under `shoulder` (`loss.tlr_shoulder`;
    no gradient), or None when `shoulder` is None (TLR on every pixel, the paper's)."""
    if shoulder is None:
        return None
    return (ldr.detach() < shoulder).all(dim=-1)


def monotonic_term(tm) -> Term:
    """ReLU of the tone mapper's negative slope (authors' code; tonemap.lambda_monotonic)."""
    return "mono", monotonicity_penalty(tm)


def opacity_term(gauss) -> Term:
    """Pull opacities towards 1 (authors' code; loss.lambda_opacity)."""
    return "opacity", (1.0 - gauss.opacities()).mean()


def scale_std_term(gauss) -> Term:
    """Standard deviation of each Gaussian's three scales (authors' code; loss.lambda_scale_std)."""
    return "scale_std", gauss.scales().std(dim=-1).mean()


def flat_term(gauss) -> Term:
    """Beyond the paper (loss.lambda_flat): the mean over Gaussians of smallest / largest scale, in
    [0, 1] (0 for a disc, 1 for a ball)."""
    s = gauss.scales()
    return "flat", (s.min(dim=-1).values / s.max(dim=-1).values.clamp_min(1e-12)).mean()


def gain_smooth_term(values: Tensor) -> Term:
    """Beyond the paper (loss.lambda_gain_smooth): the mean over Gaussians and inner knots of the
    squared second differences of the log2-gain knot values [N, K] (stops^2; zero for K < 3,
    where every curve is a constant or a straight line)."""
    d2 = gain_second_differences(values)
    if d2.numel() == 0:
        return "gain_smooth", values.sum() * 0.0
    return "gain_smooth", (d2**2).mean()


# --------------------------------------------------------------------------------------------------
# weights and assembly
# --------------------------------------------------------------------------------------------------
def loss_weights(
    loss: LossConfig, tonemap: ToneMapConfig, stage_weights: Optional[Dict[str, float]] = None
) -> Dict[str, float]:
    """Weight of every term name: the shared ones, a stage's own (e.g. {"pr": lambda_pr}), and the
    tone mapper's monotonicity weight."""
    return {
        "rgb": loss.lambda_rgb,
        "ue": loss.lambda_ue,
        "dep": loss.lambda_dep,
        "track": loss.lambda_track,
        "arap": loss.lambda_arap,
        "vel": loss.lambda_vel,
        "acc": loss.lambda_acc,
        "tlr": loss.lambda_tlr,
        **(stage_weights or {}),
        "mono": tonemap.lambda_monotonic,
        "opacity": loss.lambda_opacity,
        "scale_std": loss.lambda_scale_std,
        "flat": loss.lambda_flat,
        "gain_smooth": loss.lambda_gain_smooth,
    }


def total_loss(terms: Dict[str, Tensor], weights: Dict[str, float]) -> Tensor:
    """sum_k w_k L_k in the terms' order."""
    return sum(weights[k] * v for k, v in terms.items())


def assemble(stage, it: int) -> LossOutput:
    """One iteration's loss terms for `stage` (m4dgs.training.stage.Stage): sample the frames,
    render the query frame with the destination maps the terms need, then add in this order rgb,
    ue, dep, track, arap, vel, acc, tlr, the stage's own terms, mono, opacity, scale_std, flat
    (beyond the paper) and, when the Gaussians carry a gain over time (beyond the paper),
    gain_smooth (each only when its weight is > 0 and its ablation switch is on; rgb and ue
    always).

    The stage's generator draws, in this order: i, the flow-vs-track coin (when frame i has prior
    flows), j, and, when the moving set holds more than arap_k Gaussians, the motion subset and
    (ARAP on) the ARAP time t2. Without motion (static Gaussians only) there is no flow / track,
    TLR or motion term."""
    cfg, lc, ab, d = stage.cfg, stage.loss_cfg, stage.cfg.ablation, stage.data
    T = d.num_frames
    camera = stage.camera_model()
    motion = stage.motion
    tlr_on = motion and ab.tlr and lc.lambda_tlr > 0 and it >= stage.tlr_start_step()
    s = sample_frames(stage.rng, d, lc, ab, tlr_on, motion)
    i, j = s.i, s.j
    r = stage.render_view(float(i), i, camera, s.dest_times(stage.always_render_target))
    L: Dict[str, Tensor] = {}

    def add(term: Term) -> None:
        L[term[0]] = term[1]

    ldr = stage.tm(r.hdr, stage.log2_dt[i])
    add(rgb_term(ldr, d.ldr[i], lc.lambda_dssim))
    add(unit_exposure_term(stage.tm, stage.c0))
    if ab.depth_loss and lc.lambda_dep > 0:
        add(depth_term(r.depth, camera.depth_prior(d.depth[i], i), r.alpha, camera.extent))
    if s.track:
        if s.use_flow:
            p = d.flow_index(i, j)
            add(flow_term(r.dest[0], r.alpha, d.flow[p], d.flow_valid[p], camera, j))
        else:
            vis = d.track_vis[:, i] & d.track_vis[:, j]
            if bool(vis.any()):
                add(track_term(r.dest[0], r.alpha, d.tracks[vis, i], d.tracks[vis, j], camera, j))
    # motion regularisers on a random subset of the moving Gaussians
    traj = stage.trajectories()
    n = traj.count
    if motion and n > lc.arap_k:
        size = n if lc.motion_subset <= 0 else min(n, lc.motion_subset)
        sub = torch.from_numpy(stage.rng.choice(n, size=size, replace=False)).to(stage.device)
        smooth = (lc.lambda_vel > 0 or lc.lambda_acc > 0) and T > 2
        nbr = None
        if lc.lambda_arap > 0:
            pos_t = traj.positions(float(i))
            pos_t2 = traj.positions(float(stage.rng.integers(T)))
            nbr = stage.knn.neighbours(pos_t, lc.arap_k, it)
            add(arap_term(pos_t, pos_t2, nbr, sub, camera.extent))
        elif smooth and lc.smooth_relative:
            nbr = stage.knn.neighbours(traj.positions(float(i)), lc.arap_k, it)
        if smooth:
            lo, hi = smooth_window(i, T, lc.smooth_half_width)
            times = torch.arange(lo, hi, dtype=torch.float32, device=stage.device)
            if times.numel() >= 3:
                # [W, n, 3] / [W, n, 4]
                # the window's times from the host too (a key for the memo without a device read)
                host_times = [float(v) for v in range(lo, hi)]
                pos = spline.evaluate(traj.ctrl[sub], traj.knots, host_times, traj.memo)
                pos = pos.transpose(0, 1)
                if lc.smooth_relative:  # beyond the paper: motion relative to the neighbours'
                    k = nbr.shape[1]
                    around = spline.evaluate(
                        traj.ctrl[nbr[sub].reshape(-1)], traj.knots, host_times, traj.memo
                    )  # [n k, W, 3]
                    around = around.reshape(sub.numel(), k, len(host_times), 3).permute(2, 0, 1, 3)
                    pos = relative_to_neighbours(pos, around)
                q = rot.poly_evaluate(
                    traj.rot[sub], rot.normalize_time(times, traj.num_frames), normalize=True
                ).transpose(0, 1)
                for term in smoothness_terms(pos / camera.extent, q):
                    add(term)
    if s.tlr_neighbours:
        base = 1 if s.track or stage.always_render_target else 0
        alpha = r.alpha.detach()
        nbrs = []
        for n_idx, k in enumerate(s.tlr_neighbours):
            # the neighbour's render carries no gradient unless loss.tlr_neighbour_grad (its camera
            # never does)
            with torch.set_grad_enabled(lc.tlr_neighbour_grad):
                rn = stage.render_view(float(k), k, camera, detach_camera=True)
            dm = r.dest[base + n_idx].detach()
            flow, fvalid = camera.flow(dm, alpha, k, detach=True)
            zref = camera.depth_at(dm / alpha.clamp_min(1e-6)[..., None], k)
            nbrs.append((rn.hdr, rn.depth, flow, fvalid, zref))
        keep = shoulder_keep(ldr, lc.tlr_shoulder)
        add(
            tlr_term(
                r.hdr, nbrs, lc.tlr_occlusion_ratio, lc.tlr_neighbour_grad, lc.tlr_den_floor, keep
            )
        )
    for term in stage.stage_terms(it, s, r, camera):
        add(term)
    if cfg.tonemap.lambda_monotonic > 0:
        add(monotonic_term(stage.tm))
    if lc.lambda_opacity > 0:
        add(opacity_term(stage.gauss))
    if lc.lambda_scale_std > 0:
        add(scale_std_term(stage.gauss))
    if lc.lambda_flat > 0:
        add(flat_term(stage.gauss))
    gains = stage.gauss.gain_values()
    if gains is not None and lc.lambda_gain_smooth > 0:
        add(gain_smooth_term(gains))
    return LossOutput(L, r.meta)
