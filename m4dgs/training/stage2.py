"""Stage 2: static + dynamic world Gaussians with joint camera refinement (paper sec. 3.3.2-3.3.3,
appendix).

World Gaussians (the union of a static set and a dynamic spline set, from the video-to-world
transform or, for the "no video init" ablation and the world-only baselines, from lifted tracks) are
rendered with a pinhole camera whose per-frame pose corrections are optimised jointly. Losses: every
stage-1 loss (now with pinhole flow/track maps and the depth prior mapped to world depth by the
bundle-adjustment depth scales) plus the HDR photometric reprojection loss against the stage-1 HDR
renders (stopped gradients, t' in {t +- 1, t +- 2}, static pixels only). Static and dynamic
Gaussians have their own densification schedules; mistakenly densified dynamic Gaussians are removed
periodically by re-running the dynamic/static identification on their projected trajectories."""

from __future__ import annotations

from typing import Any, Callable, Dict, Optional

import numpy as np
import torch

from m4dgs.core import camera as cam
from m4dgs.core import rotation as rot
from m4dgs.core import spline
from m4dgs.losses.geometry import depth_loss, flow_from_destination_map, flow_loss, track_loss
from m4dgs.losses.motion import acceleration_loss, knn, velocity_loss
from m4dgs.losses.photometric import rgb_loss, unit_exposure_loss
from m4dgs.losses.temporal import (
    hdr_reprojection_loss,
    ldr_reprojection_loss,
    tlr_loss,
    tlr_valid_mask,
)
from m4dgs.model.color import ColorMLP
from m4dgs.model.gaussians import WorldGaussians
from m4dgs.model.tonemap import ToneMapper, monotonicity_penalty
from m4dgs.raster import render
from m4dgs.training.config import TrainConfig
from m4dgs.training.data import TrainingData
from m4dgs.training.densify import Strategy
from m4dgs.training.stage1 import Background, RenderResult, _arap_subset, train_loop

STATIC_KEYS = ("means", "quats", "scales", "opacities", "features")
DYNAMIC_KEYS = ("ctrl", "rot", "scales", "opacities", "features")


def axis_angle_to_rotmat(w: torch.Tensor) -> torch.Tensor:
    """Rodrigues: [..., 3] axis-angle -> [..., 3, 3] rotation (stable at 0 through the Taylor
    terms)."""
    theta2 = (w * w).sum(-1, keepdim=True)[..., None]
    theta = theta2.clamp_min(1e-20).sqrt()
    small = theta2 < 1e-8
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta2.clamp_min(1e-20))
    x, y, z = w.unbind(-1)
    o = torch.zeros_like(x)
    Kx = torch.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(*w.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(Kx)
    return eye + a * Kx + b * (Kx @ Kx)


def render_world(
    gauss: WorldGaussians,
    color: ColorMLP,
    bg: Background,
    t: float,
    c2w: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    backend: str = "auto",
    dest_times=(),
) -> RenderResult:
    """Render world Gaussians at time t from a pinhole camera c2w [4, 4] with intrinsics K [3, 3].

    Features: HDR colour (3) + the Gaussians' world positions at each destination time (3 each),
    alpha-blended."""
    means = gauss.positions(t)
    feats = torch.cat(
        [color(gauss.features())] + [gauss.positions(float(d)) for d in dest_times], -1
    )
    background = torch.cat([bg(), means.new_zeros(feats.shape[1] - 3)])
    out = render(
        means,
        gauss.quats(t),
        gauss.scales(),
        gauss.opacities(),
        feats,
        cam.invert_rigid(c2w),
        K,
        width,
        height,
        camera_model="pinhole",
        backend=backend,
        background=background,
    )
    f = out.features
    dest = [f[..., 3 + 3 * i : 6 + 3 * i] for i in range(len(dest_times))]
    return RenderResult(f[..., :3], out.depth[..., 0], out.alpha[..., 0], dest, out.meta)


class CameraRig(torch.nn.Module):
    """Per-frame camera poses as fixed initial c2w times a learnable right correction (rotation,
    translation)."""

    def __init__(self, K: torch.Tensor, c2w_init: torch.Tensor):
        super().__init__()
        T = c2w_init.shape[0]
        self.register_buffer("K", K.float())
        self.register_buffer("c2w_init", c2w_init.float())
        self.dw = torch.nn.Parameter(torch.zeros(T, 3))
        self.dt = torch.nn.Parameter(torch.zeros(T, 3))

    def c2w(self) -> torch.Tensor:
        """[T, 4, 4] current camera-to-world poses."""
        R = self.c2w_init[:, :3, :3] @ axis_angle_to_rotmat(self.dw)
        t = self.c2w_init[:, :3, 3] + (self.c2w_init[:, :3, :3] @ self.dt[..., None])[..., 0]
        top = torch.cat([R, t[..., None]], -1)
        bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], device=R.device).expand(R.shape[0], 1, 4)
        return torch.cat([top, bottom], -2)


class WorldStage:
    """Stage-2 model + optimisation state; `step(it)` runs one iteration,
    `state_dict()`/`load_state_dict()` resume."""

    def __init__(
        self,
        data: TrainingData,
        cfg: TrainConfig,
        gauss: WorldGaussians,
        color: ColorMLP,
        tm: ToneMapper,
        bg: Background,
        K: torch.Tensor,
        c2w: torch.Tensor,
        depth_scale: torch.Tensor,
        dynamic_masks: Optional[torch.Tensor],
        stage1_hdr: Optional[torch.Tensor],
        log2_dt: torch.Tensor,
        device="cpu",
        backend: str = "auto",
        ldr_reproj: bool = False,
        static_only: bool = False,
    ):
        self.data, self.cfg, self.device, self.backend = data, cfg, torch.device(device), backend
        cfg.stage2.validate()
        self.W, self.H = data.width, data.height
        self.c0 = float(cfg.exposure.unit_exposure_value or data.unit_exposure_value)
        self.log2_dt = log2_dt.to(self.device)
        self.depth_scale = depth_scale.float().to(self.device)
        self.dynamic_masks = None if dynamic_masks is None else dynamic_masks.bool().to(self.device)
        self.stage1_hdr = None if stage1_hdr is None else stage1_hdr.float().to(self.device)
        self.ldr_reproj, self.static_only = ldr_reproj, static_only
        self.rng = np.random.default_rng(cfg.seed + 1)
        self.rig = CameraRig(K.to(self.device), c2w.to(self.device))
        # position learning rates scale with the scene extent (3DGS); extent = median world depth
        d = data.depth.to(self.device) * self.depth_scale[:, None, None]
        self.extent = float(d[d > 0].median()) if bool((d > 0).any()) else 1.0
        self._setup(gauss.to(self.device), color, tm, bg)

    def _setup(self, gauss: WorldGaussians, color, tm, bg):
        s2 = self.cfg.stage2
        self.gauss, self.color, self.tm, self.bg = gauss, color, tm, bg
        lr = s2.lr
        pos = lr.position_init * self.extent
        mk = lambda p, l: torch.optim.Adam([p], lr=l, eps=lr.adam_eps)  # noqa: E731
        lrs = {
            "means": pos,
            "ctrl": pos,
            "quats": lr.rotation,
            "rot": lr.rotation,
            "scales": lr.scale,
            "opacities": lr.opacity,
            "features": lr.features,
        }
        self.opt_static = {k: mk(gauss.static[k], lrs[k]) for k in STATIC_KEYS}
        self.opt_dynamic = {k: mk(gauss.dynamic[k], lrs[k]) for k in DYNAMIC_KEYS}
        self.opt_other = {
            "color": torch.optim.Adam(color.parameters(), lr=lr.mlp, eps=lr.adam_eps),
            "tonemap": torch.optim.Adam(tm.parameters(), lr=lr.mlp, eps=lr.adam_eps),
            "background": torch.optim.Adam(bg.parameters(), lr=lr.mlp, eps=lr.adam_eps),
            "camera": torch.optim.Adam(
                [
                    {"params": [self.rig.dw], "lr": lr.camera_rotation},
                    {"params": [self.rig.dt], "lr": lr.camera_translation * self.extent},
                ],
                eps=lr.adam_eps,
            ),
        }
        self.strat_static = Strategy(s2.densify_static, gauss.static_layout(), seed=self.cfg.seed)
        self.strat_dynamic = Strategy(
            s2.densify_dynamic, gauss.dynamic_layout(), seed=self.cfg.seed + 7
        )
        self.state_static = self.strat_static.initialize_state()
        self.state_dynamic = self.strat_dynamic.initialize_state()
        self._knn_cache = None

    @property
    def optimize_cameras(self) -> bool:
        return self.cfg.stage2.optimize_cameras and not self.static_only

    def cameras(self) -> torch.Tensor:
        c = self.rig.c2w()
        return c if self.optimize_cameras else c.detach()

    # -- rendering
    # ----------------------------------------------------------------------------------------------
    def render_at(
        self,
        t: float,
        c2w: torch.Tensor,
        K: Optional[torch.Tensor] = None,
        width: Optional[int] = None,
        height: Optional[int] = None,
        dest_times=(),
    ) -> RenderResult:
        """Render at time t from camera c2w [4, 4]; features: HDR colour + world positions at each
        destination time."""
        return render_world(
            self.gauss,
            self.color,
            self.bg,
            t,
            c2w,
            self.rig.K if K is None else K,
            width or self.W,
            height or self.H,
            self.backend,
            dest_times,
        )

    # -- one iteration
    # ----------------------------------------------------------------------------------------------
    def losses(self, it: int) -> Dict[str, torch.Tensor]:
        cfg, s2, d = self.cfg, self.cfg.stage2, self.data
        T = d.num_frames
        c2w = self.cameras()
        w2c = cam.invert_rigid(c2w)
        i = int(self.rng.integers(T))
        motion = not self.static_only
        flow_targets = d.flow_targets(i) if d.flow is not None else []
        use_flow = bool(flow_targets) and self.rng.random() < s2.flow_prob
        if use_flow:
            j = int(self.rng.choice(flow_targets))
        else:
            j = int(self.rng.choice([k for k in range(T) if k != i])) if T > 1 else i
        tlr_on = motion and cfg.ablation.tlr and s2.lambda_tlr > 0 and it >= s2.tlr_start_step()
        nbrs = [k for k in (i - 1, i + 1) if 0 <= k < T] if tlr_on else []
        track_on = motion and cfg.ablation.track_loss and s2.lambda_track > 0 and j != i
        dests = ([float(j)] if track_on else []) + [float(k) for k in nbrs]
        r = self.render_at(float(i), c2w[i], dest_times=dests)
        L: Dict[str, torch.Tensor] = {}
        ldr = self.tm(r.hdr, self.log2_dt[i])
        L["rgb"] = rgb_loss(ldr, d.ldr[i], lambda_d=s2.lambda_dssim)
        L["ue"] = unit_exposure_loss(self.tm.unit_exposure_value(), self.c0)
        if cfg.ablation.depth_loss and s2.lambda_dep > 0:
            L["dep"] = (
                depth_loss(r.depth, d.depth[i] * self.depth_scale[i], valid=r.alpha.detach() > 0.5)
                / self.extent
            )
        if track_on:
            if use_flow:
                p = d.flow_index(i, j)
                pred, v = flow_from_destination_map(
                    r.dest[0], K=self.rig.K, w2c_dst=w2c[j], alpha=r.alpha
                )
                L["track"] = flow_loss(pred, d.flow[p], d.flow_valid[p] & v, norm="l1")
            else:
                vis = d.track_vis[:, i] & d.track_vis[:, j]
                if bool(vis.any()):
                    L["track"] = track_loss(
                        r.dest[0],
                        d.tracks[vis, i],
                        d.tracks[vis, j],
                        K=self.rig.K,
                        w2c_dst=w2c[j],
                        alpha=r.alpha,
                        norm="l1",
                    )
        g = self.gauss
        nd = g.num_dynamic
        if motion and nd > s2.arap_k:
            sub = torch.from_numpy(self.rng.choice(nd, size=min(nd, 4096), replace=False)).to(
                self.device
            )
            ctrl, coeff = g.dynamic["ctrl"], g.dynamic["rot"]
            if s2.lambda_arap > 0:
                pos_t = spline.evaluate(ctrl, g.knots, float(i))
                pos_t2 = spline.evaluate(ctrl, g.knots, float(self.rng.integers(T)))
                if (
                    self._knn_cache is None
                    or self._knn_cache[0] != nd
                    or it - self._knn_cache[1] >= 100
                ):
                    self._knn_cache = (nd, it, knn(pos_t.detach(), s2.arap_k)[0])
                L["arap"] = _arap_subset(pos_t, pos_t2, self._knn_cache[2], sub) / self.extent**2
            if (s2.lambda_vel > 0 or s2.lambda_acc > 0) and T > 2:
                w = s2.smooth_window
                times = torch.arange(
                    max(0, i - w - 1), min(T, i + w + 2), dtype=torch.float32, device=self.device
                )
                if times.numel() >= 3:
                    pos = spline.evaluate(ctrl[sub], g.knots, times).transpose(0, 1) / self.extent
                    q = rot.poly_evaluate(
                        coeff[sub], rot.normalize_time(times, g.num_frames), normalize=True
                    ).transpose(0, 1)
                    L["vel"] = velocity_loss(pos, q)
                    L["acc"] = acceleration_loss(pos, q)
        if nbrs:
            terms = []
            base = 1 if track_on else 0
            for n_idx, k in enumerate(nbrs):
                with torch.no_grad():
                    rn = self.render_at(float(k), c2w[k].detach())
                dm = r.dest[base + n_idx].detach()
                flow, fvalid = flow_from_destination_map(
                    dm, K=self.rig.K, w2c_dst=w2c[k].detach(), alpha=r.alpha.detach()
                )
                p_cam = cam.transform_points(
                    w2c[k].detach(), dm / r.alpha.detach().clamp_min(1e-6)[..., None]
                )
                valid = fvalid & tlr_valid_mask(
                    flow, rn.depth, p_cam[..., 2], ratio=s2.tlr_occlusion_ratio
                )
                terms.append(tlr_loss(r.hdr, rn.hdr, flow, valid))
            L["tlr"] = torch.stack(terms).mean()
        pr_active = s2.pr_steps is None or it < s2.pr_steps
        if pr_active and self.optimize_cameras:
            mask = None if self.dynamic_masks is None else self.dynamic_masks[i]
            if self.ldr_reproj:
                refs = ldr_reprojection_refs(i, T, d.num_levels, s2.ldr_reproj_pairs)
                if refs:
                    L["pr"] = torch.stack(
                        [
                            ldr_reprojection_loss(
                                d.ldr[i], d.ldr[k], r.depth, self.rig.K, c2w[i], c2w[k], mask
                            )
                            for k in refs
                        ]
                    ).mean()
            elif cfg.ablation.reproj_loss and self.stage1_hdr is not None and s2.lambda_pr > 0:
                refs = [i + o for off in s2.pr_offsets for o in (-off, off) if 0 <= i + o < T]
                if refs:
                    query = self.stage1_hdr[i] if s2.pr_query == "stage1" else r.hdr
                    L["pr"] = torch.stack(
                        [
                            hdr_reprojection_loss(
                                query, self.stage1_hdr[k], r.depth, self.rig.K, c2w[i], c2w[k], mask
                            )
                            for k in refs
                        ]
                    ).mean()
        if cfg.tonemap.lambda_monotonic > 0:
            L["mono"] = monotonicity_penalty(self.tm)
        if s2.lambda_opacity > 0:
            L["opacity"] = (1.0 - g.opacities()).mean()
        if s2.lambda_scale_std > 0:
            L["scale_std"] = g.scales().std(dim=-1).mean()
        self._last_meta = r.meta
        return L

    def weights(self) -> Dict[str, float]:
        s2, tm = self.cfg.stage2, self.cfg.tonemap
        return {
            "rgb": s2.lambda_rgb,
            "ue": s2.lambda_ue,
            "dep": s2.lambda_dep,
            "track": s2.lambda_track,
            "arap": s2.lambda_arap,
            "vel": s2.lambda_vel,
            "acc": s2.lambda_acc,
            "tlr": s2.lambda_tlr,
            "pr": s2.lambda_pr,
            "mono": tm.lambda_monotonic,
            "opacity": s2.lambda_opacity,
            "scale_std": s2.lambda_scale_std,
        }

    def _all_optimizers(self):
        return (
            list(self.opt_static.values())
            + list(self.opt_dynamic.values())
            + list(self.opt_other.values())
        )

    def step(self, it: int) -> Dict[str, float]:
        s2 = self.cfg.stage2
        for o in self._all_optimizers():
            o.zero_grad(set_to_none=True)
        lr = s2.lr.position_lr(it, s2.iterations) * self.extent
        for o in (self.opt_static["means"], self.opt_dynamic["ctrl"]):
            for group in o.param_groups:
                group["lr"] = lr
        L = self.losses(it)
        w = self.weights()
        total = sum(w[k] * v for k, v in L.items())
        meta = self._last_meta
        info = {"means2d": meta.means2d, "radii": meta.radii, "width": self.W, "height": self.H}
        if meta.means2d.requires_grad and not meta.means2d.is_leaf:
            meta.means2d.retain_grad()
        total.backward()
        for o in self._all_optimizers():
            o.step()
        counts = {}
        if meta.means2d.grad is not None:
            info_s, info_d = self.gauss.split_render_info(info)
            cs = self.strat_static.step_post_backward(
                self.gauss.static, self.opt_static, self.state_static, it, info_s
            )
            cd = {}
            if not self.static_only:
                cd = self.strat_dynamic.step_post_backward(
                    self.gauss.dynamic, self.opt_dynamic, self.state_dynamic, it, info_d
                )
            counts = {f"static_{k}": v for k, v in cs.items() if v}
            counts.update({f"dynamic_{k}": v for k, v in cd.items() if v})
        if (
            not self.static_only
            and s2.dynamic_removal_every > 0
            and it > 0
            and it % s2.dynamic_removal_every == 0
            and it <= s2.densify_dynamic.stop_iter
            and self.dynamic_masks is not None
        ):
            counts["dynamic_removed"] = self.remove_misplaced_dynamic()
        if (
            not self.static_only
            and s2.near_camera_fraction > 0
            and it > 0
            and (
                (s2.dynamic_removal_every > 0 and it % s2.dynamic_removal_every == 0)
                or it == s2.iterations - 1
            )
        ):
            counts["dynamic_near_removed"] = self.remove_near_camera_dynamic()
        if counts:
            self._knn_cache = None
        rec = {k: float(v.detach()) for k, v in L.items()}
        rec["total"] = float(total.detach())
        rec["num_gaussians"] = self.gauss.num_gaussians
        rec["num_dynamic"] = self.gauss.num_dynamic
        rec.update(counts)
        return rec

    @torch.no_grad()
    def remove_misplaced_dynamic(self) -> int:
        """Re-run the dynamic/static identification on the dynamic Gaussians' projected trajectories
        and remove the ones that no longer fall into dynamic regions (appendix: mistakenly densified
        dynamic Gaussians)."""
        from m4dgs.training.v2w import classify_dynamic

        g = self.gauss
        if g.num_dynamic == 0:
            return 0
        T = self.data.num_frames
        c2w = self.cameras().detach()
        pos = spline.evaluate(
            g.dynamic["ctrl"], g.knots, torch.arange(T, dtype=torch.float32, device=self.device)
        )
        pv = torch.stack(
            [
                cam.camera_to_video(
                    cam.transform_points(cam.invert_rigid(c2w[t]), pos[:, t]),
                    self.rig.K,
                    self.W,
                    self.H,
                )
                for t in range(T)
            ],
            1,
        )
        depth = torch.stack([self.render_at(float(t), c2w[t]).depth for t in range(T)])
        dyn = classify_dynamic(
            pv,
            self.dynamic_masks,
            depth if self.cfg.ablation.occlusion_handling else None,
            self.W,
            self.H,
            ratio=self.cfg.v2w.dynamic_ratio,
            occlusion_handling=self.cfg.ablation.occlusion_handling,
        )
        remove = ~dyn
        if bool(remove.all()):  # never empty the dynamic set completely
            return 0
        return self.strat_dynamic.remove(g.dynamic, self.opt_dynamic, self.state_dynamic, remove)

    @torch.no_grad()
    def remove_near_camera_dynamic(self) -> int:
        """Remove the dynamic Gaussians that come in view closer than stage2.near_camera_fraction x
        the scene extent (median world depth) to the camera at a training time or between two
        (cameras interpolated as for the test frames). Returns the number removed (never the whole
        dynamic set)."""
        s2, g = self.cfg.stage2, self.gauss
        if g.num_dynamic == 0:
            return 0
        T = self.data.num_frames
        ts = np.arange(0, (T - 1) * s2.near_camera_samples + 1) / max(s2.near_camera_samples, 1)
        c2w = self.cameras().detach()
        poses = cam.interpolate_trajectory(
            np.arange(T, dtype=np.float64), c2w.cpu().double().numpy(), ts
        )
        times = torch.as_tensor(ts, dtype=g.knots.dtype, device=self.device)
        poses = torch.as_tensor(poses, dtype=g.knots.dtype, device=self.device)
        ctrl = g.dynamic["ctrl"]
        near = torch.cat(
            [  # chunks of Gaussians: [chunk, S, 3] positions at a time
                near_camera_gaussians(
                    spline.evaluate(ctrl[i : i + 16384], g.knots, times),
                    poses,
                    self.rig.K,
                    self.W,
                    self.H,
                    s2.near_camera_fraction * self.extent,
                )
                for i in range(0, ctrl.shape[0], 16384)
            ]
        )
        if bool(near.all()) or not bool(near.any()):
            return 0
        return self.strat_dynamic.remove(g.dynamic, self.opt_dynamic, self.state_dynamic, near)

    # -- checkpoints
    # ----------------------------------------------------------------------------------------------
    def state_dict(self) -> Dict[str, Any]:
        return {
            "gaussians": self.gauss.to_state(),
            "color": self.color.state_dict(),
            "tonemap": self.tm.state_dict(),
            "background": self.bg.state_dict(),
            "rig": self.rig.state_dict(),
            "opt_static": {k: o.state_dict() for k, o in self.opt_static.items()},
            "opt_dynamic": {k: o.state_dict() for k, o in self.opt_dynamic.items()},
            "opt_other": {k: o.state_dict() for k, o in self.opt_other.items()},
            "state_static": self.state_static,
            "state_dynamic": self.state_dynamic,
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, sd: Dict[str, Any]) -> None:
        self.rig.load_state_dict(sd["rig"])
        self.color.load_state_dict(sd["color"])
        self.tm.load_state_dict(sd["tonemap"])
        self.bg.load_state_dict(sd["background"])
        self._setup(
            WorldGaussians.from_state(sd["gaussians"]).to(self.device), self.color, self.tm, self.bg
        )
        for name, opts in (
            ("opt_static", self.opt_static),
            ("opt_dynamic", self.opt_dynamic),
            ("opt_other", self.opt_other),
        ):
            for k, o in opts.items():
                o.load_state_dict(sd[name][k])
        self.state_static, self.state_dynamic = sd["state_static"], sd["state_dynamic"]
        self.rng.bit_generator.state = sd["rng"]


def ldr_reprojection_refs(
    i: int, num_frames: int, num_levels: int, pairs: str = "same-exposure"
) -> list:
    """Training-frame indices t' paired with frame i by the LDR reprojection baselines (those inside
    the clip).

    pairs: "same-exposure" -> i +- N_e (N_e = num_levels, the observed exposure levels): the same
    level in an
        alternating schedule, so plain L1 between the LDR frames is meaningful; "consecutive" -> i
        +- 1: the neighbouring, differently exposed frames, where the L1 compares unequal exposures
        (SplineGS-HDR as the paper ran it). With one level both are i +- 1.
    """
    if pairs == "same-exposure":
        off = max(int(num_levels), 1)
    elif pairs == "consecutive":
        off = 1
    else:
        raise ValueError(f"unknown LDR reprojection pairs {pairs!r} (same-exposure | consecutive)")
    return [k for k in (i - off, i + off) if 0 <= k < num_frames]


def near_camera_gaussians(
    positions: torch.Tensor,
    c2w: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    z_min: float,
    margin: float = 0.5,
) -> torch.Tensor:
    """[N] bool: Gaussians that, at some sample s, are in front of camera s at depth z < z_min and
    project inside the image enlarged by `margin` x its size on every side (a near Gaussian just
    outside the frame still splats in).

    Args:
        positions: [N, S, 3] world means at S sample times; c2w: [S, 4, 4] cameras at those times
        (OpenCV); K: [3, 3] intrinsics; width, height: image size in pixels; z_min: camera-space
        depth (world units).
    """
    # [N, S, 3], broadcast over S
    pc = cam.transform_points(cam.invert_rigid(c2w.to(positions)), positions)
    z = pc[..., 2]
    front = z > 1e-6
    uv = cam.project_pinhole(
        torch.where(front[..., None], pc, torch.ones_like(pc)), K.to(positions)
    )
    mx, my = margin * width, margin * height
    inside = (
        (uv[..., 0] > -mx)
        & (uv[..., 0] < width + mx)
        & (uv[..., 1] > -my)
        & (uv[..., 1] < height + my)
    )
    return (front & inside & (z < z_min)).any(1)


def train_stage2(
    stage: WorldStage,
    start: int = 0,
    on_step: Optional[Callable[[int, Dict[str, float]], None]] = None,
    progress: bool = True,
) -> None:
    """Run stage-2 iterations start..iterations-1 (see m4dgs.training.stage1.train_loop)."""
    train_loop(
        stage,
        stage.cfg.stage2.iterations,
        start,
        on_step,
        progress,
        "stage 2 (world Gaussians + cameras)",
        ("rgb", "pr"),
    )
